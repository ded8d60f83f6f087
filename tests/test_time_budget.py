"""loop --time-budget: each run is handed its training budget, a run that used it up is scored as it
stands (a flag on its record, told to the proposer), the hard limit is the budget plus the evaluation
allowance, and the audit grants its runs the same budget. And the target as a report line."""

import json

import pytest
from loop_helpers import TOY_OPTIMUM, ScriptedProposer, copy_toy, run_loop

from autoresearch.audit.inputs import open_campaign
from autoresearch.audit.noise import measure_noise
from autoresearch.campaign import Campaign, CampaignMeta
from autoresearch.cli import main
from autoresearch.execution.executors import LocalExecutor
from autoresearch.family import Family, family_problems
from autoresearch.journal import read_json, read_jsonl
from autoresearch.loop.session import settings_of
from autoresearch.loop.stopping import stop_gate
from autoresearch.proposers.base import RunOutcome
from autoresearch.proposers.tpe import TPEProposer

# The toy "trains" one 0.05 s step per epoch and honours AUTORESEARCH_TIME_BUDGET as the families do:
# it stops at the first step past the budget and reports what it reached, with budget_exhausted.
BUDGETED = """
def train(config, seed):
    budget = os.environ.get("AUTORESEARCH_TIME_BUDGET")
    started, steps, cut = time.monotonic(), 0, False
    for _ in range(config["EPOCHS"]):
        time.sleep(0.05)
        steps += 1
        if budget is not None and time.monotonic() - started >= float(budget):
            cut = True
            break
    result = toy_train({**config, "EPOCHS": max(steps, 1)}, seed)
    result["seen_budget"] = budget
    if budget is not None:
        result.update(time_budget=float(budget), budget_exhausted=cut)
    return result
"""


def budgeted_family(tmp_path, name="budgeted"):
    toy = copy_toy(tmp_path, name)
    train = toy / "train.py"
    source = train.read_text().replace(
        "def train(config: dict, seed: int) -> dict:", "def toy_train(config, seed):"
    )
    anchor = "def main() -> int:"
    train.write_text(source.replace(anchor, BUDGETED + "\n\n" + anchor, 1))
    return toy


LONG = {"EPOCHS": 60}  # 3 s of training: cut by a 1 s budget
SHORT = {"EPOCHS": 2}  # 0.1 s


def test_a_run_that_used_up_its_budget_is_scored_flagged_and_told(tmp_path):
    toy = budgeted_family(tmp_path)
    proposer = ScriptedProposer([LONG, SHORT, {"EPOCHS": 3}])
    settings = {"max_iters": 4, "plateau_window": 100}
    _, records = run_loop(toy, proposer, tmp_path / "c", timeout=30, time_budget=1.0, **settings)
    baseline, long, short = records[:3]
    assert long["status"] == "ran" and long["metric"] is not None and long["budget_exhausted"] is True
    assert long["final_metric"]["seen_budget"] == "1.0" and long["wall_seconds"] < 2.8
    assert short["status"] == "ran" and short["budget_exhausted"] is False
    assert baseline["budget_exhausted"] is False  # 10 steps: 0.5 s
    # The next turn says which runs were cut; the history shows each run's cost and the flag.
    context = proposer.contexts[-1]
    line = next(w for w in context.warnings if w.startswith("Training budget"))
    assert "at most 1 s" in line and f"iterations {long['iteration']}" in line
    shown = {item["iteration"]: item for item in context.history}
    assert shown[long["iteration"]]["budget_exhausted"] is True and shown[long["iteration"]]["seconds"] > 0
    assert "budget_exhausted" not in shown[short["iteration"]]
    # The key-free samplers get it as a trial user attribute, beside the run's cost.
    tpe = TPEProposer(Family.load(toy).search_registry())
    for record in Campaign(tmp_path / "c").records():
        if record.ran:
            tpe.tell(
                RunOutcome(
                    record.config,
                    record.metric,
                    True,
                    None,
                    None,
                    record.wall_seconds,
                    record.budget_exhausted,
                )
            )
    attrs = [t.user_attrs for t in tpe.trials]
    assert [a["budget_exhausted"] for a in attrs] == [
        r["budget_exhausted"] for r in records if r["status"] == "ran"
    ]
    assert all(a["seconds"] > 0 for a in attrs)


def test_without_a_budget_a_run_trains_as_written_whatever_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("AUTORESEARCH_TIME_BUDGET", "0.01")  # not the loop's: never handed on
    toy = budgeted_family(tmp_path)
    _, records = run_loop(toy, ScriptedProposer([LONG]), tmp_path / "c", max_iters=2)
    assert records[1]["final_metric"]["seen_budget"] is None and records[1]["budget_exhausted"] is None
    assert "time_budget" not in records[1]["final_metric"]


