"""loop --early-stop: PROGRESS lines, Optuna's pruners, pruned runs kept out of every result."""

import json

import pytest
from loop_helpers import TOY_FAMILY, TOY_OPTIMUM, ScriptedProposer, copy_toy, run_loop

from autoresearch.audit.inputs import AuditedCampaign
from autoresearch.audit.verify import rank_candidates
from autoresearch.campaign import Campaign, CampaignState, Record, Status
from autoresearch.direction import Direction
from autoresearch.execution.protocol import parse_progress
from autoresearch.family import Family
from autoresearch.loop.context import build_context
from autoresearch.loop.early_stop import EarlyStopper
from autoresearch.proposers.base import ProposerContext, RunOutcome
from autoresearch.proposers.prompting import render_prompt
from autoresearch.proposers.tpe import TPEProposer

# Slow to learn and far from the optimum: a curve clearly worse than the finished runs' at step 1.
HOPELESS = {"LEARNING_RATE": 0.0001, "MOMENTUM": 0.0, "EPOCHS": 1, "BATCH_SIZE": 128}
GOOD = {**TOY_OPTIMUM, "ACTIVATION": "tanh"}  # loss about 0.1: short of the target (0.05)
SCRIPT = [GOOD, {"EPOCHS": 29}, {"EPOCHS": 31}, {"DROPOUT": 0.12}, HOPELESS]


def progress_family(tmp_path):
    """The toy family printing a four-point learning curve that ends at its loss."""
    toy = copy_toy(tmp_path, "progress")
    train = toy / "train.py"
    anchor = "    noise = random.Random(seed)"
    curve = (
        "    for step in range(1, 5):  # the curve ends at the final loss\n"
        '        print("PROGRESS: " + json.dumps({"step": step, "loss": loss * (2 - step / 4)}), flush=True)\n'
        "        time.sleep(0.2)\n"
    )
    train.write_text(train.read_text().replace(anchor, curve + anchor, 1))
    return toy


def test_progress_lines_are_parsed_and_malformed_ones_ignored():
    assert parse_progress('PROGRESS: {"step": 3, "loss": 0.5, "x": 1}', "loss") == {"step": 3, "value": 0.5}
    for bad in (
        'PROGRESS: {"step": 1.5, "loss": 1}',
        'PROGRESS: {"step": 1}',
        "PROGRESS: [1]",
        "PROGRESS: {",
    ):
        assert parse_progress(bad, "loss") is None
    assert parse_progress('PROGRESS: {"step": 1, "loss": NaN}', "loss") is None


@pytest.mark.parametrize("pruner", ["median", "asha"])
def test_a_hopeless_run_is_stopped_early_and_never_counts(tmp_path, pruner):
    toy = progress_family(tmp_path)
    outcome, records = run_loop(toy, ScriptedProposer(SCRIPT), tmp_path / "c", max_iters=6, early_stop=pruner)
    ran = [r for r in records if r["status"] == "ran"]
    assert all(len(r["progress"]) == 4 for r in ran)  # finished runs keep their whole curve
    hopeless = records[5]
    assert hopeless["config"]["LEARNING_RATE"] == 0.0001
    assert hopeless["status"] == "early_stopped" and hopeless["run_status"] == "early_stopped"
    assert hopeless["metric"] is None and hopeless["feasible"] is None and hopeless["verdict"] is None
    assert 1 <= len(hopeless["progress"]) < 4 and "stopped early at step" in hopeless["reason"]
    assert hopeless["wall_seconds"] < max(r["wall_seconds"] for r in ran)
    # Never best, not a failure; the next proposer turn hears it and sees the curve.
    store = Campaign(tmp_path / "c")
    typed = store.records()
    state = CampaignState.from_records(Family.load(toy), typed)
    assert state.best.run_id != hopeless["run_id"] and state.consecutive_failures == 0
    assert outcome.best.run_id == state.best.run_id and state.n_runs_ok == len(ran)
    before_stop = CampaignState.from_records(Family.load(toy), typed[:6])
    context = build_context(before_stop, registry=Family.load(toy).registry, blind=False)
    assert any("stopped early" in w for w in context.warnings)
    shown = render_prompt(context)
    assert '"progress"' in "".join(shown.history) and hopeless["run_id"] in "".join(shown.history)
    # The audit never promotes it: it is no candidate.
    family = Family.load(toy)
    campaign = AuditedCampaign(store, None, family, typed)
    assert hopeless["run_id"] not in [c["source"]["run_id"] for c in rank_candidates(campaign, 10)]
    # On --resume the pruner's study is rebuilt from the records' curves.
    study = EarlyStopper(pruner, Direction.MINIMIZE, typed).study
    pruned = [r for r in records if r["status"] == "early_stopped"]  # ASHA also stops some good runs
    assert [t.state.name for t in study.trials].count("PRUNED") == len(pruned) >= 1
    assert len(study.trials) == len(ran) + len(pruned)


