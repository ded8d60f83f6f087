"""loop --workers K: several experiments in flight in one campaign."""

import json
import time

import optuna
import pytest
from loop_helpers import ScriptedProposer, copy_toy, run_loop

from autoresearch.campaign import Campaign
from autoresearch.campaign.check import check_campaign
from autoresearch.family import Family
from autoresearch.journal import read_jsonl
from autoresearch.proposers.base import Proposal, ProposerContext, RunOutcome
from autoresearch.proposers.random_search import RandomProposer
from autoresearch.proposers.tpe import TPEProposer


@pytest.fixture
def toy(tmp_path, monkeypatch):
    monkeypatch.setenv("TOY_SLEEP_S", "0.4")  # runs overlap for sure
    return copy_toy(tmp_path)


class StaggeredProposer(ScriptedProposer):
    """Answers its first turn late, so iteration 2 starts well after the baseline and is still
    running when the baseline's end frees a worker (equal run times would otherwise race)."""

    def propose(self, context: ProposerContext) -> Proposal:
        if not self.contexts:
            time.sleep(0.6)
        return super().propose(context)


def test_two_workers_keep_two_runs_in_flight_and_show_them_to_the_proposer(toy, tmp_path):
    script = [{"LEARNING_RATE": 0.003}, {"LEARNING_RATE": 0.003}, {"EPOCHS": 12}, {"MOMENTUM": 0.6}]
    proposer = StaggeredProposer(script)
    outcome, records = run_loop(toy, proposer, tmp_path / "c", workers=2, max_iters=5, max_failures=5)
    # The proposer is first asked while the baseline runs, and sees it in flight.
    first = proposer.contexts[0]
    assert first.iteration == 2 and [r["run_id"] for r in first.running] == ["it0001"]
    assert set(first.running[0]) == {"iteration", "run_id", "overrides", "config", "hypothesis"}
    # The same overrides again while iteration 2 runs: refused by the in-flight dedup.
    second = proposer.contexts[1]
    assert "it0002" in [r["run_id"] for r in second.running]
    refused = next(r for r in records if r["iteration"] == 3)
    assert refused["status"] == "invalid" and "running now, at iteration 2" in refused["reason"]
    # Every iteration recorded exactly once; the stop record is last and has the highest number.
    assert sorted(r["iteration"] for r in records) == list(range(1, len(records) + 1))
    assert records[-1]["status"] == "stopped" and records[-1]["iteration"] == len(records)
    assert sum(r["status"] == "ran" for r in records) == 4 and outcome.trigger == "max_iters"
    # The fold of the file (completion order) gives the live state; `check` finds nothing wrong.
    state = Campaign(tmp_path / "c").state(Family.load(toy))
    assert state.best.metric == outcome.best.metric and state.n_runs_ok == 4
    problems = check_campaign(tmp_path / "c").problems
    assert [p for p in problems if p.where != "campaign.json"] == []  # campaign.json is written by the CLI


def test_a_trigger_stops_proposals_and_the_runs_in_flight_are_recorded_first(toy, tmp_path):
    proposer = RandomProposer(json.loads((toy / "family.json").read_text()), seed=2)
    outcome, records = run_loop(toy, proposer, tmp_path / "c", workers=3, max_runs=4)
    ran = [r for r in records if r["status"] == "ran"]
    # max_runs counts the runs in flight as would-be successes: no fifth run is started
    assert len(ran) == 4 and len(records) == 5 and outcome.trigger == "max_runs"
    assert records[-1]["status"] == "stopped" and records[-1]["iteration"] == 5
    assert len({json.dumps(r["config"], sort_keys=True) for r in ran}) == 4


