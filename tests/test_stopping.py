import time

import pytest
from loop_helpers import TOY_OPTIMUM, ScriptedProposer, copy_toy, run_loop, stop

from autoresearch.campaign import Campaign, CampaignState
from autoresearch.family import Family
from autoresearch.loop.stopping import Budgets, closest_trigger, first_trigger, stop_gate
from autoresearch.proposers.base import Proposal, Usage
from autoresearch.splits import Score
from autoresearch.verdicts import noise_threshold, plateau, verdict

BAD = Proposal(kind="invalid", error="scripted junk")


@pytest.fixture
def toy(tmp_path):
    return copy_toy(tmp_path)


def statuses(records):
    return [r["status"] for r in records]


def test_iteration_cap(toy, tmp_path):
    outcome, records = run_loop(
        toy, ScriptedProposer([{"EPOCHS": 11}, BAD, {"EPOCHS": 12}]), tmp_path / "c", max_iters=3
    )
    assert statuses(records) == ["ran", "ran", "invalid", "stopped"]
    assert (
        records[-1]["iteration"] == 4
        and records[-1]["trigger"] == "max_iters"
        and outcome.trigger == "max_iters"
    )


def test_successful_runs_cap_counts_only_successes(toy, tmp_path):
    script = [BAD, {"EPOCHS": 11}, {"EPOCHS": 0}, {"EPOCHS": 12}, {"EPOCHS": 13}]
    _, records = run_loop(toy, ScriptedProposer(script), tmp_path / "c", max_runs=3)
    assert statuses(records) == ["ran", "invalid", "ran", "failed", "ran", "stopped"]
    assert records[-1]["trigger"] == "max_runs"


def test_target_reached_by_a_feasible_run_and_precedence(toy, tmp_path):
    script = [TOY_OPTIMUM, {"EPOCHS": 11}]
    _, records = run_loop(toy, ScriptedProposer(list(script)), tmp_path / "a", stop_at_target=True)
    assert statuses(records) == ["ran", "ran", "stopped"] and records[-1]["trigger"] == "target_reached"
    assert records[1]["metric"] <= 0.05 and records[1]["feasible"]
    # The runs cap precedes the target in Eq. stop.
    _, records = run_loop(
        toy, ScriptedProposer([TOY_OPTIMUM]), tmp_path / "b", max_runs=2, stop_at_target=True
    )
    assert records[-1]["trigger"] == "max_runs"
    # Without the paper's rule (the default) the target is no stop: the budget is used whole.
    _, records = run_loop(toy, ScriptedProposer(list(script)), tmp_path / "d", max_iters=3)
    assert statuses(records) == ["ran", "ran", "ran", "stopped"] and records[-1]["trigger"] == "max_iters"


def test_consecutive_failures_and_their_reset(toy, tmp_path):
    script = [{"EPOCHS": 0}, BAD, {"EPOCHS": 11}, BAD, stop(), {"DROPOUT": 7}]
    _, records = run_loop(toy, ScriptedProposer(script), tmp_path / "c")
    assert statuses(records) == [
        "ran",
        "failed",
        "invalid",
        "ran",
        "invalid",
        "stop_rejected",
        "invalid",
        "stopped",
    ]
    assert records[-1]["trigger"] == "max_failures" and records[-1]["iteration"] == 8


def test_spend_cap_is_strict(toy, tmp_path):
    script = [{"EPOCHS": 11}, {"EPOCHS": 12}, {"EPOCHS": 13}, {"EPOCHS": 14}]
    _, records = run_loop(
        toy, ScriptedProposer(script, usage=Usage(cost_usd=0.25)), tmp_path / "c", max_cost_usd=0.5
    )
    # 0.25, 0.50 (not above the cap), 0.75 -> stop.
    assert [r["cumulative_cost_usd"] for r in records] == [0.0, 0.25, 0.5, 0.75, 0.75]
    assert records[-1]["trigger"] == "max_cost" and records[-1]["iteration"] == 5


def test_plateau_window(toy, tmp_path):
    script = [
        {"LEARNING_RATE": 0.003},
        {"BATCH_SIZE": 128},
        {"BATCH_SIZE": 16},
        {"DROPOUT": 0.4},
        {"EPOCHS": 11},
    ]
    _, records = run_loop(toy, ScriptedProposer(script), tmp_path / "c", plateau_window=3)
    assert statuses(records) == ["ran"] * 5 + ["stopped"]
    assert records[-1]["trigger"] == "plateau"


class SlowProposer(ScriptedProposer):
    def propose(self, context):
        time.sleep(0.3)
        return super().propose(context)


def test_wall_clock(toy, tmp_path):
    script = [{"EPOCHS": e} for e in range(11, 30)]
    _, records = run_loop(toy, SlowProposer(script), tmp_path / "c", max_seconds=0.5)
    assert records[-1]["trigger"] == "wall_clock" and records[-1]["elapsed_s"] >= 0.5  # rounded to ms
    # Each iteration takes 0.3 s or more, so the clock stops the 19-step script within a few; a
    # loaded machine may stop it before the first run ends (CI did), never after the 5th.
    assert len(records) <= 5 and statuses(records)[:-1] == ["ran"] * (len(records) - 1)