def test_the_cli_keeps_the_budget_and_kills_a_family_that_ignores_it(tmp_path, capsys, monkeypatch):
    toy = copy_toy(tmp_path)  # ignores the variable; TOY_SLEEP_S makes every run 5 s
    campaign = tmp_path / "c"
    args = ["loop", "--family", toy, "--proposer", "random", "--max-iters", "1", "--campaign", campaign]
    args += ["--time-budget", "0.5", "--eval-allowance", "1", "--plain"]
    monkeypatch.setenv("TOY_SLEEP_S", "5")
    assert main([*map(str, args)]) == 0
    monkeypatch.delenv("TOY_SLEEP_S")
    meta = read_json(campaign / "campaign.json")
    assert meta["settings"]["time_budget"] == 0.5 and meta["settings"]["eval_allowance"] == 1
    assert CampaignMeta.read(campaign).run_timeout == 1.5
    (baseline,) = [r for r in read_jsonl(campaign / "proposals.jsonl") if r["run_id"]]
    assert baseline["run_status"] == "timeout" and 1.4 < baseline["wall_seconds"] < 4
    assert "1.5 s wall-clock limit" in baseline["reason"]
    # A budgeted run's limit is the budget plus the allowance: --timeout-per-run beside it is refused.
    capsys.readouterr()
    refused = ["loop", "--family", toy, "--proposer", "random", "--campaign", tmp_path / "d"]
    assert main([*map(str, refused), "--time-budget", "5", "--timeout-per-run", "60"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--timeout-per-run does not apply with --time-budget" in err
    assert main([*map(str, refused), "--time-budget", "0", "--eval-allowance", "5"]) == 2
    assert "--eval-allowance applies under a time budget only" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


def test_the_audit_grants_its_runs_the_campaigns_budget(tmp_path):
    toy = budgeted_family(tmp_path)
    campaign = tmp_path / "c"
    campaign.mkdir()
    family = Family.load(toy)
    CampaignMeta.new(family, "scripted", {"timeout_per_run": 3600.0, "time_budget": 0.25}).write(campaign)
    run_loop(toy, ScriptedProposer([]), campaign, max_iters=1, time_budget=0.25)
    noise = measure_noise(family, LocalExecutor(2), k=2, campaign=open_campaign(campaign))
    assert noise["time_budget"] == 0.25 and noise["k"] == 2
    lines = read_jsonl(campaign / "audit" / "noise" / "runs.jsonl")
    assert [line["time_budget"] for line in lines] == [0.25, 0.25]
    assert open_campaign(campaign).timeout == 0.25 + 60.0  # the documented evaluation allowance


def test_the_target_is_a_report_line_unless_the_papers_rule_is_asked_for(tmp_path, capsys):
    toy = copy_toy(tmp_path)
    queue = tmp_path / "queue.json"
    queue.write_text(json.dumps(TOY_OPTIMUM))
    args = f"loop --family {toy} --proposer random --max-iters 4 --enqueue {queue} --plain".split()
    assert main([*map(str, args), "--campaign", str(tmp_path / "a")]) == 0
    out = capsys.readouterr().out
    records = read_jsonl(tmp_path / "a" / "proposals.jsonl")
    assert records[-1]["trigger"] == "max_iters" and len(records) == 5  # the target did not stop it
    assert "target 0.05: first reached at iteration 2 (it0002)" in out
    assert read_json(tmp_path / "a" / "campaign.json")["settings"]["stop_at_target"] is False
    assert main([*map(str, args), "--campaign", str(tmp_path / "b"), "--stop-at-target"]) == 0
    records = read_jsonl(tmp_path / "b" / "proposals.jsonl")
    assert records[-1]["trigger"] == "target_reached" and len(records) == 3
    # A campaign saved before the choice existed stopped at the target: it resumes under that rule.
    assert settings_of({}, {"max_iters": 4})["stop_at_target"] is True
    assert settings_of({}, {})["stop_at_target"] is False


def test_the_stop_gate_accepts_a_met_target_only_under_the_papers_rule(tmp_path):
    toy = copy_toy(tmp_path)
    run_loop(toy, ScriptedProposer([TOY_OPTIMUM]), tmp_path / "c", max_iters=2)
    state = Campaign(tmp_path / "c").state(Family.load(toy))
    assert state.target_met
    claim = {"status": "target_met"}
    assert stop_gate(claim, state, stop_at_target=True)[0] is True
    accepted, why = stop_gate(claim, state, stop_at_target=False)
    assert not accepted and "a stop needs at least 6 experiments" in why


@pytest.mark.parametrize("allowance", ["0", "-1"])
def test_a_non_positive_allowance_is_refused(tmp_path, allowance, capsys):
    toy = copy_toy(tmp_path)
    args = f"loop --family {toy} --proposer random --time-budget 5 --eval-allowance {allowance}".split()
    with pytest.raises(SystemExit) as exit_:
        main([*map(str, args), "--campaign", str(tmp_path / "c")])
    assert exit_.value.code == 2 and "expected a positive float" in capsys.readouterr().err


def _with_budget(toy, budget):
    registry = json.loads((toy / "family.json").read_text())
    (toy / "family.json").write_text(json.dumps({**registry, "time_budget": budget}))


def test_a_plain_loop_grants_the_familys_budget_and_says_how_long_it_may_take(tmp_path, capsys):
    """family.json's time_budget is every run's unless the flags decide (issue 59): the banner says the
    budget, the caps, the workers and a bound on the campaign; --time-budget 0 means none."""
    toy = budgeted_family(tmp_path)
    _with_budget(toy, 0.5)
    args = ["loop", "--family", toy, "--proposer", "random", "--max-iters", "2", "--plain", "--seed", "3"]
    assert main([*map(str, [*args, "--campaign", tmp_path / "a"])]) == 0
    out = capsys.readouterr().out
    assert CampaignMeta.read(tmp_path / "a").time_budget == 0.5
    banner = out.split("\n[it 1]")[0]
    assert "loop: family toy, proposer random, 1 worker" in banner
    assert "each run: 0.5 s of training (the family's default)" in banner
    assert "stops at the first of: 2 iterations" in banner
    eval_allowance = CampaignMeta.read(tmp_path / "a").eval_allowance
    assert f"campaign length: at most {round(2 * (0.5 + eval_allowance) / 60)} min (2 runs" in banner
    records = read_jsonl(tmp_path / "a" / "proposals.jsonl")
    assert all(r["final_metric"]["seen_budget"] == "0.5" for r in records if r.get("final_metric"))
    # --time-budget 0: no budget, each run limited by --timeout-per-run alone.
    assert main([*map(str, [*args, "--campaign", tmp_path / "b", "--time-budget", "0"])]) == 0
    assert "each run: no training budget; stopped at 1 h 00 min" in capsys.readouterr().out
    assert CampaignMeta.read(tmp_path / "b").time_budget is None
    # --timeout-per-run alone decides the limit too: the family's budget is not granted beside it.
    assert main([*map(str, [*args, "--campaign", tmp_path / "c", "--timeout-per-run", "30"])]) == 0
    assert CampaignMeta.read(tmp_path / "c").time_budget is None
    # --max-iters 1 runs the baseline only, and says so.
    one = [*map(str, args[:5]), "--max-iters", "1", "--plain", "--campaign", str(tmp_path / "d")]
    assert main(one) == 0
    assert "1 iteration (the baseline only" in capsys.readouterr().out


@pytest.mark.parametrize("given", ["-1", "nan", "inf", "ten"])
def test_a_bad_time_budget_is_refused_by_name(tmp_path, capsys, given):
    toy = copy_toy(tmp_path)
    with pytest.raises(SystemExit):
        main(["loop", "--family", str(toy), "--proposer", "random", "--time-budget", given])
    err = capsys.readouterr().err
    assert "--time-budget" in err and "seconds >= 0" in err and repr(given) in err
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize("declared", [-5, 0, "300", True, float("inf")])
def test_a_familys_bad_time_budget_is_named_by_its_check(tmp_path, declared):
    toy = copy_toy(tmp_path)
    registry = json.loads((toy / "family.json").read_text())
    registry["time_budget"] = declared
    (toy / "family.json").write_text(json.dumps(registry).replace("Infinity", "1e999"))
    problems = family_problems(toy)
    assert any("'time_budget' must be a positive number of seconds or null" in p for p in problems)


def test_a_campaign_with_no_feasible_run_says_which_came_closest_and_by_how_much(tmp_path, capsys):
    """ "best: none" names the run nearest the gate and what it missed (issue 59), from its record."""
    toy = copy_toy(tmp_path)
    registry = json.loads((toy / "family.json").read_text())
    registry["baseline"]["config"]["MOMENTUM"] = 0.99  # lr / (1 - momentum) = 1.0: over the toy's 0.5
    (toy / "family.json").write_text(json.dumps(registry))
    train = toy / "train.py"
    train.write_text(train.read_text().replace("MOMENTUM = 0.5  #", "MOMENTUM = 0.99  #", 1))
    args = ["loop", "--family", toy, "--proposer", "random", "--max-iters", "1", "--plain"]
    assert main([*map(str, [*args, "--campaign", tmp_path / "c"])]) == 0
    out = capsys.readouterr().out
    assert "best loss: none: no feasible run; the closest, it0001, missed step_excess by 0.5" in out


def test_loop_help_says_what_a_run_and_a_campaign_cost(capsys):
    with pytest.raises(SystemExit):
        main(["loop", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "Each run trains for the family's time budget (family.json 'time_budget'" in text
    assert "1 runs the baseline only" in text and "0: no budget" in text
    assert "autoresearch loop --family rendezvous --proposer gp" in text  # an example that runs key-free
