"""The families' algorithm axis (POLICY_FORM, RESIDUAL_SCALE, DAGGER_ITERS, DAGGER_STARTS): the
defaults are the paper's behaviour cloning, a residual or costate policy with a zero correction is
the closed-form law (and a costate policy at the expert's multiplier the expert), and DAgger's
labels are the expert re-solved from the visited states. The docking families' robust safety
(issue 58, item 5): ROBUST_FILTER_K flies the robust filter, DAGGER_DISPERSED flies DAgger's rounds
under the dispersions, and the Monte Carlo auxiliary reports a 3-sigma stress set and the share of
starts breaking a constraint, which the ``robust`` protocol limits."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from extras import needs_module
from test_families import family_copy, final_metric, run

from autoresearch.family import Family
from cwh_envs import experts
from cwh_envs.constraints import cone_terms, speed_margin
from cwh_envs.controllers import MinEnergyFeedback, WaypointFeedback, pd_action
from cwh_envs.datasets import demonstrations, evaluation_starts
from cwh_envs.mpc import RecedingHorizon
from cwh_envs.observations import rendezvous_observation
from cwh_envs.prepare import DataNeeds, load_train, required_sets
from cwh_envs.robust_cbf import ErrorBounds
from cwh_envs.rollout import control_effort, fly

torch = needs_module("torch", "families")

ROOT = Path(__file__).resolve().parents[1]
FAMILIES = ("rendezvous", "docking", "docking-constrained")
DOCKING_FAMILIES = ("docking", "docking-constrained")


def run_with(script: Path, tmp_path: Path, env: dict, *args: str) -> subprocess.CompletedProcess:
    """train.py in a subprocess with extra environment variables (the private cache of the tests)."""
    full = {**os.environ, "CWH_ENVS_CACHE": str(tmp_path / "cache"), "OMP_NUM_THREADS": "1", **env}
    return subprocess.run(
        [sys.executable, str(script), *args],
        cwd=script.parent,
        env=full,
        capture_output=True,
        text=True,
        timeout=300,
    )


def budgeted_record(family: Path, tmp_path: Path, seconds: str) -> dict:
    """The FINAL_METRIC record of the family's train.py run under AUTORESEARCH_TIME_BUDGET=seconds."""
    result = run_with(
        family / "train.py", tmp_path, {"AUTORESEARCH_TIME_BUDGET": seconds}, "--out", str(tmp_path / "out")
    )
    assert result.returncode == 0, result.stderr
    return final_metric(result.stdout)


@pytest.fixture(scope="module")
def trains():
    return {name: load_train(ROOT / "families" / name) for name in FAMILIES}


def defaults(train) -> dict:
    return {name: getattr(train, name) for name in train.CONFIG_NAMES}


def starts_of(train, n: int):
    starts, goals = evaluation_starts(
        train.TASK,
        n,
        train.PROBLEM.replace(speed_limit=None, approach_cone=None)
        if train.TASK == "docking"
        else train.PROBLEM,
    )
    return starts, (goals if train.TASK == "docking" else None)


def small_policy(train, form: str, seed: int = 0, standardised: bool = False):
    """A 1 x 16 policy of ``form`` with random weights (torch seed ``seed``), in eval mode; its input
    standardisation random unless ``standardised`` (then mean 0, std 1)."""
    config = {**defaults(train), "POLICY_FORM": form, "HIDDEN_DIM": 16, "N_LAYERS": 1}
    torch.manual_seed(seed)
    if standardised:
        mean, std = torch.zeros(train.OBS_DIM), torch.ones(train.OBS_DIM)
    else:
        mean, std = torch.randn(train.OBS_DIM).abs(), torch.rand(train.OBS_DIM) + 0.5
    return train.build_policy(config, mean, std).eval()


def flown_both_ways(train, form: str):
    """A small random policy of ``form`` flown from 16 starts by the env and by the docking families'
    ClosedLoop (without the filter), its terminal distances and energies checked equal start by start;
    returns the env's flight, the starts' goals and ClosedLoop's middle term (intrusion, excursions)."""
    policy = small_policy(train, form)
    starts, goals = starts_of(train, 16)
    env = fly(train.PROBLEM, policy.act, starts, goals)
    with torch.no_grad():
        distance, middle, energy = train.ClosedLoop(torch.device("cpu"), 0.0).flight(
            policy, torch.as_tensor(starts), torch.as_tensor(goals)
        )
    # ClosedLoop's norm is smooth at 0 (sqrt(d^2 + 1e-12)): the route form ends 1e-7 m from the port
    smoothed = np.sqrt(env.terminal_distance**2 + 1e-12)
    np.testing.assert_allclose(distance.numpy(), smoothed, rtol=0, atol=1e-8)
    effort = control_effort(env.thrust, train.PROBLEM)[0]
    np.testing.assert_allclose(energy.numpy(), effort, rtol=1e-10)
    # The starts' flights differ, so a flight ignoring its policy would not match: they end apart, or
    # (the route form, whose law alone docks every start to 1e-7 m) spend apart.
    assert env.terminal_distance.std() > 1e-3 or effort.std() > 0.05 * effort.mean()
    return env, goals, middle


@pytest.mark.parametrize("name", FAMILIES)
def test_the_defaults_are_plain_behaviour_cloning(trains, name):
    config = defaults(trains[name])
    assert config["POLICY_FORM"] == "direct" and config["DAGGER_ITERS"] == 0
    family = json.loads((ROOT / "families" / name / "family.json").read_text())
    assert {k: config[k] for k in family["baseline"]["config"]} == family["baseline"]["config"]


def zero_correction(train, form: str):
    """A fresh ``form`` policy (some standardisation) whose network outputs zero, and its config."""
    config = {**defaults(train), "POLICY_FORM": form, "HIDDEN_DIM": 8, "N_LAYERS": 1}
    policy = train.build_policy(config, torch.randn(train.OBS_DIM).abs(), torch.rand(train.OBS_DIM) + 0.5)
    with torch.no_grad():
        policy.net[-1].weight.zero_()
        policy.net[-1].bias.zero_()
    return policy, config


def assert_flies_the_law(train, policy, starts, goals, law=None):
    """``policy`` flies ``law`` (the closed-form law by default) from ``starts``: returns the law's flight."""
    learned = fly(train.PROBLEM, policy.act, starts, goals)
    closed_form = fly(train.PROBLEM, law or MinEnergyFeedback(train.PROBLEM), starts, goals)
    np.testing.assert_allclose(learned.states, closed_form.states, rtol=0, atol=1e-9)
    np.testing.assert_allclose(learned.thrust, closed_form.thrust, rtol=0, atol=1e-12)
    return closed_form


@pytest.mark.parametrize("name", FAMILIES)
def test_a_residual_with_a_zero_correction_flies_the_closed_form_law(trains, name):
    train = trains[name]
    policy, config = zero_correction(train, "residual")
    starts, goals = starts_of(train, 3)
    closed_form = assert_flies_the_law(train, policy, starts, goals)
    law = MinEnergyFeedback(train.PROBLEM)
    # and the correction moves it, within its bound
    with torch.no_grad():
        policy.net[-1].bias.fill_(10.0)  # tanh -> 1: the law plus RESIDUAL_SCALE on every axis
    obs = closed_form.states[:, 5]
    observed = np.concatenate(
        [obs, *([closed_form.goals] if goals is not None else []), np.full((3, 1), 0.5)], axis=1
    )
    np.testing.assert_allclose(
        policy.act(observed),
        np.clip(law.thrust(observed) / train.PROBLEM.u_max + config["RESIDUAL_SCALE"], -1, 1),
        atol=1e-6,
    )


