import itertools
import json
import math
import random
import statistics

import pytest
from extras import missing_extras
from loop_helpers import TOY_FAMILY

from autoresearch.extras import MissingExtra
from autoresearch.proposers import make_proposer
from autoresearch.proposers.base import ProposerContext, RunOutcome
from autoresearch.proposers.gp import GPProposer
from autoresearch.proposers.random_search import RandomProposer
from autoresearch.proposers.tpe import TPEProposer

TINY = {
    "direction": "maximize",
    "axes": ["a", "b"],
    "search_space": {
        "FLAG": {"type": "bool", "axis": "a"},
        "KIND": {"type": "categorical", "choices": ["x", "y"], "axis": "b"},
    },
}
ALL_TINY = [{"FLAG": f, "KIND": k} for f, k in itertools.product([False, True], ["x", "y"])]


def context(history, iteration=2, running=()):
    return ProposerContext(
        iteration=iteration,
        warnings=(),
        program="",
        registry={},
        random_arm_summary=None,
        history=tuple({"config": c, "m": 0.0} for c in history),
        current_values=ALL_TINY[0],
        running=tuple({"config": c} for c in running),
    )


@pytest.mark.parametrize("cls", [RandomProposer, TPEProposer, GPProposer])
def test_never_repeats_a_seen_config_when_it_can_avoid_it(cls):
    proposer = cls(TINY, seed=0)
    for config in ALL_TINY[:3]:
        proposer.tell(RunOutcome(config, 1.0, True))
    proposal = proposer.propose(context(ALL_TINY[:3]))
    assert proposal.kind == "propose" and proposal.overrides == ALL_TINY[3]
    proposer.tell(RunOutcome(ALL_TINY[3], 1.0, True))
    exhausted = proposer.propose(context(ALL_TINY))
    assert exhausted.kind == "invalid" and "no unseen configuration" in exhausted.error
    # An experiment still running counts as seen: the last unseen one is not proposed twice.
    assert proposer.propose(context(ALL_TINY[:3], running=ALL_TINY[3:])).kind == "invalid"


def test_random_draws_depend_only_on_seed_and_iteration():
    registry = json.loads((TOY_FAMILY / "family.json").read_text())
    a, b = RandomProposer(registry, seed=4), RandomProposer(registry, seed=4)
    first = a.propose(context([], iteration=2))
    assert b.propose(context([], iteration=2)).overrides == first.overrides
    assert a.propose(context([], iteration=3)).overrides != first.overrides
    assert RandomProposer(registry, seed=5).propose(context([], iteration=2)).overrides != first.overrides
    assert first.annotation["axes"]  # the axes it moves off the current values


def test_tpe_observations_failures_and_infeasible_runs():
    registry = json.loads((TOY_FAMILY / "family.json").read_text())
    tpe = TPEProposer(registry, seed=1, n_startup_trials=2)
    base = json.loads((TOY_FAMILY / "family.json").read_text())["baseline"]["config"]
    tpe.tell(RunOutcome({**base, "EPOCHS": 1}, None, False))
    assert [t.state.name for t in tpe.trials] == ["FAIL"]  # nothing succeeded yet: no crash cost
    tpe.tell(RunOutcome(base, 0.8, True))
    tpe.tell(RunOutcome({**base, "EPOCHS": 0}, None, False))
    tpe.tell(RunOutcome({**base, "MOMENTUM": 0.99, "LEARNING_RATE": 0.05}, 0.5, False))
    trials = tpe.trials
    assert [t.state.name for t in trials] == ["COMPLETE"] * 4
    # Failures sit at the worst metric seen (the toy minimises: the highest), marked infeasible.
    assert [t.value for t in trials] == [0.8, 0.8, 0.8, 0.5]
    assert [t.constraints["feasible"] for t in trials] == [1.0, 0.0, 1.0, 1.0]
    history = [
        {**base, "EPOCHS": 1},
        base,
        {**base, "EPOCHS": 0},
        {**base, "MOMENTUM": 0.99, "LEARNING_RATE": 0.05},
    ]
    first = tpe.propose(context(history, iteration=5))
    again = tpe.propose(context(history, iteration=5))
    assert first.kind == "propose" and first.overrides == again.overrides  # a function of seed and history
    assert set(first.overrides) == set(base)
    with pytest.raises(ValueError):
        tpe.tell(RunOutcome({"EPOCHS": 3}, 1.0, True))  # tell() needs the full configuration


