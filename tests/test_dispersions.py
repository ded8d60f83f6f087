"""Issue 28, item 4: Monte Carlo dispersions (cwh_envs.dispersions): seeded per episode, off by
default, each with the effect it names."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import cwh_envs  # noqa: F401  (registers the ids)
from cwh_envs.dispersions import Dispersions

ALL = {"thrust_scale": 0.05, "misalignment_deg": 2.0, "mass": 0.03, "nav_position": 0.1, "nav_velocity": 1e-3}


def run(env, seed, actions):
    obs, info = env.reset(seed=seed)
    observed, states = [obs], [env.unwrapped.state]
    for action in actions:
        obs, *_ = env.step(action)
        observed.append(obs)
        states.append(env.unwrapped.state)
    return info, np.array(observed), np.array(states)


@pytest.mark.parametrize("env_id", ["CWHRendezvous-v0", "CWHDockKOZ-v1"])
def test_same_seed_same_dispersions_and_the_nominal_starts(env_id):
    actions = np.random.default_rng(0).uniform(-1, 1, (20, 3)).astype(np.float32)
    first = run(Dispersions(gym.make(env_id), **ALL), 7, actions)
    again = run(Dispersions(gym.make(env_id), **ALL), 7, actions)
    other = run(Dispersions(gym.make(env_id), **ALL), 8, actions)
    nominal = run(gym.make(env_id), 7, actions)
    assert first[0]["dispersion"] == again[0]["dispersion"] != other[0]["dispersion"]
    np.testing.assert_array_equal(first[1], again[1])
    np.testing.assert_array_equal(first[2][0], nominal[2][0])  # the start is the nominal env's
    assert np.abs(first[2][-1] - nominal[2][-1]).max() > 0  # and the flight is not


def test_off_by_default_is_the_nominal_env():
    actions = np.random.default_rng(1).uniform(-1, 1, (30, 3)).astype(np.float32)
    dispersed = run(Dispersions(gym.make("CWHDockKOZ-v1")), 3, actions)
    nominal = run(gym.make("CWHDockKOZ-v1"), 3, actions)
    np.testing.assert_array_equal(dispersed[1], nominal[1])
    np.testing.assert_array_equal(dispersed[2], nominal[2])
    assert dispersed[0]["dispersion"] == {"thrust_scale": 1.0, "misalignment_deg": 0.0, "mass_scale": 1.0}


def test_each_plant_error_acts_as_named():
    env = Dispersions(gym.make("CWHRendezvous-v0"), thrust_scale=0.1, misalignment_deg=5.0, mass=0.05)
    _, info = env.reset(seed=4)
    before = env.unwrapped.state
    command = np.array([0.5, -0.2, 0.1], np.float32)
    env.step(command)
    a, b = env.unwrapped.problem.matrices()
    felt = np.linalg.lstsq(b, env.unwrapped.state - a @ before, rcond=None)[0] / env.unwrapped.problem.u_max
    draw = info["dispersion"]
    # the thrust the plant felt: the command scaled by thrust / mass and turned by the misalignment
    norm = np.linalg.norm(command.astype(np.float64))
    assert np.linalg.norm(felt) == pytest.approx(norm * draw["thrust_scale"] / draw["mass_scale"], rel=1e-6)
    # a rotation by the drawn angle about a random axis turns a vector by at most that angle
    turned = np.degrees(np.arccos(felt @ command / np.linalg.norm(felt) / norm))
    assert 0.1 < turned <= draw["misalignment_deg"] + 1e-9


def test_navigation_noise_is_on_the_observation_only():
    env = Dispersions(gym.make("CWHDockKOZ-v1"), nav_position=0.5, nav_velocity=0.01)
    env.reset(seed=5)
    errors = []
    for _ in range(200):
        obs, *_ = env.step(np.zeros(3, np.float32))
        errors.append(obs[:6] - env.unwrapped.state)
    errors = np.array(errors)
    assert errors[:, :3].std() == pytest.approx(0.5, rel=0.15)
    assert errors[:, 3:].std() == pytest.approx(0.01, rel=0.15)
    nominal = gym.make("CWHDockKOZ-v1")
    nominal.reset(seed=5)
    for _ in range(200):
        nominal.step(np.zeros(3, np.float32))
    np.testing.assert_array_equal(nominal.unwrapped.state, env.unwrapped.state)  # the plant is untouched


@pytest.mark.parametrize(
    "bad", [{"mass": -0.1}, {"thrust_scale": float("inf")}, {"nav_position": True}, {"mass": 0.6}]
)
def test_bad_spreads_are_refused(bad):
    with pytest.raises(ValueError, match="must"):
        Dispersions(gym.make("CWHDockKOZ-v1"), **bad)


@pytest.mark.parametrize("env_id", ["CWHRendezvous-v0", "CWHDockKOZ-v1"])
def test_the_env_option_is_the_wrapper(env_id):
    actions = np.random.default_rng(2).uniform(-1, 1, (25, 3)).astype(np.float32)
    wrapped = run(Dispersions(gym.make(env_id), **ALL), 11, actions)
    option = run(gym.make(env_id, dispersions=ALL), 11, actions)
    assert wrapped[0]["dispersion"] == option[0]["dispersion"]
    np.testing.assert_array_equal(wrapped[1], option[1])
    np.testing.assert_array_equal(wrapped[2], option[2])
    with pytest.raises(ValueError, match="unknown dispersion"):
        gym.make(env_id, dispersions={"thrust": 0.1})


def test_fly_draws_what_the_wrapped_env_draws_start_by_start():
    from cwh_envs.controllers import pd_action
    from cwh_envs.datasets import start_pool
    from cwh_envs.problems import DockingProblem
    from cwh_envs.rollout import fly
    from cwh_envs.wrappers import CBFSafetyFilter

    problem = DockingProblem()
    pool = start_pool("docking", 4, problem)
    law = lambda obs: pd_action(obs, problem)  # noqa: E731
    flight = fly(problem, law, pool.starts, pool.goals, cbf_margin=0.5, dispersions=ALL, dispersion_seed=40)
    nominal = fly(problem, law, pool.starts, pool.goals, cbf_margin=0.5)
    for i in range(4):
        env = CBFSafetyFilter(Dispersions(gym.make("CWHDockKOZ-v1"), **ALL))
        obs, _ = env.reset(seed=40 + i, options={"initial_state": pool.starts[i], "goal": pool.goals[i]})
        states = [env.unwrapped.state]
        done = False
        while not done:
            obs, _, done, truncated, _ = env.step(law(obs[None])[0])
            states.append(env.unwrapped.state)
            done = done or truncated
        np.testing.assert_array_equal(np.array(states), flight.states[i])
    assert np.abs(flight.terminal_distance - nominal.terminal_distance).max() > 0


def test_the_dispersed_env_passes_gymnasiums_checker():
    from gymnasium.utils.env_checker import check_env

    check_env(gym.make("CWHDockKOZ-v1", dispersions=ALL).unwrapped, skip_render_check=True)