def test_a_route_policy_with_a_zero_correction_flies_the_waypoint_law(trains):
    """Constrained docking's "route" form: at zero the torch law is WaypointFeedback's, on and off
    the route's waypoints, and the correction moves it within its bound."""
    train = trains["docking-constrained"]
    policy, config = zero_correction(train, "route")
    law = WaypointFeedback(train.PROBLEM)
    starts, goals = starts_of(train, 3)
    flight = assert_flies_the_law(train, policy, starts, goals, law)
    assert (
        np.abs(
            flight.thrust - fly(train.PROBLEM, MinEnergyFeedback(train.PROBLEM), starts, goals).thrust
        ).max()
        > 1e-3
    )
    with torch.no_grad():
        policy.net[-1].bias.fill_(-10.0)
    observed = np.concatenate([flight.states[:, 40], goals, np.full((3, 1), 0.5)], axis=1)
    np.testing.assert_allclose(
        policy.act(observed),
        np.clip(law.thrust(observed) / train.PROBLEM.u_max - config["RESIDUAL_SCALE"], -1, 1),
        atol=1e-6,
    )
    # past the route's last waypoint (the final 20 steps) the correction is off: the law alone
    horizon = train.PROBLEM.horizon
    for steps_to_go, corrected in ((21, True), (20, False), (1, False)):
        observed[:, -1] = steps_to_go / horizon
        alone = np.clip(law.thrust(observed) / train.PROBLEM.u_max, -1, 1)
        moved = np.abs(policy.act(observed) - alone).max()
        assert (moved > 0.05) if corrected else (moved <= 1e-12), (steps_to_go, moved)


@pytest.mark.parametrize("route_lr", [0.0, 0.5])
def test_only_fine_tuning_with_a_route_rate_moves_the_route(trains, route_lr):
    """Constrained docking's ROUTE_LR: cloning never moves the route form's waypoints; fine-tuning
    moves them (downhill on its loss) only when ROUTE_LR > 0, records where they went, and leaves
    them frozen; at 0 they stay as drawn, bit for bit."""
    train = trains["docking-constrained"]
    drawn = train.build_policy({**defaults(train), "POLICY_FORM": "route"})
    drawn = torch.cat([drawn.route_along, drawn.route_across]).detach()
    config = {**defaults(train), "POLICY_FORM": "route", "RESIDUAL_SCALE": 0.01, "HIDDEN_DIM": 8}
    config |= {"N_LAYERS": 1, "EPOCHS": 2, "BATCH_SIZE": 16}
    rng = np.random.default_rng(0)
    obs, actions = rng.normal(size=(40, train.OBS_DIM)), rng.uniform(-1, 1, size=(40, 3))
    cpu, generator = torch.device("cpu"), torch.Generator().manual_seed(0)
    torch.manual_seed(0)  # the network's initialisation: the same whatever ran before in this worker
    policy, _ = train.train(config, obs, actions, cpu, generator)
    route = lambda: torch.cat([policy.route_along, policy.route_across]).detach().clone()  # noqa: E731
    torch.testing.assert_close(route(), drawn, rtol=0, atol=0)  # cloning left it

    pool = demonstrations("docking", 8, seed=0)  # any starts, goals and expert energies will do
    starts, goals = (torch.as_tensor(a) for a in (pool.starts, pool.goals))
    expert = torch.as_tensor(control_effort(pool.trajectory_thrust(), train.PROBLEM)[0])
    loss_of = train.ClosedLoop(cpu, 0.1)
    with torch.no_grad():
        before = loss_of(policy, starts, goals, expert)
    config |= {"FINETUNE_STEPS": 3, "FINETUNE_LR": 1e-6, "FINETUNE_ENERGY": 0.1, "ROUTE_LR": route_lr}
    policy, counts = train.finetune(config, policy, cpu, generator, train.Budget(None), pool)
    assert counts["steps"] == 3 and not policy.route_along.requires_grad
    if not route_lr:
        torch.testing.assert_close(route(), drawn, rtol=0, atol=0)
        assert "route" not in counts
        return
    moved = (route() - drawn).abs()
    assert moved.max() > 0.1 and moved.max() < 3 * route_lr  # Adam: about the rate a step, at most
    recorded = torch.tensor(counts["route"]["along"] + counts["route"]["across"], dtype=torch.float64)
    torch.testing.assert_close(recorded, route().flatten(), rtol=0, atol=5e-4)
    with torch.no_grad():
        assert loss_of(policy, starts, goals, expert) < before  # the network barely moved (lr 1e-6)


def test_a_costate_policy_is_the_law_at_zero_and_the_expert_at_the_experts_multiplier(trains):
    """Rendezvous' POLICY_FORM = "costate": with a zero correction it flies the closed-form law; the
    expert's controls are clip(-Gamma^T nu) for one nu along its whole trajectory, and at the
    correction that gives that nu the policy's action is the expert's and PlanLoss vanishes, while
    the law's (zero correction) does not where the box binds."""
    train = trains["rendezvous"]
    problem, horizon = train.PROBLEM, train.PROBLEM.horizon
    policy, _ = zero_correction(train, "costate")
    starts, _ = starts_of(train, 8)
    assert_flies_the_law(train, policy, starts, None)

    plans = np.stack([experts.solve_rendezvous(start, problem)[1] for start in starts])  # (8, H, 3)
    states = np.stack([experts.solve_rendezvous(start, problem)[0][:-1] for start in starts])
    saturated = (np.abs(plans) >= problem.u_max * (1 - 1e-6)).any(axis=(1, 2))
    assert saturated.any() and not saturated.all()
    model = train.PlanModel()
    free = ~(np.abs(plans) >= problem.u_max * (1 - 1e-6))
    gram = np.einsum("njc,jic,jkc->nik", free, model.impulse, model.impulse)
    nu = np.linalg.solve(gram, -np.einsum("njc,jic,njc->ni", free, model.impulse, plans)[..., None])[..., 0]
    replanned = np.clip(-np.einsum("jic,ni->njc", model.impulse, nu), -problem.u_max, problem.u_max)
    np.testing.assert_allclose(replanned, plans, rtol=0, atol=1e-9)  # one nu answers the whole plan

    obs = np.concatenate(
        [rendezvous_observation(states[:, k], k, horizon, dtype=np.float64) for k in range(horizon)]
    )
    episode = np.tile(np.arange(len(starts)), horizon)
    m = np.rint(obs[:, -1] * horizon).astype(int)
    rest = nu[episode] - np.einsum("nij,nj->ni", model.law_multiplier[m], obs[:, :6])
    correction = np.stack(
        [np.linalg.lstsq(model.spread[k], r, rcond=None)[0] for k, r in zip(m, rest, strict=True)]
    )
    raw = torch.as_tensor(obs)
    with torch.no_grad():
        action = policy.law(raw) + (
            policy.correction_gain[train.steps_to_go(raw)] @ torch.as_tensor(correction)[:, :, None]
        ).squeeze(-1)
    np.testing.assert_allclose(
        np.clip(action.numpy(), -1, 1), plans[episode, horizon - m] / problem.u_max, rtol=0, atol=1e-9
    )
    loss = train.PlanLoss(train.Plans(plans.astype(np.float32), episode), obs, torch.device("cpu"))
    rows = torch.arange(len(obs))
    assert loss(torch.as_tensor(correction), raw, rows).item() < 1e-12
    assert loss(torch.zeros(len(obs), 6), raw, rows).item() > 1e-4


