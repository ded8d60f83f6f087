import json

import pytest
from loop_helpers import TOY_OPTIMUM, ScriptedProposer, copy_toy, run_loop, snapshot

from autoresearch.campaign import Record
from autoresearch.journal import read_json, read_jsonl
from autoresearch.proposers.base import Proposal, Usage


@pytest.fixture
def toy(tmp_path):
    return copy_toy(tmp_path)


def test_first_iteration_is_the_baseline_without_a_proposer_call(toy, tmp_path):
    proposer = ScriptedProposer([{"LEARNING_RATE": 0.003}])
    _, records = run_loop(toy, proposer, tmp_path / "c", max_iters=2)
    first = records[0]
    assert first["proposer"] == "baseline" and first["overrides"] == {} and first["verdict"] == "baseline"
    assert first["config"] == json.loads((toy / "family.json").read_text())["baseline"]["config"]
    assert first["seed"] == 0 and first["run_id"] == "it0001"
    assert [c.iteration for c in proposer.contexts] == [2]  # the proposer is first asked at iteration 2
    # Every arm shares that first iteration: same config, same seed, same metric.
    _, other = run_loop(toy, ScriptedProposer([]), tmp_path / "c2", max_iters=1)
    assert other[0]["metric"] == first["metric"] and other[0]["config"] == first["config"]


def test_records_schema_best_and_family_untouched(toy, tmp_path):
    before = snapshot(toy)
    proposer = ScriptedProposer(
        [{"LEARNING_RATE": 0.003}, {"ACTIVATION": "tanh", "EPOCHS": 12}, {"EPOCHS": 1}]
    )
    outcome, records = run_loop(toy, proposer, tmp_path / "c", max_iters=4, max_cost_usd=1.0)
    assert [r["iteration"] for r in records] == [1, 2, 3, 4, 5]
    assert all(tuple(r) == tuple(Record.__dataclass_fields__) for r in records)  # every field, in order
    assert [r["status"] for r in records] == ["ran", "ran", "ran", "ran", "stopped"]
    assert records[-1]["trigger"] == "max_iters" and outcome.status == "stopped"
    it2 = records[1]
    assert it2["verdict"] == "confirmed" and it2["best_so_far"] == it2["metric"] < records[0]["metric"]
    # Overrides apply to the best configuration so far.
    assert records[2]["config"] == {**records[1]["config"], "EPOCHS": 12}
    assert records[2]["overrides"] == {"EPOCHS": 12, "ACTIVATION": "tanh"}
    assert records[3]["verdict"] == "regressed"
    registry = read_json(tmp_path / "c" / "family.json")
    assert registry["campaign_best"]["run_id"] == outcome.best.run_id  # the campaign's own, not the family's
    assert registry["campaign_best"]["metric"] == min(r["metric"] for r in records if r["metric"] is not None)
    assert "best" not in registry
    assert [t[1] for t in proposer.tells] == [r["metric"] for r in records[:4]]
    assert proposer.tells[0][0] == records[0]["config"]  # tell() receives full configurations
    runs = read_jsonl(tmp_path / "c" / "runs.jsonl")
    assert [r["run_id"] for r in runs] == ["it0001", "it0002", "it0003", "it0004"]
    assert snapshot(toy) == before


def test_dedup_both_ways_and_refusals_fed_back(toy, tmp_path):
    proposer = ScriptedProposer(
        [
            {"LEARNING_RATE": 0.003},  # ran, becomes the best
            {"LEARNING_RATE": 0.003},  # same override map
            {"LEARNING_RATE": 0.003, "EPOCHS": 10},  # new map, but the same resulting configuration
            {"EPOCHS": 7.5},  # refused by validation
            {},  # changes nothing
            {"EPOCHS": 11},
        ]
    )
    _, records = run_loop(toy, proposer, tmp_path / "c", max_iters=7, max_failures=10)
    statuses = [r["status"] for r in records]
    assert statuses == ["ran", "ran", "invalid", "invalid", "invalid", "invalid", "ran", "stopped"]
    assert "override map was already run at iteration 2" in records[2]["reason"]
    assert "configuration was already run at iteration 2" in records[3]["reason"]
    assert records[4]["reason"] == "EPOCHS: expected an integer, got 7.5"
    assert "changes nothing" in records[5]["reason"]
    assert all(r["run_id"] is None for r in records[2:6])
    warnings = [c.warnings for c in proposer.contexts]
    assert any("refused" in w and "already run at iteration 2" in w for w in warnings[2])
    assert any("EPOCHS: expected an integer, got 7.5" in w for w in warnings[4])
    assert not any("refused" in w for w in warnings[1])


