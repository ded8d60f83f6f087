"""The single envs against Gymnasium's and SB3's checkers, and their documented contract."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import cwh_envs
from cwh_envs.docking import CWHDockKOZEnv
from cwh_envs.problems import DockingProblem, RendezvousProblem
from cwh_envs.rendezvous import CWHRendezvousEnv

IDS = ("CWHRendezvous-v0", "CWHDockKOZ-v1")
STEP_KEYS = {
    "CWHRendezvous-v0": {"distance", "speed"},
    "CWHDockKOZ-v1": {"distance", "speed", "clearance", "in_koz"},
}
FINAL_KEYS = {
    "CWHRendezvous-v0": {"terminal_distance", "terminal_speed", "is_success"},
    "CWHDockKOZ-v1": {"terminal_distance", "terminal_speed", "is_success", "violation_rate", "min_clearance"},
}
DOCK_START = np.array([-60.0, 5.0, 3.0, 0.0, 0.0, 0.0])
DOCK_GOAL = np.array([8.0, 0.0, 0.0])
# Fixed starts for short-horizon envs: the screened samplers need the default horizons.
FIXED = {
    "CWHRendezvous-v0": {"initial_state": np.array([30.0, -20.0, 5.0, 0.01, 0.0, 0.0])},
    "CWHDockKOZ-v1": {"initial_state": DOCK_START, "goal": DOCK_GOAL},
}


def rollout(env: gym.Env, seed: int, options: dict | None = None):
    """A full episode with seeded random actions: (observations, rewards, infos)."""
    env.action_space.seed(seed)
    obs, info = env.reset(seed=seed, options=options)
    observations, rewards, infos = [obs], [], [info]
    terminated = False
    while not terminated:
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert truncated is False
        observations.append(obs)
        rewards.append(reward)
        infos.append(info)
    return np.array(observations), np.array(rewards), infos


@pytest.mark.parametrize("env_id", IDS)
def test_gymnasiums_checker_passes_without_warnings(env_id):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # The unwrapped env: gym.make's own wrappers would (rightly) trigger the wrapped-env warning.
        check_env(gym.make(env_id).unwrapped)


@pytest.mark.needs("sb3")
@pytest.mark.parametrize("env_id", IDS)
def test_sb3s_checker_passes_without_warnings(env_id):
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = gym.make(env_id)
        sb3_check_env(env.unwrapped)
        sb3_check_env(env)


def test_the_package_prefix_imports_and_registers():
    assert isinstance(gym.make("cwh_envs:CWHRendezvous-v0").unwrapped, CWHRendezvousEnv)
    assert isinstance(gym.make("CWHDockKOZ-v1").unwrapped, CWHDockKOZEnv)
    assert gym.spec("CWHRendezvous-v0").max_episode_steps is None  # the env ends its own episodes
    assert cwh_envs.CBFSafetyFilter.__name__ == "CBFSafetyFilter"


@pytest.mark.parametrize("env_id", IDS)
def test_same_seed_same_episode_different_seed_different_episode(env_id):
    obs_a, rew_a, info_a = rollout(gym.make(env_id), seed=3)
    obs_b, rew_b, info_b = rollout(gym.make(env_id), seed=3)
    obs_c, _, _ = rollout(gym.make(env_id), seed=4)
    np.testing.assert_array_equal(obs_a, obs_b)
    np.testing.assert_array_equal(rew_a, rew_b)
    assert info_a == info_b
    assert not np.array_equal(obs_a[0], obs_c[0])


@pytest.mark.parametrize("env_id", IDS)
def test_spaces_and_observation_layout(env_id):
    env = gym.make(env_id)
    dim = 7 if env_id == "CWHRendezvous-v0" else 10
    assert env.observation_space.shape == (dim,) and env.observation_space.dtype == np.float32
    assert np.all(np.isfinite(env.observation_space.low)) and np.all(np.isfinite(env.observation_space.high))
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (3,), np.float32)
    obs, _ = env.reset(seed=0)
    base = env.unwrapped
    np.testing.assert_allclose(obs[:6], base.state, rtol=1e-6)
    assert obs[-1] == 1.0
    if dim == 10:
        np.testing.assert_allclose(obs[6:9], base.goal, rtol=1e-6)
        assert np.linalg.norm(base.goal) == pytest.approx(base.problem.goal_radius)
    obs, *_ = env.step(np.zeros(3))
    assert obs[-1] == pytest.approx((base.problem.horizon - 1) / base.problem.horizon)


@pytest.mark.parametrize("env_id", IDS)
def test_episode_terminates_exactly_at_the_horizon_with_final_info(env_id):
    horizon = 12
    observations, rewards, infos = rollout(gym.make(env_id, horizon=horizon), seed=0, options=FIXED[env_id])
    assert len(rewards) == horizon
    assert observations[-1][-1] == 0.0  # tau = (H - H) / H
    assert set(infos[0]) == STEP_KEYS[env_id]
    for info in infos[1:-1]:
        assert set(info) == STEP_KEYS[env_id] | {"reward_terms"} | (
            {"cost"} if "clearance" in info else set()
        )
    final = infos[-1]
    assert FINAL_KEYS[env_id] <= set(final)
    assert final["terminal_distance"] == final["distance"]
    assert final["terminal_speed"] == final["speed"]
    assert isinstance(final["is_success"], bool)
    for info, reward in zip(infos[1:], rewards, strict=True):
        assert sum(info["reward_terms"].values()) == pytest.approx(reward, abs=1e-12)
        assert all(isinstance(v, float) for v in info["reward_terms"].values())
    assert all(info["reward_terms"]["terminal"] == 0.0 for info in infos[1:-1])


@pytest.mark.parametrize("env_id", IDS)
def test_stepping_after_the_end_or_before_reset_raises(env_id):
    env = gym.make(env_id, horizon=2).unwrapped
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(3))
    env.reset(options=FIXED[env_id])
    env.step(np.zeros(3))
    env.step(np.zeros(3))
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(3))


@pytest.mark.parametrize("discretization", ["euler", "exact"])
@pytest.mark.parametrize("env_id", IDS)
def test_step_is_the_shared_discrete_model(env_id, discretization):
    env = gym.make(env_id, discretization=discretization).unwrapped
    a, b = env.problem.matrices()
    env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(10):
        x, action = env.state, rng.uniform(-1, 1, 3).astype(np.float32)
        env.step(action)
        np.testing.assert_allclose(
            env.state, a @ x + b @ (action * env.problem.u_max), rtol=1e-12, atol=1e-12
        )


@pytest.mark.parametrize("env_id", IDS)
def test_out_of_box_actions_are_clipped(env_id):
    big, clipped = np.array([5.0, -7.0, 0.5]), np.array([1.0, -1.0, 0.5])
    results = []
    for action in (big, clipped):
        env = gym.make(env_id)
        env.reset(seed=2)
        obs, reward, *_, info = env.step(action)
        results.append((obs, reward, info))
    np.testing.assert_array_equal(results[0][0], results[1][0])
    assert results[0][1] == results[1][1] and results[0][2] == results[1][2]
    assert results[0][2]["reward_terms"]["effort"] == pytest.approx(-0.01 * (1 + 1 + 0.25))
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([np.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(4))


def test_rendezvous_reset_options_and_reward():
    env = gym.make("CWHRendezvous-v0", horizon=3)
    x0 = np.array([30.0, -40.0, 0.0, 0.0, 0.0, 0.0])
    obs, info = env.reset(seed=0, options={"initial_state": x0})
    np.testing.assert_array_equal(obs, np.r_[x0, 1.0].astype(np.float32))
    assert info == {"distance": 50.0, "speed": 0.0}
    _, reward, _, _, info = env.step(np.zeros(3))
    terms = info["reward_terms"]
    assert terms["effort"] == 0.0 and terms["terminal"] == 0.0 and reward == terms["progress"]
    assert terms["progress"] == pytest.approx(0.1 * (50.0 - info["distance"]))
    env.step(np.zeros(3))
    _, _, terminated, _, info = env.step(np.zeros(3))
    d, v = info["terminal_distance"], info["terminal_speed"]
    assert terminated and info["is_success"] is False  # 50 m out after 30 s of coasting
    assert info["reward_terms"]["terminal"] == pytest.approx(-(d / 25.0 + v / 0.05))


def test_expert_controls_succeed_in_the_env():
    """The env and the experts step the same model: replaying the expert docks exactly."""
    from cwh_envs.experts import solve_docking, solve_rendezvous

    env = gym.make("CWHRendezvous-v0")
    x0 = np.array([40.0, -30.0, 10.0, 0.01, 0.0, -0.01])
    env.reset(options={"initial_state": x0})
    _, controls = solve_rendezvous(x0)
    for u in controls:
        *_, terminated, _, info = env.step(u / env.unwrapped.problem.u_max)
    assert terminated and info["is_success"] and info["terminal_distance"] < 1e-6
    assert info["reward_terms"]["terminal"] > 9.9

    env = gym.make("CWHDockKOZ-v1")
    env.reset(options={"initial_state": DOCK_START, "goal": DOCK_GOAL})
    _, controls = solve_docking(DOCK_START, DOCK_GOAL)
    total_cost = 0.0
    for u in controls:
        *_, terminated, _, info = env.step(u / env.unwrapped.problem.u_max)
        total_cost += info["cost"]
    assert terminated and info["is_success"] and info["violation_rate"] == 0.0 and total_cost == 0.0
    assert info["min_clearance"] >= env.unwrapped.problem.margin - 1e-6


def test_docking_keep_out_accounting():
    env = gym.make("CWHDockKOZ-v1", horizon=4)
    _, info = env.reset(options={"initial_state": np.array([1.0, 0, 0, 0, 0, 0]), "goal": DOCK_GOAL})
    assert info["in_koz"] is True and info["clearance"] == pytest.approx(-4.0)
    for _ in range(4):
        _, _, terminated, _, info = env.step(np.zeros(3))
        assert info["cost"] == 1.0 and info["in_koz"] is True
        assert info["reward_terms"]["keep_out"] == -1.0
    assert terminated and info["violation_rate"] == 1.0 and info["is_success"] is False
    assert info["min_clearance"] == pytest.approx(-4.0, abs=1e-3)
    # A half-inside episode: violation_rate counts the steps that end inside the sphere.
    env.reset(options={"initial_state": np.array([5.5, 0, 0, -0.025, 0, 0]), "goal": DOCK_GOAL})
    costs = []
    for _ in range(4):
        *_, info = env.step(np.zeros(3))
        costs.append(info["cost"])
    assert info["violation_rate"] == pytest.approx(np.mean(costs)) and 0 < np.mean(costs) < 1


def test_docking_reset_options_fill_the_missing_part_from_the_sampler():
    env = gym.make("CWHDockKOZ-v1").unwrapped
    env.reset(seed=5, options={"goal": DOCK_GOAL})
    np.testing.assert_array_equal(env.goal, DOCK_GOAL)
    assert np.linalg.norm(env.state[:3]) >= 40.0 - 1e-9
    env.reset(seed=5, options={"initial_state": DOCK_START})
    np.testing.assert_array_equal(env.state, DOCK_START)


@pytest.mark.parametrize(
    ("env_id", "options", "match"),
    [
        ("CWHRendezvous-v0", {"initial_state": np.zeros(5)}, "shape"),
        ("CWHRendezvous-v0", {"initial_state": [0, 0, np.nan, 0, 0, 0]}, "finite"),
        ("CWHRendezvous-v0", {"initial_state": [2e4, 0, 0, 0, 0, 0]}, "position"),
        ("CWHRendezvous-v0", {"initial_state": "far"}, "numeric"),
        ("CWHRendezvous-v0", {"goal": DOCK_GOAL}, "unknown reset option"),
        ("CWHDockKOZ-v1", {"goal": np.zeros(2)}, "shape"),
        ("CWHDockKOZ-v1", {"goal": [3.0, 0.0, 0.0]}, "outside the keep-out"),
        ("CWHDockKOZ-v1", {"goal": [5.5, 0.0, 0.0]}, "outside the keep-out"),  # exactly at R + margin
        ("CWHDockKOZ-v1", {"initial_state": np.zeros((2, 6))}, "shape"),
    ],
)
def test_bad_reset_options_raise_value_error(env_id, options, match):
    with pytest.raises(ValueError, match=match):
        gym.make(env_id).reset(options=options)


@pytest.mark.parametrize(
    ("env_id", "kwargs", "error", "match"),
    [
        ("CWHRendezvous-v0", {"horizon": 1}, ValueError, "horizon"),
        ("CWHRendezvous-v0", {"u_max": -1.0}, ValueError, "u_max"),
        ("CWHRendezvous-v0", {"discretization": "rk4"}, ValueError, "discretization"),
        ("CWHRendezvous-v0", {"effort_weight": -0.1}, ValueError, "effort_weight"),
        ("CWHRendezvous-v0", {"koz_weight": 1.0}, TypeError, "koz_weight"),
        ("CWHDockKOZ-v1", {"goal_radius": 5.2}, ValueError, "goal_radius"),
        ("CWHDockKOZ-v1", {"koz_weight": float("nan")}, ValueError, "koz_weight"),
    ],
)
def test_bad_constructor_arguments(env_id, kwargs, error, match):
    with pytest.raises(error, match=match):
        gym.make(env_id, **kwargs)


def test_unsupported_render_mode():
    # gym.make would wrap "human" in HumanRendering; the env itself only draws rgb_array.
    with pytest.raises(ValueError, match="render_mode"):
        CWHRendezvousEnv(render_mode="human")


def test_every_problem_field_is_a_keyword_argument():
    rdzv = gym.make("CWHRendezvous-v0", **RendezvousProblem(horizon=30, u_max=0.5).as_dict()).unwrapped
    assert rdzv.problem == RendezvousProblem(horizon=30, u_max=0.5)
    dock = gym.make("CWHDockKOZ-v1", koz_radius=4.0, margin=1.0, progress_weight=0.5).unwrapped
    assert dock.problem == DockingProblem(koz_radius=4.0, margin=1.0)
    assert dock.reward_weights.progress_weight == 0.5