@pytest.mark.parametrize(
    ("name", "form"), [("docking", "residual"), ("rendezvous", "costate"), ("docking-constrained", "route")]
)
def test_the_onnx_export_carries_the_law(trains, tmp_path, name, form):
    """Docking's residual, rendezvous' costate, constrained docking's route policy: the ONNX graph
    carries their gain tables (and the route's waypoints)."""
    onnx_policy = pytest.importorskip("cwh_envs.onnx_policy")
    train = trains[name]
    config = {**defaults(train), "POLICY_FORM": form, "HIDDEN_DIM": 8, "N_LAYERS": 1}
    starts, goals = starts_of(train, 2)
    obs = fly(train.PROBLEM, MinEnergyFeedback(train.PROBLEM), starts, goals).states.reshape(-1, 6)
    goal_mean, goal_std = (goals.mean(0), goals.std(0) + 1.0) if goals is not None else ([], [])
    mean, std = np.r_[obs.mean(0), goal_mean, 0.5], np.r_[obs.std(0), goal_std, 0.3]
    policy = train.build_policy(config, torch.as_tensor(mean), torch.as_tensor(std))
    source = tmp_path / "policy.pt"
    source.write_bytes(b"weights")
    summary = onnx_policy.export_checked(policy, tmp_path / "p.onnx", {"task": train.TASK}, source)
    assert summary["max_action_difference"] <= 1e-5


@pytest.mark.parametrize("name", ["rendezvous", "docking"])
def test_dagger_labels_are_the_expert_resolved_from_the_visited_states(trains, name):
    """A PD flight's visited states, relabelled: at every state the label is the first control of
    the expert solved from that state over the steps left (where the hard expert answers; the
    docking SCP to its own tolerance), the last step the law's."""
    train = trains[name]
    problem = train.PROBLEM
    starts, goals = starts_of(train, 2)
    flight = fly(
        problem,
        lambda obs: pd_action(obs, problem),
        starts,
        goals,
        cbf_margin=problem.margin if goals is not None else None,
    )
    obs, thrust, *plans, labels = train.relabel(flight)  # rendezvous: each state's re-plan too
    horizon = problem.horizon
    assert len(obs) == len(thrust) == 2 * horizon == labels["relabelled_states"]
    assert labels["hard_labels"] + labels["soft_labels"] + labels["fallback_labels"] == 2 * (horizon - 1)
    checked = 0
    for k in range(0, horizon - 1, 1 if name == "rendezvous" else 29):
        for i in range(2):
            row = k * 2 + i
            state = flight.states[i, k]
            try:
                if goals is None:
                    _, controls = experts.solve_rendezvous(state, problem, horizon=horizon - k)
                    tolerance = 1e-9
                else:
                    _, controls = experts.solve_docking(state, goals[i], problem, horizon=horizon - k)
                    tolerance = 1e-3
            except experts.Infeasible:
                continue
            np.testing.assert_allclose(thrust[row], controls[0], rtol=0, atol=tolerance)
            np.testing.assert_allclose(obs[row, :6], state)
            if plans:  # the costate form fits the whole re-plan, rows NaN before its step
                table = plans[0].table[plans[0].row[row]]
                np.testing.assert_allclose(table[k:], controls, rtol=0, atol=1e-6)  # float32
                assert np.isnan(table[:k]).all()
            checked += 1
    assert checked >= (100 if name == "rendezvous" else 10)
    last = obs[-2:]
    law = np.clip(MinEnergyFeedback(problem).thrust(last), -problem.u_max, problem.u_max)
    np.testing.assert_allclose(thrust[-2:], law, atol=1e-12)


@pytest.mark.parametrize("name", ["docking", "docking-constrained"])
def test_a_spent_budget_ends_the_relabelling_at_the_steps_labelled(trains, name):
    """The docking experts can take longer per round than a run's whole budget: relabelling stops at
    the first step past it and keeps every start's steps before it, each the expert's own label."""
    train = trains[name]
    problem = train.PROBLEM
    starts, goals = starts_of(train, 2)
    flight = fly(problem, lambda obs: pd_action(obs, problem), starts, goals, cbf_margin=problem.margin)
    budget = train.Budget(1e-9)
    budget.start()
    obs, thrust, labels = train.relabel(flight, budget=budget)
    assert obs.shape == (0, train.OBS_DIM) and thrust.shape == (0, 3) and budget.exhausted
    assert labels["relabelled_states"] == labels["last_step_law_labels"] == 0

    budget = train.Budget(0.3)  # the first step always runs; a whole flight takes minutes
    budget.start()
    obs, thrust, labels = train.relabel(flight, budget=budget)
    steps = len(obs) // 2
    assert 1 <= steps < problem.horizon and len(obs) == len(thrust) == 2 * steps
    assert labels["relabelled_states"] == 2 * steps and labels["last_step_law_labels"] == 0
    if name == "docking":  # step 0: the expert solved from the start over the whole horizon
        for i in range(2):
            _, controls = experts.solve_docking(starts[i], goals[i], problem)
            np.testing.assert_allclose(thrust[i], controls[0], rtol=0, atol=1e-3)


def test_a_relabelled_subsample_is_the_expert_from_each_drawn_state(trains):
    """Constrained docking's DAGGER_STATES: the states drawn are distinct visited states of the
    flight, drawn by the run's generator (the same seed draws the same states), each labelled with
    the expert re-solved from it alone, warm-started from what the flight applied from there."""
    train = trains["docking-constrained"]
    problem = train.PROBLEM
    starts, goals = starts_of(train, 2)
    flight = fly(problem, lambda obs: pd_action(obs, problem), starts, goals, cbf_margin=problem.margin)
    draw = [train.relabel_sample(flight, 2, torch.Generator().manual_seed(seed)) for seed in (3, 3, 4)]
    obs, thrust, labels = draw[0]
    np.testing.assert_array_equal(obs, draw[1][0])
    assert not np.array_equal(obs, draw[2][0])
    assert obs.shape == (2, train.OBS_DIM) and thrust.shape == (2, 3) and labels["relabelled_states"] == 2
    assert (
        labels["hard_labels"]
        + labels["soft_labels"]
        + labels["fallback_labels"]
        + labels["last_step_law_labels"]
        == 2
    )
    steps = np.rint((1 - obs[:, -1]) * problem.horizon).astype(int)
    rows = [
        int(np.flatnonzero((flight.states[:, k] == o[:6]).all(axis=1))[0])
        for o, k in zip(obs, steps, strict=True)
    ]
    assert len({(r, k) for r, k in zip(rows, steps, strict=True)}) == 2
    expert = RecedingHorizon(problem, on_failure="soft")
    for o, t, row, k in zip(obs, thrust, rows, steps, strict=True):
        np.testing.assert_array_equal(o[6:9], goals[row])
        expected = expert.answer(o[None], [flight.thrust[row, k:]])[0] * problem.u_max
        np.testing.assert_allclose(t, expected, rtol=0, atol=1e-9)
    budget = train.Budget(1e-9)
    budget.start()
    obs, thrust, labels = train.relabel_sample(flight, 2, torch.Generator().manual_seed(3), budget=budget)
    assert len(obs) == len(thrust) == labels["relabelled_states"] == 0 and budget.exhausted
    with pytest.raises(SystemExit, match="DAGGER_STATES must be an int in"):
        train.check_config({**defaults(train), "DAGGER_STATES": -1})