def test_make_proposer():
    registry = json.loads((TOY_FAMILY / "family.json").read_text())
    assert isinstance(make_proposer("random", registry, seed=1), RandomProposer)
    assert isinstance(make_proposer("tpe", registry, seed=1), TPEProposer)
    if missing_extras(["gp"]):  # the base install: one line naming the extra, before any search
        with pytest.raises(MissingExtra, match=r"--proposer gp .* needs torch.*cwh-autoresearch\[gp\]"):
            make_proposer("gp", registry, seed=1)
    else:
        assert isinstance(make_proposer("gp", registry, seed=1), GPProposer)
    with pytest.raises(ValueError, match="--space applies to the key-free proposers"):
        make_proposer("anthropic", registry, seed=1, space="bounds")
    with pytest.raises(ValueError, match="unknown proposer"):
        make_proposer("grid", registry, seed=1)
    with pytest.raises(ValueError, match="apply to LLM proposers"):
        make_proposer("tpe", registry, seed=1, model="x")


def toy_outcomes(proposer, n, seed=0):
    """``n`` random configurations of the family's full space told with a smooth metric; returns them."""
    rng = random.Random(seed)
    configs = [proposer.family_space.sample(rng) for _ in range(n)]
    for i, config in enumerate(configs):
        metric = None if i == 3 else abs(math.log10(config["LEARNING_RATE"]) + 2) + config["DROPOUT"]
        proposer.tell(RunOutcome(config, metric, True))
    return configs


@pytest.mark.parametrize("name", ["random", "tpe", pytest.param("gp", marks=pytest.mark.needs("gp"))])
@pytest.mark.parametrize("space", ["bounds", "random-range"])
def test_every_key_free_arm_searches_the_chosen_space(name, space):
    registry = json.loads((TOY_FAMILY / "family.json").read_text())
    epochs = []
    for seed in range(3):
        proposer = make_proposer(name, registry, seed=seed, space=space)
        history = toy_outcomes(proposer, 7, seed) if name != "random" else []
        for iteration in range(2, 8 if name == "random" else 4):
            proposal = proposer.propose(context(history, iteration=iteration))
            assert proposal.kind == "propose"
            epochs.append(proposal.overrides["EPOCHS"])
    if space == "random-range":
        assert all(5 <= e <= 50 for e in epochs)  # EPOCHS' random_range; the bounds are [0, 60]
    else:
        assert proposer.space.params["EPOCHS"].high == 60
        if name == "random":
            assert max(epochs) > 50 or min(epochs) < 5


@pytest.mark.needs("gp")
def test_gp_resume_asks_the_same_and_pending_trials_move_it():
    registry = json.loads((TOY_FAMILY / "family.json").read_text())
    gp = GPProposer(registry, seed=2, n_startup_trials=4)
    history = toy_outcomes(gp, 8)
    assert [t.state.name for t in gp.trials].count("COMPLETE") == 8  # the failure at the crash cost
    first = gp.propose(context(history, iteration=9))
    resumed = GPProposer(registry, seed=2, n_startup_trials=4)
    toy_outcomes(resumed, 8)
    assert resumed.propose(context(history, iteration=9)).overrides == first.overrides
    assert first.annotation["hypothesis"].startswith("GP suggestion")
    # With the first suggestion still running, qLogEI proposes elsewhere.
    pending = gp.propose(context(history, iteration=10, running=[first.overrides]))
    assert pending.kind == "propose" and pending.overrides != first.overrides
    assert (
        gp.propose(context(history, iteration=10, running=[first.overrides])).overrides == pending.overrides
    )


def test_history_outside_a_narrowed_space_is_kept_out_of_the_model():
    registry = json.loads((TOY_FAMILY / "family.json").read_text())
    tpe = TPEProposer(registry, seed=0, space="random-range")
    base = registry["baseline"]["config"]
    tpe.tell(RunOutcome({**base, "EPOCHS": 60}, 3.0, True))  # outside random_range [5, 50]
    tpe.tell(RunOutcome(base, 1.0, True))
    assert [t.params["EPOCHS"] for t in tpe.trials] == [10]
    tpe.tell(RunOutcome({**base, "EPOCHS": 7}, None, False))
    assert [t.value for t in tpe.trials] == [1.0, 3.0]  # the crash cost still counts the outside run


GATE = {
    "direction": "minimize",
    "axes": ["a"],
    "search_space": {
        "X": {"type": "real", "low": 0.0, "high": 1.0, "axis": "a"},
        "Y": {"type": "real", "low": 0.0, "high": 1.0, "axis": "a"},
    },
}