def test_precedence_and_closest_trigger(toy, tmp_path):
    run_loop(toy, ScriptedProposer([TOY_OPTIMUM]), tmp_path / "c", max_iters=2)
    records = Campaign(tmp_path / "c").records()
    state = CampaignState.from_records(Family.load(toy), records[:2])  # target met, 2 iterations, 2 runs
    everything = Budgets(max_seconds=1, max_runs=2, max_iters=2, max_cost_usd=0.0)
    assert first_trigger(state, everything, elapsed_s=5).name == "wall_clock"
    assert first_trigger(state, everything, elapsed_s=0).name == "max_runs"
    assert (
        first_trigger(state, Budgets(max_iters=2, stop_at_target=True), elapsed_s=0).name == "target_reached"
    )
    assert first_trigger(state, Budgets(max_iters=2), elapsed_s=0).name == "max_iters"
    state.family.registry["target"] = None
    assert first_trigger(state, Budgets(max_iters=2), elapsed_s=0).name == "max_iters"
    assert first_trigger(state, Budgets(max_iters=3), elapsed_s=0) is None
    assert closest_trigger(state, Budgets(max_iters=4, max_runs=3), 0.0).startswith("2 of 3 runs done")


def test_verdict_and_threshold():
    assert noise_threshold(2.0, None) == pytest.approx(0.1) and noise_threshold(0.0, None) == 1e-12
    assert noise_threshold(2.0, 0.3) == 0.3
    # minimise: lower is better
    assert verdict(1.8, 2.0, -1, None) == "confirmed"
    assert verdict(1.95, 2.0, -1, None) == "within noise"
    assert verdict(2.1, 2.0, -1, None) == "regressed"
    # maximise, with a measured sigma
    assert verdict(2.5, 2.0, +1, 0.5) == "confirmed"
    assert verdict(2.4, 2.0, +1, 0.5) == "within noise"
    assert verdict(1.5, 2.0, +1, 0.5) == "regressed"


def scores(*pairs: tuple[float, bool]) -> list[Score]:
    return [Score(metric, feasible) for metric, feasible in pairs]


def test_plateau_predicate():
    runs = scores((1.0, True), (2.0, True), (2.05, True), (1.9, True))
    assert plateau(runs, +1, window=2, kappa=1.0, sigma=None)  # 2.05 beats 2.0 by < 5 %
    assert not plateau(runs, +1, window=2, kappa=1.0, sigma=0.01)  # ... but by > sigma
    assert not plateau(runs, +1, window=3, kappa=1.0, sigma=None)  # 2.0 beats 1.0
    assert not plateau(runs, +1, window=4, kappa=1.0, sigma=None)  # no run before the window
    infeasible_last = scores((1.0, True), (9.0, False))
    assert plateau(infeasible_last, +1, window=1, kappa=1.0, sigma=None)  # infeasible beats nothing
    no_b_pre = scores((1.0, False), (0.5, True))
    assert not plateau(no_b_pre, -1, window=1, kappa=1.0, sigma=None)  # no feasible b_pre
    assert plateau(runs, +1, window=2, kappa=6.0, sigma=0.01)  # a larger kappa demands more


SIX_OVER_FOUR_AXES = [
    {"EPOCHS": 11},
    {"LEARNING_RATE": 0.005},
    {"BATCH_SIZE": 32},
    {"ACTIVATION": "relu"},
    {"EPOCHS": 12},
    {"USE_NORM": True},
]


def test_stop_gate_accepts_after_six_experiments_over_four_axes(toy, tmp_path):
    proposer = ScriptedProposer([stop(), *SIX_OVER_FOUR_AXES, stop("success"), stop("plateau")])
    outcome, records = run_loop(toy, proposer, tmp_path / "c")
    assert statuses(records) == ["ran", "stop_rejected", *["ran"] * 6, "stop_rejected", "stop_accepted"]
    assert "only 0 experiment(s)" in records[1]["reason"]
    assert "claims success" in records[8]["reason"] and "the target is not met" in records[8]["reason"]
    assert any("stop request was rejected" in w for w in proposer.contexts[-1].warnings)
    assert (
        records[-1]["trigger"] == "stop_research"
        and "6 completed experiments over 5 axes" in records[-1]["reason"]
    )
    assert outcome.status == "stop_accepted"


def test_stop_gate_needs_four_axes(toy, tmp_path):
    narrow = [
        {"EPOCHS": 11},
        {"EPOCHS": 12},
        {"EPOCHS": 13},
        {"LEARNING_RATE": 0.005},
        {"EPOCHS": 14},
        {"MOMENTUM": 0.6},
    ]
    _, records = run_loop(toy, ScriptedProposer([*narrow, stop()]), tmp_path / "c", max_iters=8)
    assert records[7]["status"] == "stop_rejected"
    assert "6 experiment(s) completed over 2 axis/axes" in records[7]["reason"]


def test_stop_gate_accepts_when_the_target_is_met(toy, tmp_path):
    run_loop(toy, ScriptedProposer([TOY_OPTIMUM]), tmp_path / "c", max_iters=2)
    state = CampaignState.from_records(Family.load(toy), Campaign(tmp_path / "c").records()[:2])
    accepted, why = stop_gate({"status": "target_met"}, state)
    assert accepted and why.startswith("target met")