def test_a_pairs_loss_weight_scales_its_pull_and_weight_zero_pairs_move_nothing(trains):
    """Constrained docking's DAGGER_WEIGHT: a batch's loss is the weighted mean of its pairs, so a
    weight-0 pair's label cannot move the policy, and a weighted pair's label does."""
    train = trains["docking-constrained"]
    config = {**defaults(train), "EPOCHS": 3, "BATCH_SIZE": 64, "HIDDEN_DIM": 8, "N_LAYERS": 1}
    rng = np.random.default_rng(0)
    obs, actions = rng.normal(size=(40, train.OBS_DIM)), rng.uniform(-1, 1, size=(40, 3))
    other = actions.copy()
    other[30:] = -actions[30:]  # the last 10 labels differ

    def trained(labels, weights, epochs=3):
        torch.manual_seed(0)
        policy, loss = train.train(
            {**config, "EPOCHS": epochs},
            obs,
            labels,
            torch.device("cpu"),
            torch.Generator().manual_seed(0),
            weights=weights,
        )
        return torch.cat([p.detach().flatten() for p in policy.parameters()]), loss

    zero_tail = np.r_[np.ones(30), np.zeros(10)]
    a, b = trained(actions, zero_tail)[0], trained(other, zero_tail)[0]
    torch.testing.assert_close(a, b, rtol=0, atol=0)
    heavy = np.r_[np.ones(30), np.full(10, 50.0)]
    assert not torch.equal(trained(actions, heavy)[0], trained(other, heavy)[0])
    # One epoch of one batch: its loss is the weighted mean of the untrained policy's errors.
    torch.manual_seed(0)
    untrained = train.build_policy(config, obs.mean(0), obs.std(0))
    with torch.no_grad():
        x = torch.as_tensor((obs - obs.mean(0)) / obs.std(0), dtype=torch.float32)
        error = (untrained(x) - torch.as_tensor(actions / train.PROBLEM.u_max, dtype=torch.float32)).square()
    first = (error.sum(1).double() * torch.as_tensor(heavy)).sum().item() / heavy.sum()
    assert trained(actions, heavy, epochs=1)[1] == pytest.approx(first, rel=1e-5)
    assert trained(actions, None, epochs=1)[1] == pytest.approx(error.sum(1).mean().item(), rel=1e-5)
    for bad in (-1.0, math.nan, True, 1e4):
        with pytest.raises(SystemExit, match="DAGGER_WEIGHT must be a number in"):
            train.check_config({**defaults(train), "DAGGER_WEIGHT": bad})


@pytest.mark.parametrize("form", ["direct", "residual", "costate"])
def test_closed_loop_fine_tuning_flies_the_policy_as_the_env_does(trains, form):
    """ClosedLoop's torch flight is the env's: the same terminal distances, start by start."""
    train = trains["rendezvous"]
    policy = small_policy(train, form)
    starts, _ = starts_of(train, 16)
    env = fly(train.PROBLEM, policy.act, starts).terminal_distance
    with torch.no_grad():
        flown = train.ClosedLoop(torch.device("cpu")).terminal_distance(policy, torch.as_tensor(starts))
    np.testing.assert_allclose(flown.numpy(), env, rtol=0, atol=1e-8)
    assert env.std() > 1e-3  # the starts end apart: a flight that ignored its policy would not match


@pytest.mark.parametrize("form", ["direct", "residual"])
def test_docking_fine_tuning_flies_the_policy_as_the_env_does_without_the_filter(trains, form):
    """Docking's ClosedLoop: the env's terminal distances and energy, and the keep-out intrusion of
    the env's own states, start by start."""
    train = trains["docking"]
    env, _, intrusion = flown_both_ways(train, form)
    standoff = train.PROBLEM.koz_radius + train.PROBLEM.margin
    radius = np.linalg.norm(env.states[:, 1:, :3], axis=2)
    np.testing.assert_allclose(intrusion.numpy(), np.maximum(standoff - radius, 0).sum(axis=1), atol=1e-8)


@pytest.mark.parametrize("form", ["direct", "residual", "route"])
def test_constrained_fine_tuning_flies_the_policy_as_the_env_does_and_sums_every_excursion(trains, form):
    """Constrained docking's ClosedLoop: the env's terminal distances and energy, and, from the env's
    own states, the keep-out intrusion, the speed excess times the step and the distance outside the
    cone within its radius (cwh_envs.constraints' slack), start by start."""
    train = trains["docking-constrained"]
    env, goals, excursion = flown_both_ways(train, form)
    problem, visited = train.PROBLEM, env.states[:, 1:].reshape(-1, 6)  # steps 1..H
    at = np.repeat(goals, problem.horizon, axis=0)
    region, slack, _ = cone_terms(visited, at, problem.approach_cone)
    expected = {
        "keep_out": np.maximum(
            problem.koz_radius + problem.margin - np.linalg.norm(visited[:, :3], axis=1), 0
        ),
        "speed": np.maximum(-speed_margin(visited, at, problem.speed_limit), 0) * problem.dt,
        "cone": np.where(region, np.maximum(-slack, 0), 0),
    }
    for name, per_step in expected.items():
        summed = per_step.reshape(len(goals), problem.horizon).sum(axis=1)
        np.testing.assert_allclose(excursion[name].numpy(), summed, rtol=1e-9, atol=1e-8, err_msg=name)
    # The flights break the speed limit, and the law's (which reach the port) the cone: not zeros compared.
    assert excursion["speed"].max() > 1e-3 and (form == "direct" or excursion["cone"].max() > 1e-3)


def test_constrained_fine_tuning_can_hold_a_narrower_cone(trains):
    """FINETUNE_CONE_TIGHTEN: ClosedLoop's cone term is the slack of the cone narrowed by that many
    degrees (same region), from the env's own states, and it counts more than the cone's own."""
    train = trains["docking-constrained"]
    problem, cpu = train.PROBLEM, torch.device("cpu")
    policy = small_policy(train, "route")
    starts, goals = starts_of(train, 16)
    env = fly(problem, policy.act, starts, goals)
    visited, at = env.states[:, 1:].reshape(-1, 6), np.repeat(goals, problem.horizon, axis=0)
    half_angle, radius = problem.approach_cone
    region, slack, _ = cone_terms(visited, at, (half_angle - 5.0, radius))
    expected = np.where(region, np.maximum(-slack, 0), 0).reshape(16, problem.horizon).sum(axis=1)
    with torch.no_grad():
        flown = [torch.as_tensor(starts), torch.as_tensor(goals)]
        tight = train.ClosedLoop(cpu, 0.0, 5.0).flight(policy, *flown)[1]["cone"]
        plain = train.ClosedLoop(cpu, 0.0).flight(policy, *flown)[1]["cone"]
    np.testing.assert_allclose(tight.numpy(), expected, rtol=1e-9, atol=1e-8)
    assert (tight >= plain).all() and (tight > plain + 1e-3).any()


@pytest.mark.parametrize("form", ["direct", "route"])
def test_constrained_fine_tuning_under_dispersions_flies_the_envs_dispersed_flight(trains, form):
    """FINETUNE_DISPERSED (issue 58): ClosedLoop under the draws the env draws for each start (the
    plant's thrust gain, the navigation error the policy sees) ends where the env's dispersed flight
    ends, start by start; under no draws it flies otherwise (the draws are used, not ignored)."""
    from cwh_envs.dispersions import draw_episode, episode_rng

    train = trains["docking-constrained"]
    problem, cpu = train.PROBLEM, torch.device("cpu")
    policy = small_policy(train, form)
    starts, goals = starts_of(train, 16)
    env = fly(problem, policy.act, starts, goals, dispersions=train.DISPERSIONS, dispersion_seed=7)
    episodes = [draw_episode(train.DISPERSIONS, episode_rng(7 + i), problem.horizon) for i in range(16)]
    draws = (
        torch.as_tensor(np.stack([e.gain for e in episodes])),
        torch.as_tensor(np.stack([e.nav for e in episodes])),
    )
    loop = train.ClosedLoop(cpu, 0.0, dispersions=train.DISPERSIONS)
    with torch.no_grad():
        flown = [torch.as_tensor(starts), torch.as_tensor(goals)]
        dispersed = loop.flight(policy, *flown, draws)[0]
        nominal = loop.flight(policy, *flown)[0]
    smoothed = np.sqrt(env.terminal_distance**2 + 1e-12)
    np.testing.assert_allclose(dispersed.numpy(), smoothed, rtol=1e-9, atol=1e-8)
    assert np.abs(nominal.numpy() - smoothed).max() > 1e-3
    # The loss draws afresh from the run's generator: two calls, two draws; the same seed, the same.
    expert = torch.ones(16, dtype=torch.float64)
    losses = [loop(policy, *flown, expert, torch.Generator().manual_seed(s)).item() for s in (0, 0, 1)]
    assert losses[0] == losses[1] != losses[2]
    assert train.check_config({**defaults(train), "FINETUNE_DISPERSED": True}) is None
    with pytest.raises(SystemExit, match="FINETUNE_DISPERSED"):
        train.check_config({**defaults(train), "FINETUNE_DISPERSED": 1})