def test_graded_constraints_are_the_trials_constraints_and_failures_take_the_worst():
    tpe = TPEProposer(GATE, seed=0)
    tpe.tell(RunOutcome({"X": 0.2, "Y": 0.5}, 3.0, False, {"shortfall": 0.7, "violation": 0.0}))
    tpe.tell(RunOutcome({"X": 0.5, "Y": 0.5}, None, False))
    tpe.tell(RunOutcome({"X": 0.95, "Y": 0.5}, 1.0, True, {"shortfall": -0.05, "violation": 0.0}))
    assert [t.constraints for t in tpe.trials] == [
        {"shortfall": 0.7, "violation": 0.0},
        {"shortfall": 0.7, "violation": 0.0},  # the failure: the worst of each seen
        {"shortfall": -0.05, "violation": 0.0},
    ]
    met = TPEProposer(GATE, seed=0)
    met.tell(RunOutcome({"X": 0.95, "Y": 0.5}, 1.0, True, {"shortfall": -0.05}))
    met.tell(RunOutcome({"X": 0.5, "Y": 0.5}, None, False))
    assert met.trials[1].constraints == {"shortfall": 1.0}  # a failure is never feasible
    # A record without graded constraints: every trial is 0/1 again.
    tpe.tell(RunOutcome({"X": 0.3, "Y": 0.1}, 2.0, False))
    assert [t.constraints for t in tpe.trials] == [{"feasible": v} for v in (1.0, 1.0, 0.0, 1.0)]


@pytest.mark.parametrize("cls", [TPEProposer, pytest.param(GPProposer, marks=pytest.mark.needs("gp"))])
def test_graded_constraints_steer_the_search_towards_feasibility_before_any_run_is_feasible(cls):
    """Feasible needs X >= 0.9 and Y >= 0.9; no draw so far is, and the metric says nothing about
    either. Told how far each draw missed, the model-based arms move towards that corner; told
    only 0/1 they cannot tell one miss from another."""

    def proposals(graded: bool) -> list[float]:
        sums = []
        for seed in range(8):
            proposer = cls(GATE, seed=seed, n_startup_trials=4)
            rng = random.Random(seed)
            history = []
            while len(history) < 16:
                config = {"X": rng.random(), "Y": rng.random()}
                shortfall = max(0.9 - config["X"], 0.0) + max(0.9 - config["Y"], 0.0)
                if shortfall == 0.0:
                    continue
                proposer.tell(
                    RunOutcome(
                        config, rng.uniform(1.0, 2.0), False, {"shortfall": shortfall} if graded else None
                    )
                )
                history.append(config)
            proposal = proposer.propose(context(history, iteration=17)).overrides
            sums.append(proposal["X"] + proposal["Y"])
        return sums

    graded, blind = proposals(True), proposals(False)  # X + Y of each seed's next proposal
    assert statistics.mean(graded) > 1.6, graded  # the corner is at 1.8 to 2.0
    assert statistics.mean(graded) > statistics.mean(blind) + 0.5, (graded, blind)


def toy_metric(config):
    return abs(math.log10(config["LEARNING_RATE"]) + 2) + config["DROPOUT"]


@pytest.mark.parametrize("name", ["tpe", pytest.param("gp", marks=pytest.mark.needs("gp"))])
def test_off_at_zero_lets_a_sampler_propose_exactly_zero(name):
    """DROPOUT's range starts at 0 and the metric is best there: with the switch the sampler proposes
    exactly 0 (and models it: most of its later draws). Without it TPE never does (its Parzen density
    puts no mass on an end point); the GP's acquisition optimiser, bounded, can land on one. MOMENTUM,
    also a real range from 0, gets a switch too; the int and log ranges none."""
    registry = json.loads((TOY_FAMILY / "family.json").read_text())
    zeros = {}
    for off_at_zero in (False, True):
        proposer = make_proposer(name, registry, seed=0, off_at_zero=off_at_zero)
        history, drawn = [], []
        for iteration in range(2, 32):
            config = proposer.propose(context(history, iteration=iteration)).overrides
            proposer.tell(RunOutcome(config, toy_metric(config), True))
            history.append(config)
            drawn.append(config["DROPOUT"])
        zeros[off_at_zero] = sum(value == 0 for value in drawn[15:])  # after the random start-up
    assert zeros[True] >= 10 and (name == "gp" or zeros[False] == 0)
    assert sorted(n for n in proposer.distributions if n.endswith(":off")) == ["DROPOUT:off", "MOMENTUM:off"]
    # A config at 0 is told as switched off; asking again from the same history asks the same.
    off = next(t for t in proposer.trials if t.params["DROPOUT"] == 0)
    assert off.params["DROPOUT:off"] is True and all(
        t.params["DROPOUT:off"] is (t.params["DROPOUT"] == 0) for t in proposer.trials
    )
    assert proposer._ask(proposer.trials, 0) == proposer._ask(proposer.trials, 0)
    with pytest.raises(ValueError, match="--off-at-zero applies to the tpe and gp samplers"):
        make_proposer("random", registry, seed=0, off_at_zero=True)
