"""cwh_envs.rollout: a batched flight through the env's own core ends where gym.make ends, to the bit."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import cwh_envs
from cwh_envs import dynamics
from cwh_envs.datasets import evaluation_set
from cwh_envs.problems import DockingProblem, RendezvousProblem
from cwh_envs.rollout import control_effort, fly


def linear_policy(dim: int, seed: int = 0, gain: float = 0.3):
    """A fixed nonlinear policy: float32 observations in, actions that saturate now and then."""
    weights = (
        np.random.default_rng(seed).normal(size=(dim, 3)) * gain / np.r_[np.full(dim - 1, 50.0), 1.0][:, None]
    )
    return lambda obs: np.tanh(obs.astype(np.float64) @ weights) * 1.2


def fly_one_by_one(env_id, policy, starts, goals=None, cbf_margin=None):
    """Each start in its own gym.make env; the policy is asked for every env's action in one batch."""
    envs, observations = [], []
    for i, start in enumerate(starts):
        env = gym.make(env_id)
        if cbf_margin is not None:
            env = cwh_envs.CBFSafetyFilter(env, margin=cbf_margin)
        options = {"initial_state": start} if goals is None else {"initial_state": start, "goal": goals[i]}
        envs.append(env)
        observations.append(env.reset(options=options)[0])
    done = False
    while not done:
        steps = [env.step(a) for env, a in zip(envs, policy(np.stack(observations)), strict=True)]
        observations = [s[0] for s in steps]
        done = all(s[2] for s in steps)
    return [s[4] for s in steps]


@pytest.mark.parametrize("cbf_margin", [None, 0.5])
def test_docking_flight_equals_gym_make_per_start(cbf_margin, tmp_path):
    problem = DockingProblem()
    held_out = evaluation_set("docking", 24, cache_dir=tmp_path)
    policy = linear_policy(10)
    flight = fly(problem, policy, held_out.starts, held_out.goals, cbf_margin=cbf_margin)
    infos = fly_one_by_one("CWHDockKOZ-v1", policy, held_out.starts, held_out.goals, cbf_margin)
    for key in ("terminal_distance", "terminal_speed", "violation_rate", "min_clearance", "is_success"):
        np.testing.assert_array_equal([info[key] for info in infos], getattr(flight, key), err_msg=key)
    assert flight.states.shape == (24, problem.horizon + 1, 6) and flight.thrust.shape == (
        24,
        problem.horizon,
        3,
    )
    np.testing.assert_array_equal(flight.states[:, 0], held_out.starts)
    assert np.abs(flight.thrust).max() <= problem.u_max
    assert (flight.cbf_active is None) == (cbf_margin is None)


def test_rendezvous_flight_equals_gym_make_per_start(tmp_path):
    held_out = evaluation_set("rendezvous", 24, cache_dir=tmp_path)
    policy = linear_policy(7, seed=1)
    flight = fly(RendezvousProblem(), policy, held_out.starts)
    infos = fly_one_by_one("CWHRendezvous-v0", policy, held_out.starts)
    for key in ("terminal_distance", "terminal_speed", "is_success"):
        np.testing.assert_array_equal([info[key] for info in infos], getattr(flight, key), err_msg=key)
    assert flight.violation_rate is None and flight.min_clearance is None


def test_the_step_is_batch_invariant():
    a, b = RendezvousProblem().matrices()
    rng = np.random.default_rng(0)
    x, u = rng.normal(size=(1024, 6)) * 50, rng.normal(size=(1024, 3))
    batch = dynamics.step(x, u, a, b)
    alone = np.array([dynamics.step(x[i], u[i], a, b) for i in range(1024)])
    np.testing.assert_array_equal(batch, alone)
    np.testing.assert_allclose(batch, x @ a.T + u @ b.T, rtol=1e-13)


def test_the_expert_flown_through_the_core_reproduces_its_own_effort(tmp_path):
    problem = RendezvousProblem()
    held_out = evaluation_set("rendezvous", 8, cache_dir=tmp_path)
    thrust = held_out.trajectory_thrust()

    def replay(obs):
        step = np.rint((1.0 - obs[:, -1].astype(np.float64)) * problem.horizon).astype(int)
        return thrust[np.arange(len(obs)), step] / problem.u_max

    flight = fly(problem, replay, held_out.starts)
    assert flight.terminal_distance.max() < 1e-6  # the expert ends on the target
    energy, delta_v = control_effort(flight.thrust, problem)
    expert_energy, expert_delta_v = control_effort(thrust, problem)
    np.testing.assert_allclose(energy, expert_energy, rtol=1e-12)
    np.testing.assert_allclose(delta_v, expert_delta_v, rtol=1e-12)
    hand = (np.linalg.norm(thrust[0], axis=1) * problem.dt / problem.mass).sum()
    assert delta_v[0] == pytest.approx(hand) and energy[0] == pytest.approx(
        (thrust[0] ** 2).sum() * problem.dt
    )


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda p: fly(RendezvousProblem(), p, np.zeros((0, 6))), "N >= 1"),
        (lambda p: fly(DockingProblem(), p, np.ones((2, 6))), "goals"),
        (lambda p: fly(RendezvousProblem(), p, np.zeros((2, 6)), cbf_margin=0.5), "no goals and no CBF"),
        (lambda p: fly(RendezvousProblem(), lambda o: np.full((2, 3), np.nan), np.zeros((2, 6))), "NaN"),
        (lambda p: fly(RendezvousProblem(), lambda o: np.zeros((2, 2)), np.zeros((2, 6))), "shape"),
        (lambda p: fly("docking", p, np.zeros((2, 6))), "RendezvousProblem or DockingProblem"),
        (lambda p: control_effort(np.zeros((4, 3)), RendezvousProblem()), r"\(N, H, 3\)"),
    ],
)
def test_bad_input_is_refused_with_a_clear_error(call, message):
    with pytest.raises(ValueError, match=message):
        call(lambda obs: np.zeros((len(obs), 3)))