def test_a_closed_loop_gradient_step_lowers_the_flown_distance(trains):
    """The loss's gradient reaches the network through the whole flight and points downhill: a small
    step against it lowers the mean terminal distance from the same starts."""
    train = trains["rendezvous"]
    policy = small_policy(train, "residual", seed=1, standardised=True)
    starts = torch.as_tensor(starts_of(train, 32)[0])
    loss_of = train.ClosedLoop(torch.device("cpu"))
    before = loss_of(policy, starts)
    before.backward()
    grads = [p.grad for p in policy.net.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads) and any(
        g.abs().sum() > 0 for g in grads
    )
    with torch.no_grad():
        for p in policy.net.parameters():
            p -= 1e-4 * p.grad
        after = loss_of(policy, starts)
    assert after < before


@pytest.mark.parametrize("name", ["docking", "docking-constrained"])
def test_a_docking_gradient_step_lowers_its_loss_and_the_energy_weight_counts(trains, name):
    """The loss is the mean distance, the mean of each start's summed intrusion (constrained: of every
    constraint's excursion) and the weighted energy; a small step against its gradient lowers it."""
    train = trains[name]
    policy = small_policy(train, "residual", seed=1, standardised=True)
    starts, goals = (torch.as_tensor(a) for a in starts_of(train, 16))
    expert = torch.ones(16)  # a unit expert energy per start: the energy term is the batch's energy
    loss_of = train.ClosedLoop(torch.device("cpu"), 0.5)
    distance, beyond, energy = loss_of.flight(policy, starts, goals)
    if isinstance(beyond, dict):  # constrained docking: one term per constraint
        beyond = sum(beyond.values())
    distance, beyond, energy = (v.detach() for v in (distance, beyond, energy))
    before = loss_of(policy, starts, goals, expert)
    assert before.item() == pytest.approx((distance.mean() + beyond.mean() + 0.5 * energy.sum() / 16).item())
    before.backward()
    with torch.no_grad():
        for p in policy.net.parameters():
            p -= 1e-5 * p.grad
        assert loss_of(policy, starts, goals, expert) < before


@pytest.mark.parametrize("name", ["rendezvous", "docking"])
def test_a_fine_tuning_run_reports_its_steps_and_keeps_its_share_of_a_budget(tmp_path, name):
    family = family_copy(name, tmp_path, N_DEMOS=4, EPOCHS=2, HIDDEN_DIM=16, N_LAYERS=1, FINETUNE_STEPS=3)
    record = final_metric(
        run(family / "train.py", "--out", str(tmp_path / "out"), cache=tmp_path / "cache", check=True).stdout
    )
    tuned = record["finetune"]
    assert tuned["steps"] == 3 and math.isfinite(tuned["first_loss"]) and math.isfinite(tuned["last_loss"])
    assert record["config"]["FINETUNE_STEPS"] == 3
    # Cloning that would outlast the budget stops at its share; fine-tuning gets the rest.
    family = family_copy(
        name,
        tmp_path / "cut",
        N_DEMOS=8,
        EPOCHS=100000,
        BATCH_SIZE=16,
        HIDDEN_DIM=16,
        FINETUNE_STEPS=3,
        FINETUNE_SHARE=0.6,
    )
    record = budgeted_record(family, tmp_path, "4.0")
    assert record["budget_exhausted"] is True and record["finetune"]["steps"] == 3
    assert 1.6 <= record["train_seconds"] - record["finetune"]["seconds"] < 1.6 + 2.0


@pytest.mark.parametrize("name", FAMILIES)
def test_a_phase_of_a_budget_stops_at_its_share_and_marks_the_run_cut(trains, name):
    budget = trains[name].Budget(0.4)
    budget.start()
    cloning = budget.first(0.5)
    assert not cloning.spent() and not budget.exhausted
    time.sleep(0.25)
    assert cloning.spent() and cloning.exhausted and budget.exhausted  # the phase was cut, so the run
    assert not budget.spent()  # the whole still has its time
    time.sleep(0.2)
    assert budget.spent()
    assert not trains[name].Budget(None).first(0.5).spent()  # no budget, no limit


def test_a_budget_paces_the_rendezvous_schedule_to_end_annealed(trains):
    """Without a budget the cosine runs over the steps alone, as it always has; under one, its progress
    is the larger of the steps' and the clock's share, so a phase the budget cuts ends at rate 0."""
    train = trains["rendezvous"]
    config = defaults(train)

    def rate_after(descent, steps: int, pause: float = 0.0) -> float:
        for _ in range(steps):
            time.sleep(pause)
            descent.step(sum(p.sum() for p in descent.parameters))
        return descent.optimizer.param_groups[0]["lr"]

    peak, total = 1e-3, 100
    plain = train.Descent(small_policy(train, "direct"), peak, config, total)
    assert rate_after(plain, 3) == pytest.approx(peak * 0.5 * (1 + math.cos(math.pi * 3 / total)), rel=1e-12)
    roomy = train.Descent(small_policy(train, "direct"), peak, config, total, seconds=3600.0)
    assert rate_after(roomy, 3) == pytest.approx(peak * 0.5 * (1 + math.cos(math.pi * 3 / total)), rel=1e-6)
    # 3 steps of 100 would leave the rate near its peak; 0.3 s of a 0.2 s clock anneals it to 0
    paced = train.Descent(small_policy(train, "direct"), peak, config, total, seconds=0.2)
    assert 0 < rate_after(paced, 1) < peak
    assert rate_after(paced, 2, pause=0.15) == 0.0
    assert train.Budget(None).remaining() is None
    budget = train.Budget(10.0)
    budget.start()
    assert 9.0 < budget.remaining() <= 10.0 and 4.0 < budget.first(0.5).remaining() <= 5.0


# Docking relabels with its SCP (about 0.2 s a state from an untrained policy's states): one round
# from one start keeps it near a minute.
@pytest.mark.parametrize(
    ("name", "form", "iters", "starts"),
    [("rendezvous", "residual", 2, 3), ("rendezvous", "costate", 1, 2), ("docking", "residual", 1, 1)],
)
def test_a_dagger_run_on_the_law_reports_its_relabelling(tmp_path, name, form, iters, starts):
    family = family_copy(
        name,
        tmp_path,
        N_DEMOS=4,
        EPOCHS=2,
        BATCH_SIZE=64,
        HIDDEN_DIM=16,
        N_LAYERS=1,
        POLICY_FORM=f'"{form}"',
        DAGGER_ITERS=iters,
        DAGGER_STARTS=starts,
    )
    result = run(family / "train.py", "--out", str(tmp_path / "out"), cache=tmp_path / "cache", check=True)
    record = final_metric(result.stdout)
    counts = record["dagger"]
    horizon = load_train(family).PROBLEM.horizon
    assert counts["rounds"] == iters and counts["starts"] == starts
    assert counts["relabelled_states"] == iters * starts * horizon
    assert record["n_train_pairs"] == 4 * horizon + counts["relabelled_states"]
    progress = [
        json.loads(line.split(": ", 1)[1])
        for line in result.stdout.splitlines()
        if line.startswith("PROGRESS")
    ]
    assert [p["step"] for p in progress] == sorted({p["step"] for p in progress}) and progress[-1][
        "step"
    ] == 2 * (1 + iters)