def test_failed_runs_infeasible_runs_and_proposer_errors(toy, tmp_path):
    infeasible_but_low = {**TOY_OPTIMUM, "MOMENTUM": 0.995}  # loss ~0.05 but lr/(1-m) = 0.6 > 0.5
    proposer = ScriptedProposer(
        [
            {"EPOCHS": 0},  # train.py fails
            RuntimeError("API outage"),
            Proposal(kind="invalid", error="no tool call"),
            infeasible_but_low,
            Proposal(kind="propose", overrides={"LEARNING_RATE": 0.003}),
        ]
    )
    _, records = run_loop(toy, proposer, tmp_path / "c", max_iters=6, max_failures=5)
    failed, raised, invalid, infeasible, ok = records[1:6]
    assert (
        failed["status"] == "failed"
        and failed["run_status"] == "failed"
        and "EPOCHS must be positive" in failed["reason"]
    )
    assert (
        raised["status"] == "invalid" and raised["reason"] == "the proposer raised RuntimeError: API outage"
    )
    assert invalid["reason"] == "no tool call"
    assert (
        infeasible["status"] == "ran"
        and infeasible["feasible"] is False
        and infeasible["verdict"] == "infeasible"
    )
    assert infeasible["metric"] < ok["metric"] < records[0]["metric"]
    assert infeasible["best_so_far"] == records[0]["metric"]  # an infeasible run is never the best
    assert ok["best_so_far"] == ok["metric"]
    assert records[-1]["trigger"] == "max_iters"  # the infeasible run's low loss did not count as the target
    assert proposer.tells[1] == (failed["config"], None, False)
    assert proposer.tells[2] == (infeasible["config"], infeasible["metric"], False)
    # The family's graded constraints reach the proposer with each run that has a record, and again
    # when a resumed campaign tells its history.
    excess = infeasible["config"]["LEARNING_RATE"] / (1 - infeasible["config"]["MOMENTUM"]) - 0.5
    assert proposer.constraints[1] is None and proposer.constraints[2] == {
        "step_excess": pytest.approx(excess)
    }
    assert proposer.constraints[0]["step_excess"] < 0 < excess
    resumed = ScriptedProposer([])
    run_loop(toy, resumed, tmp_path / "c", max_iters=6, max_failures=5)
    assert resumed.constraints[: len(proposer.constraints)] == proposer.constraints


def test_spend_is_recorded_and_accumulated(toy, tmp_path):
    proposer = ScriptedProposer([{"EPOCHS": 11}, {"EPOCHS": 12}], usage=Usage(100, 20, 0.25))
    _, records = run_loop(toy, proposer, tmp_path / "c", max_iters=3)
    assert [r["cost_usd"] for r in records] == [0.0, 0.25, 0.25, 0.0]
    assert [r["cumulative_cost_usd"] for r in records] == [0.0, 0.25, 0.5, 0.5]
    assert records[1]["input_tokens"] == 100 and records[1]["output_tokens"] == 20


def test_blind_context_hides_answer_bearing_numbers(toy, tmp_path):
    registry = json.loads((toy / "family.json").read_text())
    registry["notes"] = "the optimum learning rate is 3e-3"
    registry["seed_noise"] = {"mean": 0.86, "std": 0.01, "k": 5, "seeds": [1, 2, 3, 4, 5], "metric": "loss"}
    (toy / "family.json").write_text(json.dumps(registry))
    success = Proposal(kind="stop", annotation={"status": "target_met"})
    blind, seeing = (
        ScriptedProposer([{"EPOCHS": 11}, success, {"EPOCHS": 12}]),
        ScriptedProposer([{"EPOCHS": 11}]),
    )
    run_loop(toy, blind, tmp_path / "blind", max_iters=4, blind=True)
    run_loop(toy, seeing, tmp_path / "seeing", max_iters=2)
    ctx = blind.contexts[-1]
    assert ctx.blind and ctx.program == (toy / "program_blind.md").read_text()
    assert set(ctx.registry) == {
        "name",
        "metric",
        "direction",
        "feasibility_field",
        "default_seed",
        "axes",
        "search_space",
    }
    assert all(set(item) == {"config", "loss"} for item in ctx.history) and len(ctx.history) == 2
    assert "0.05" not in json.dumps(ctx.registry) and "0.86" not in json.dumps(ctx.registry)
    assert any("stop request was rejected" in w for w in ctx.warnings)
    assert not any("0.05" in w or "short of the target" in w or "target reached" in w for w in ctx.warnings)
    full = seeing.contexts[-1]
    assert not full.blind and full.program == (toy / "program.md").read_text()
    assert full.registry["target"] == 0.05 and full.registry["campaign_best"]["run_id"] == "it0001"
    assert any("short of the target 0.05" in w for w in full.warnings)
    assert full.history[0]["verdict"] == "baseline" and "auxiliary" in full.history[0]
    assert full.current_values == full.history[0]["config"]


def test_random_arm_summary_is_shown(toy, tmp_path):
    from autoresearch.proposers.random_search import RandomProposer

    run_loop(
        toy,
        RandomProposer(json.loads((toy / "family.json").read_text()), seed=1),
        tmp_path / "rs",
        max_iters=4,
    )
    from autoresearch.family import Family
    from autoresearch.loop.orchestrator import LoopSettings, Orchestrator
    from autoresearch.loop.stopping import Budgets

    proposer = ScriptedProposer([{"EPOCHS": 11}])
    settings = LoopSettings("scripted", Budgets(max_iters=2), random_arm=tmp_path / "rs")
    Orchestrator(Family.load(toy), proposer, tmp_path / "c", settings).run()
    summary = proposer.contexts[0].random_arm_summary
    assert summary.startswith("Random-search arm (rs): 4 successful runs, 0 failed.") and "loss=" in summary