def test_a_family_without_progress_lines_runs_as_before(tmp_path):
    toy = copy_toy(tmp_path)
    _, plain = run_loop(toy, ScriptedProposer(list(SCRIPT)), tmp_path / "a", max_iters=6)
    _, pruned = run_loop(
        toy, ScriptedProposer(list(SCRIPT)), tmp_path / "b", max_iters=6, early_stop="median"
    )
    keys = ("status", "config", "metric", "verdict", "best_so_far", "progress")
    assert [[r[k] for k in keys] for r in pruned] == [[r[k] for k in keys] for r in plain]
    assert all(r["progress"] is None for r in pruned) and pruned[5]["status"] == "ran"
    assert json.loads((tmp_path / "b" / "runs" / "it0006" / "result.json").read_text())["progress"] is None


def _finished(iteration: int, loss: float) -> Record:
    curve = [{"step": step, "value": loss * (2 - step / 4)} for step in range(1, 5)]
    return Record(iteration, Status.RAN, run_id=f"it{iteration:04d}", metric=loss, progress=curve)


def test_hyperband_stops_a_hopeless_curve_and_rebuilds_its_rungs_on_resume():
    """Optuna's HyperbandPruner, fed as the other pruners are; on --resume the finished curves are
    replayed through it, so its rungs hold their values again (without them nothing is pruned)."""
    records = [_finished(1, 0.86), *(_finished(i, 0.1 + 0.01 * i) for i in range(2, 11))]
    stopper = EarlyStopper("hyperband", Direction.MINIMIZE, records)
    assert type(stopper.study.pruner).__name__ == "HyperbandPruner"
    rungs = [k for t in stopper.study.trials for k in t.system_attrs if k.startswith("completed_rung")]
    assert rungs  # the replay set them
    stopped = []
    for n in range(3):
        report = stopper.start(f"hopeless{n}")
        stopped.append(any(report(step, 3.0 * (2 - step / 4)) for step in range(1, 5)))
    assert all(stopped)
    # A curve as good as the best finished one goes on.
    report = stopper.start("good")
    assert not any(report(step, 0.1 * (2 - step / 4)) for step in range(1, 5))


def test_an_early_stopped_run_is_a_pruned_trial_for_tpe_with_its_curve():
    registry = Family.load(TOY_FAMILY).search_registry()
    tpe = TPEProposer(registry, seed=0)
    baseline = Family.load(TOY_FAMILY).baseline_config
    tpe.tell(RunOutcome(baseline, 0.8, True, {"step_excess": -1.0}, seconds=2.0))
    tpe.tell(RunOutcome({**baseline, "EPOCHS": 40}, None, False, curve={1: 3.0, 2: 2.5}, seconds=0.7))
    complete, pruned = tpe.trials
    assert complete.state.name == "COMPLETE" and complete.user_attrs["seconds"] == 2.0
    assert pruned.state.name == "PRUNED" and pruned.intermediate_values == {1: 3.0, 2: 2.5}
    assert pruned.user_attrs == {"seconds": 0.7, "budget_exhausted": False}
    # not told at the crash cost any more: Optuna's TPE ranks it by how far it got
    assert (
        pruned.value is None
        and tpe.propose(ProposerContext.of_configs(3, registry, [], baseline)).kind == "propose"
    )