def test_a_bad_lever_is_refused_in_one_line(tmp_path):
    family = family_copy(
        "rendezvous", tmp_path, POLICY_FORM='"mixed"', DAGGER_ITERS=99, FINETUNE_STEPS=-1, FINETUNE_SHARE=1.5
    )
    result = run(family / "train.py", cache=tmp_path / "cache")
    assert result.returncode != 0
    assert "POLICY_FORM must be one of" in result.stderr and "DAGGER_ITERS must be an int" in result.stderr
    assert "FINETUNE_STEPS must be a non-negative int" in result.stderr
    assert "FINETUNE_SHARE must lie in (0, 1)" in result.stderr


def test_a_bad_constrained_fine_tuning_lever_is_refused_in_one_line(tmp_path):
    family = family_copy(
        "docking-constrained", tmp_path, FINETUNE_STEPS=2.5, FINETUNE_LR=0, FINETUNE_ENERGY=-1.0
    )
    result = run(family / "train.py", cache=tmp_path / "cache")
    assert result.returncode != 0 and len(result.stderr.strip().splitlines()) == 1
    for problem in ("FINETUNE_STEPS must be a non-negative int", "FINETUNE_LR must be a positive finite"):
        assert problem in result.stderr
    assert "FINETUNE_ENERGY must be a non-negative finite number" in result.stderr


def test_a_time_budget_cuts_training_and_the_run_is_scored_as_it_stands(tmp_path):
    """AUTORESEARCH_TIME_BUDGET: training stops at the first step past it, the policy is scored on
    the split as usual and the record says it was cut; without the variable nothing changes."""
    family = family_copy("rendezvous", tmp_path, N_DEMOS=8, EPOCHS=100000, BATCH_SIZE=16)
    record = budgeted_record(family, tmp_path, "1.5")
    assert record["budget_exhausted"] is True and record["time_budget"] == 1.5
    assert 1.5 <= record["train_seconds"] < 30
    assert math.isfinite(record["mean_terminal_distance"]) and "runaway_share" in record
    refused = run_with(family / "train.py", tmp_path, {"AUTORESEARCH_TIME_BUDGET": "-3"})
    assert refused.returncode != 0 and "AUTORESEARCH_TIME_BUDGET must be a positive number" in refused.stderr


def test_each_expert_margin_has_its_own_pools_and_the_default_is_the_problems(trains):
    train = trains["docking"]
    needs = DataNeeds(
        task=train.TASK,
        problem=train.PROBLEM,
        pool_demos=8,
        data_seed=0,
        n_eval=4,
        obs_dim=train.OBS_DIM,
        pool_recovery=4,
        expert_margins=train.EXPERT_MARGINS,
    )
    described = [data.description for data in required_sets(needs)]
    assert len(described) == 1 + 2 * len(
        train.EXPERT_MARGINS
    )  # the search split, a pool and a recovery pool each
    for margin in (0.75, 1.0):
        assert sum(f"(expert margin {margin} m)" in d for d in described) == 2
    assert train.expert_problem(defaults(train)) == train.PROBLEM  # the default keeps the old data
    assert train.expert_problem({**defaults(train), "EXPERT_MARGIN": 0.75}).margin == 0.75
    assert "EXPERT_MARGINS" in (ROOT / "families" / "docking" / "prepare.py").read_text()


@pytest.mark.parametrize("name", ["rendezvous", "docking"])
def test_a_budget_spent_before_dagger_keeps_the_first_trainings_loss(tmp_path, name):
    """A budget the first training uses up leaves no DAgger round: the run is scored as it stands
    with the first training's loss (it died writing best_train_loss = inf, a lost run)."""
    family = family_copy(
        name,
        tmp_path,
        N_DEMOS=8,
        EPOCHS=100000,
        BATCH_SIZE=16,
        HIDDEN_DIM=16,
        N_LAYERS=1,
        DAGGER_ITERS=2,
        DAGGER_STARTS=4,
    )
    record = budgeted_record(family, tmp_path, "1.0")
    assert record["budget_exhausted"] is True and record["dagger"]["rounds"] == 0
    assert math.isfinite(record["best_train_loss"])


@pytest.mark.parametrize("name", DOCKING_FAMILIES)
def test_the_robust_filter_lever_flies_the_robust_filter_and_the_default_flies_as_before(trains, name):
    """ROBUST_FILTER_K: 0 (the default) flies the nominal filter, > 0 the robust filter sized for
    DISPERSIONS at that many sigmas, which flies differently (a wider berth of the keep-out); with the
    filter off there is none. Docking's fly still takes RUNTIME_CBF_FILTER's bool: the same flight."""
    train = trains[name]
    config = {**defaults(train), "POLICY_FORM": "residual", "HIDDEN_DIM": 8, "N_LAYERS": 1}
    assert defaults(train)["ROBUST_FILTER_K"] == 0.0 and defaults(train)["DAGGER_DISPERSED"] is False
    nominal_filter = {"cbf_margin": train.PROBLEM.margin}
    assert train.safety_filter(config) == nominal_filter
    assert train.safety_filter({**config, "RUNTIME_CBF_FILTER": False, "ROBUST_FILTER_K": 3.0}) == {}
    robust = train.safety_filter({**config, "ROBUST_FILTER_K": 2.0})
    assert robust["cbf_margin"] == train.PROBLEM.margin
    assert robust["cbf_bounds"] == ErrorBounds.from_dispersions(train.DISPERSIONS, k_sigma=2.0)
    policy, _ = zero_correction(train, "residual")  # the law heads through the keep-out: the filter acts
    starts, goals = starts_of(train, 3)
    nominal = train.fly(policy, starts, goals, nominal_filter)
    flown = train.fly(policy, starts, goals, robust)
    assert nominal.cbf_margin_scale is None and flown.cbf_margin_scale is not None  # the robust filter flew
    assert np.abs(flown.states - nominal.states).max() > 0.1
    assert flown.min_clearance.min() > nominal.min_clearance.min() >= 0.0
    if name == "docking":
        for cbf, safety in ((True, nominal_filter), (False, {})):
            by_bool = train.fly(policy, starts, goals, cbf, train.DISPERSIONS)
            by_keywords = train.fly(policy, starts, goals, safety, train.DISPERSIONS)
            np.testing.assert_array_equal(by_bool.states, by_keywords.states)