def test_random_and_tpe_skip_and_pend_the_running_configurations(toy):
    registry = json.loads((toy / "family.json").read_text())
    family = Family.load(toy)
    history = []
    for seed in range(12):  # enough outcomes for TPE to leave its random start-up
        config = family.space.sample(__import__("random").Random(seed))
        history.append({"config": config, "loss": float(seed)})
    running = [{"iteration": 13, "run_id": "it0013", "overrides": {}, "config": history[0]["config"]}]
    context = ProposerContext(13, (), "", registry, None, tuple(history), family.baseline_config, running=())
    tpe = TPEProposer(registry, seed=0, n_startup_trials=5)
    for item in history:
        tpe.tell(RunOutcome(item["config"], item["loss"], True))
    # What TPE would suggest first becomes the run in flight: asked again, it must move away.
    first = tpe.propose(context).overrides
    running = [{"iteration": 13, "run_id": "it0013", "overrides": first, "config": first, "hypothesis": None}]
    busy = ProposerContext(
        14, (), "", registry, None, tuple(history), family.baseline_config, running=tuple(running)
    )
    assert tpe.propose(busy).overrides != first
    # Optuna sees it as a RUNNING trial of a constant-liar TPE (its own pending-trial mechanism).
    pending = optuna.trial.create_trial(
        state=optuna.trial.TrialState.RUNNING, params=first, distributions=tpe.distributions
    )
    assert pending.state == optuna.trial.TrialState.RUNNING
    # Random search draws per iteration; a draw equal to a running configuration is skipped.
    rnd = RandomProposer(registry, seed=0)
    drawn = rnd.propose(busy).overrides
    running = [{"iteration": 14, "run_id": "it0014", "overrides": drawn, "config": drawn, "hypothesis": None}]
    again = ProposerContext(14, (), "", registry, None, (), family.baseline_config, running=tuple(running))
    assert rnd.propose(again).overrides != drawn


def test_the_views_show_every_run_in_flight(toy, tmp_path):
    import io

    from rich.console import Console

    from autoresearch.loop.live import PlainView, RichView
    from autoresearch.proposers.base import Proposal

    console = Console(file=io.StringIO(), force_terminal=True, width=200)
    rich, plain = RichView("loss", console=console, run_limit=300), PlainView("loss", stream=io.StringIO())
    for view in (rich, plain):
        for iteration in (1, 2):
            view.iteration_started(iteration)
            view.proposal(
                iteration, "random", Proposal(kind="propose", annotation={"hypothesis": f"h{iteration}"})
            )
            view.run_started(f"it000{iteration}")
        view.run_progress(3.0, "it0001")
        view.run_progress(1.0, "it0002")
    assert sorted(rich.running) == ["it0001", "it0002"]
    table = rich._table()
    assert table.row_count == 2
    rich.close()
    text = console.file.getvalue()
    assert "it0001 3/300 s" in text and "it0002 1/300 s" in text  # elapsed of its limit
    assert "[it 2] started it0002 (also running: it0001)" in plain.stream.getvalue()


@pytest.mark.slow
def test_workers_on_ray_run_the_same_campaign(ray_instance, tmp_path):
    from autoresearch.cli import main

    toy = copy_toy(tmp_path)
    args = ["loop", "--family", str(toy), "--proposer", "random", "--max-iters", "4", "--workers", "2"]
    assert main([*args, "--campaign", str(tmp_path / "ray"), "--executor", "ray", "--plain"]) == 0
    records = read_jsonl(tmp_path / "ray" / "proposals.jsonl")
    assert sorted(r["iteration"] for r in records) == [1, 2, 3, 4, 5]
    assert sum(r["status"] == "ran" for r in records) == 4
    assert json.loads((tmp_path / "ray" / "campaign.json").read_text())["settings"]["executor"] == "ray"
    # Early stopping under Ray (once refused: a task's progress was not read while it ran)
    assert (
        main([*args, "--campaign", str(tmp_path / "es"), "--executor", "ray", "--early-stop", "median"]) == 0
    )
    assert json.loads((tmp_path / "es" / "campaign.json").read_text())["settings"]["early_stop"] == "median"