@pytest.mark.parametrize("name", DOCKING_FAMILIES)
@pytest.mark.parametrize(
    ("key", "bad", "message"),
    [
        ("ROBUST_FILTER_K", -1.0, "ROBUST_FILTER_K must be a number in [0, 5.0]"),
        ("ROBUST_FILTER_K", 5.5, "ROBUST_FILTER_K must be a number in [0, 5.0]"),
        ("ROBUST_FILTER_K", math.nan, "ROBUST_FILTER_K must be a number in [0, 5.0]"),
        ("ROBUST_FILTER_K", True, "ROBUST_FILTER_K must be a number in [0, 5.0]"),
        ("ROBUST_FILTER_K", "3", "ROBUST_FILTER_K must be a number in [0, 5.0]"),
        ("DAGGER_DISPERSED", 1, "DAGGER_DISPERSED must be True or False"),
    ],
)
def test_the_config_check_refuses_a_bad_robust_lever(trains, name, key, bad, message):
    train = trains[name]
    assert train.MAX_ROBUST_FILTER_K == 5.0
    train.check_config({**defaults(train), "ROBUST_FILTER_K": 5.0, "DAGGER_DISPERSED": True})  # the bounds
    with pytest.raises(SystemExit, match=re.escape(message)):
        train.check_config({**defaults(train), key: bad})


def test_a_bad_docking_robust_lever_is_refused_in_one_line(tmp_path):
    family = family_copy("docking", tmp_path, ROBUST_FILTER_K=9.0, DAGGER_DISPERSED=1)
    result = run(family / "train.py", cache=tmp_path / "cache")
    assert result.returncode != 0 and len(result.stderr.strip().splitlines()) == 1
    assert "ROBUST_FILTER_K must be a number in [0, 5.0]" in result.stderr
    assert "DAGGER_DISPERSED must be True or False" in result.stderr


@pytest.mark.parametrize("name", DOCKING_FAMILIES)
@pytest.mark.parametrize("dispersed", [False, True])
def test_dagger_dispersed_flies_the_rounds_under_the_dispersions(trains, monkeypatch, name, dispersed):
    """DAGGER_DISPERSED: a DAgger round flies its starts under DISPERSIONS (the draw of each start's
    seed) through the recipe's filter, and that flight is the one relabelled; off, the nominal flight.
    The training pool and the expert are stubbed (the expert's relabelling is tested above)."""
    train = trains[name]
    starts, goals = starts_of(train, 2)
    monkeypatch.setattr(
        train, "demonstrations", lambda *args, **kwargs: SimpleNamespace(starts=starts, goals=goals)
    )
    flights, relabelled = [], []
    flown_for_real = train.fly

    def recording(policy, starts, goals, safety, dispersions=None):
        flights.append((safety, dispersions, flown_for_real(policy, starts, goals, safety, dispersions)))
        return flights[-1][-1]

    def relabel(flight, expert_at=None, budget=None):
        relabelled.append(flight)
        labels = dict.fromkeys(("hard_labels", "soft_labels", "fallback_labels", "last_step_law_labels"), 0)
        return np.zeros((4, train.OBS_DIM)), np.zeros((4, 3)), {**labels, "relabelled_states": 4}

    monkeypatch.setattr(train, "fly", recording)
    monkeypatch.setattr(train, "relabel", relabel)
    config = {**defaults(train), "EPOCHS": 1, "HIDDEN_DIM": 8, "N_LAYERS": 1, "ROBUST_FILTER_K": 2.0}
    config |= {"DAGGER_ITERS": 1, "DAGGER_STARTS": 2, "DAGGER_DISPERSED": dispersed}
    generator = torch.Generator().manual_seed(0)
    obs = np.random.default_rng(0).normal(size=(8, train.OBS_DIM))
    policy = train.build_policy(config, obs.mean(axis=0), obs.std(axis=0)).eval()
    budget = train.Budget(None)
    budget.start()
    _, _, pairs, counts = train.dagger(
        config, policy, obs, np.zeros((8, 3)), torch.device("cpu"), generator, None, budget, math.inf
    )
    assert counts["rounds"] == 1 and pairs == 8 + 4
    ((safety, dispersions, flight),) = flights
    assert relabelled == [flight]
    assert safety == train.safety_filter(config) and safety["cbf_bounds"].k_sigma == 2.0
    assert dispersions == (train.DISPERSIONS if dispersed else None)


@pytest.mark.parametrize("name", DOCKING_FAMILIES)
def test_the_auxiliary_reports_a_stress_set_and_the_share_of_starts_breaking_a_constraint(
    trains, monkeypatch, name
):
    """evaluate's Monte Carlo auxiliary: ``dispersed`` at 1 sigma and ``dispersed_3sigma`` at
    STRESS_SCALE x DISPERSIONS, each with the starts breaking each constraint (docking: its one, the
    keep-out) and the deepest violation, and ``dispersed_violating_share``, the 1-sigma share of starts
    breaking any; the nominal metrics are the flight's own, untouched by them. Flown without the
    filter by the closed-form law, which heads through the keep-out: starts break things."""
    train = trains[name]
    policy, config = zero_correction(train, "residual")
    starts, goals = starts_of(train, 4)
    expert_thrust = fly(train.PROBLEM, MinEnergyFeedback(train.PROBLEM), starts, goals).thrust
    held_out = SimpleNamespace(starts=starts, goals=goals, trajectory_thrust=lambda: expert_thrust)
    off = train.safety_filter({**config, "RUNTIME_CBF_FILTER": False})
    flown_starts, flown_goals, draws = starts, goals, ()
    if name == "docking-constrained":  # each level flies DISPERSED_FLIGHTS flights: here 2 draws a start
        monkeypatch.setattr(train, "DISPERSED_FLIGHTS", 2 * len(starts) - 1)
        flown_starts, flown_goals, draws = np.concatenate([starts] * 2), np.concatenate([goals] * 2), (2,)
    metrics = train.evaluate(policy, held_out, off)
    nominal = train.evaluate(policy, held_out, off, dispersed=False)
    assert {k: v for k, v in metrics.items() if k in nominal} == nominal
    levels = {"dispersed", "dispersed_3sigma", "dispersed_violating_share"}
    if name == "docking-constrained":  # what its robust-fuel protocol limits besides
        levels |= {"dispersed_failure_share", "dispersed_3sigma_failure_share"}
        assert metrics["dispersed_3sigma_failure_share"] == 1 - metrics["dispersed_3sigma"]["success_rate"]
        assert metrics["dispersed_failure_share"] == 1 - metrics["dispersed"]["success_rate"]
    assert set(metrics) - set(nominal) == levels
    assert train.STRESS_SCALE == 3.0
    stress = {key: 3.0 * value for key, value in train.DISPERSIONS.items()}
    constraints = {"keep_out"} if name == "docking" else {"keep_out", "speed", "cone"}
    for key, spreads in (("dispersed", train.DISPERSIONS), ("dispersed_3sigma", stress)):
        level = metrics[key]
        assert level["dispersions"] == spreads
        flown = train.fly(policy, flown_starts, flown_goals, off, spreads)
        assert level == train.dispersed_metrics(flown, spreads, *draws)
        # Flight j draws seed DISPERSION_SEED + j: the first draw of every start is its one-draw flight.
        once = train.fly(policy, starts, goals, off, spreads)
        np.testing.assert_array_equal(flown.terminal_distance[: len(starts)], once.terminal_distance)
        assert draws == () or not np.array_equal(
            flown.terminal_distance[len(starts) :], once.terminal_distance
        )
        assert set(level["breaking_starts"]) == set(level["deepest"]) == constraints
        breaking = level["breaking_starts"]
        assert (
            0
            < max(breaking.values())
            <= level["violating_starts"]
            <= min(len(flown_starts), sum(breaking.values()))
        )
        assert all((level["deepest"][c] > 0) == (n > 0) for c, n in breaking.items())
        if name == "docking":  # one constraint: the starts breaking it are the violating ones
            assert level["violating_starts"] == breaking["keep_out"]
    assert (
        metrics["dispersed_3sigma"]["mean_terminal_distance"]
        != metrics["dispersed"]["mean_terminal_distance"]
    )
    flown = train.fly(policy, flown_starts, flown_goals, off, train.DISPERSIONS)
    broken = flown.violation_rate + (
        0 if name == "docking" else flown.speed_violation_rate + flown.cone_violation_rate
    )
    assert metrics["dispersed_violating_share"] == (broken > 0).sum() / len(flown_starts) > 0
    assert metrics["dispersed_violating_share"] == metrics["dispersed"]["violating_starts"] / len(
        flown_starts
    )
    # Here every start breaks something at both levels: the share is the 1-sigma level's, never the
    # stress set's, seen with levels that differ.
    counts = {"dispersed": 1, "dispersed_3sigma": 3}
    monkeypatch.setattr(
        train,
        "dispersed_metrics",
        lambda flight, spreads, *draws: {
            "violating_starts": counts["dispersed" if spreads == train.DISPERSIONS else "dispersed_3sigma"],
            "success_rate": 1.0,
        },
    )
    assert train.evaluate(policy, held_out, off)["dispersed_violating_share"] == 1 / len(flown_starts)


@pytest.mark.parametrize("name", DOCKING_FAMILIES)
def test_the_robust_protocol_limits_the_dispersed_share_and_the_space_holds_the_levers(trains, name):
    train = trains[name]
    family = Family.load(ROOT / "families" / name)
    robust = family.under_protocol("robust")
    assert robust.limits == {"dispersed_violating_share": 0.001}
    assert robust.is_feasible({"strict_feasible": True, "dispersed_violating_share": 0.0})
    assert not robust.is_feasible({"strict_feasible": True, "dispersed_violating_share": 1 / train.N_EVAL})
    assert not robust.is_feasible({"strict_feasible": False, "dispersed_violating_share": 0.0})
    assert not robust.is_feasible({"strict_feasible": True})  # a run that does not report it fails
    registry = json.loads((ROOT / "families" / name / "family.json").read_text())["search_space"]
    assert registry["ROBUST_FILTER_K"] == {
        "type": "categorical",
        "choices": [0.0, 1.0, 2.0, 3.0],
        "axis": "algorithm",
    }
    assert max(registry["ROBUST_FILTER_K"]["choices"]) <= train.MAX_ROBUST_FILTER_K
    assert registry["DAGGER_DISPERSED"] == {"type": "bool", "axis": "algorithm"}


def test_a_docking_run_with_the_robust_filter_flies_it_and_records_the_stress_set(tmp_path):
    """End to end, tiny: a docking run with ROBUST_FILTER_K > 0 trains as the run without it (the
    same loss) and is scored through the robust filter, which flies the near-law residual policy
    wider of the keep-out; its record carries the stress set and the robust protocol's share, on
    top and per split."""
    records = {}
    for k in (0.0, 3.0):
        family = family_copy(
            "docking",
            tmp_path / f"k{k:g}",
            N_DEMOS=4,
            EPOCHS=2,
            HIDDEN_DIM=16,
            N_LAYERS=1,
            POLICY_FORM='"residual"',
            RESIDUAL_SCALE=0.01,
            ROBUST_FILTER_K=k,
        )
        out = str(tmp_path / f"out{k:g}")
        result = run(family / "train.py", "--out", out, cache=tmp_path / "cache", check=True)
        records[k] = final_metric(result.stdout)
    nominal, record = records[0.0], records[3.0]
    assert (
        record["config"]["ROBUST_FILTER_K"] == 3.0 and record["best_train_loss"] == nominal["best_train_loss"]
    )
    assert record["min_clearance"] > nominal["min_clearance"] >= 0.0  # the robust filter's wider berth
    search = record["splits"]["search"]
    assert {"dispersed", "dispersed_3sigma", "dispersed_violating_share"} <= set(search) <= set(record)
    n_eval = load_train(family).N_EVAL
    assert search["dispersed_violating_share"] == search["dispersed"]["violating_starts"] / n_eval
    assert search["dispersed_3sigma"]["dispersions"]["nav_position"] == pytest.approx(3 * 0.05)
    assert set(search["dispersed_3sigma"]["breaking_starts"]) == {"keep_out"}


def test_the_navigation_filter_lever_puts_the_policy_and_the_filter_on_its_estimate(trains):
    """NAVIGATION_FILTER (issue 58): the family's flight software gains the navigation filter sized for
    its DISPERSIONS; a nominal flight is unchanged, a dispersed one is not (the lever is used), and a
    small random route policy through the robust filter on it keeps every constraint at 3 sigma."""
    train = trains["docking-constrained"]
    config = {**defaults(train), "POLICY_FORM": "route", "ROBUST_FILTER_K": 3.0}
    raw, on_filter = train.safety_filter(config), train.safety_filter({**config, "NAVIGATION_FILTER": True})
    assert "navigation" not in raw and on_filter["navigation"] == ErrorBounds.from_dispersions(
        train.DISPERSIONS
    )
    assert on_filter["cbf_bounds"] == raw["cbf_bounds"]
    policy = small_policy(train, "route")
    starts, goals = starts_of(train, 16)
    np.testing.assert_allclose(
        train.fly(policy, starts, goals, on_filter).states,
        train.fly(policy, starts, goals, raw).states,
        atol=1e-9,
    )
    stress = {name: train.STRESS_SCALE * value for name, value in train.DISPERSIONS.items()}
    flown = train.fly(policy, starts, goals, on_filter, stress)
    assert not np.allclose(flown.states, train.fly(policy, starts, goals, raw, stress).states)
    for depth in (flown.keep_out_depth, flown.speed_depth, flown.cone_depth):
        np.testing.assert_array_equal(depth, 0.0)
    assert train.safety_filter({**config, "RUNTIME_CBF_FILTER": False, "NAVIGATION_FILTER": True}) == {
        "navigation": on_filter["navigation"]
    }
    with pytest.raises(SystemExit, match="NAVIGATION_FILTER"):
        train.check_config({**config, "NAVIGATION_FILTER": "yes"})


def test_the_covariance_margins_lever_sizes_the_robust_filter_by_the_navigation_filter_with_its_stop_line(
    trains,
):
    """COVARIANCE_MARGINS (issue 58): with the navigation filter and the robust filter, the robust
    filter's navigation margins come from the navigation filter's covariance and it gets its stop
    line; alone, or without the robust filter, it changes nothing. A small random route policy flown
    with it at 3 sigma keeps every constraint, on margins smaller than the raw measurement's."""
    train = trains["docking-constrained"]
    config = {**defaults(train), "POLICY_FORM": "route", "ROBUST_FILTER_K": 3.0, "NAVIGATION_FILTER": True}
    on_filter = train.safety_filter(config)
    sized = train.safety_filter({**config, "COVARIANCE_MARGINS": True})
    assert sized == {**on_filter, "cbf_navigation": "covariance", "cbf_stop_line": True}
    for without in ({"NAVIGATION_FILTER": False}, {"ROBUST_FILTER_K": 0.0}, {"RUNTIME_CBF_FILTER": False}):
        alone = {**config, **without}
        assert train.safety_filter({**alone, "COVARIANCE_MARGINS": True}) == train.safety_filter(alone)
    policy = small_policy(train, "route")
    starts, goals = starts_of(train, 16)
    stress = {name: train.STRESS_SCALE * value for name, value in train.DISPERSIONS.items()}
    flown = train.fly(policy, starts, goals, sized, stress)
    for depth in (flown.keep_out_depth, flown.speed_depth, flown.cone_depth):
        np.testing.assert_array_equal(depth, 0.0)
    assert not np.allclose(flown.states, train.fly(policy, starts, goals, on_filter, stress).states)
    with pytest.raises(SystemExit, match="COVARIANCE_MARGINS"):
        train.check_config({**config, "COVARIANCE_MARGINS": 1})
