"""The native vector envs: Gymnasium's vector contract and row-for-row equality with single envs."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from cwh_envs.vector import CWHDockKOZVectorEnv, CWHRendezvousVectorEnv
from cwh_envs.wrappers import CBFSafetyFilter

IDS = ("CWHRendezvous-v0", "CWHDockKOZ-v1")
N = 5


def make_native(env_id, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # make_vec warns on missing/ill-typed autoreset metadata
        return gym.make_vec(env_id, num_envs=N, vectorization_mode="vector_entry_point", **kwargs)


def starts(env_id, seed=0):
    """Per-row initial states (and goals) as reset options, drawn through the native env's sampler."""
    env = make_native(env_id)
    env.reset(seed=seed)
    options = {"initial_state": env.unwrapped.states}
    if env_id == "CWHDockKOZ-v1":
        options["goal"] = env.unwrapped.goals
    return options


def assert_info_equal(native: dict, sync: dict, path: str = "info") -> None:
    assert set(native) == set(sync), f"{path}: {sorted(native)} != {sorted(sync)}"
    for key, value in sync.items():
        if isinstance(value, dict):
            assert_info_equal(native[key], value, f"{path}[{key!r}]")
        else:
            assert native[key].dtype == value.dtype, f"{path}[{key!r}] dtype"
            np.testing.assert_allclose(native[key], value, rtol=1e-10, atol=1e-12, err_msg=f"{path}[{key!r}]")


@pytest.mark.parametrize("env_id", IDS)
def test_make_vec_builds_the_native_env_with_next_step_autoreset(env_id):
    env = make_native(env_id)
    assert isinstance(env.unwrapped, CWHRendezvousVectorEnv | CWHDockKOZVectorEnv)
    assert env.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    single = gym.make(env_id)
    assert env.single_observation_space == single.observation_space
    assert env.single_action_space == single.action_space
    assert env.observation_space.shape == (N, *single.observation_space.shape)
    obs, info = env.reset(seed=0)
    assert obs in env.observation_space
    assert {f"_{key}" for key in info if not key.startswith("_")} == {
        key for key in info if key.startswith("_")
    }
    obs2, *_ = env.step(env.action_space.sample())
    assert obs2 in env.observation_space and obs2 is not obs


@pytest.mark.parametrize(
    ("env_id", "cbf"),
    [("CWHRendezvous-v0", False), ("CWHDockKOZ-v1", False), ("CWHDockKOZ-v1", True)],
)
def test_native_rows_equal_single_envs_under_sync_vector_env(env_id, cbf):
    """Same starts, same actions: obs, rewards, terminations and the whole info dict agree."""
    horizon = 6
    native = make_native(env_id, horizon=horizon, **({"cbf_margin": 0.5} if cbf else {}))
    sync = gym.make_vec(
        env_id,
        num_envs=N,
        vectorization_mode="sync",
        wrappers=(CBFSafetyFilter,) if cbf else None,
        horizon=horizon,
    )
    options = starts(env_id)
    if cbf:  # put some rows on a collision course so the filter acts
        options["initial_state"][:3] = [
            [12.0, 0, 0, -1.0, 0, 0],
            [0, -9.0, 0, 0, 0.8, 0],
            [7.0, 7.0, 0, -0.5, -0.5, 0],
        ]
    native.reset(seed=0, options=options)
    sync.reset(seed=0, options={key: value[0] for key, value in options.items()})
    for i, sub in enumerate(sync.envs):  # SyncVectorEnv passes one options dict to every row
        sub.reset(options={key: value[i] for key, value in options.items()})
    rng = np.random.default_rng(1)
    active = 0
    for _ in range(horizon):
        actions = rng.uniform(-1.5, 1.5, (N, 3)).astype(np.float32)
        out_native = native.step(actions)
        out_sync = sync.step(actions)
        for a, b in zip(out_native[:4], out_sync[:4], strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-9)
            assert a.dtype == b.dtype
        assert_info_equal(out_native[4], out_sync[4])
        active += out_native[4].get("cbf_active", np.zeros(N)).sum()
    assert out_native[2].all() and not out_native[3].any()
    assert set(out_native[4]) >= {"terminal_distance", "_terminal_distance", "is_success"}
    if cbf:
        assert active > 0


@pytest.mark.parametrize("env_id", IDS)
def test_next_step_autoreset(env_id):
    env = make_native(env_id)
    horizon = env.unwrapped.problem.horizon
    env.reset(seed=0)
    for _ in range(horizon):
        obs, reward, terminated, truncated, info = env.step(np.ones((N, 3), dtype=np.float32))
    assert terminated.all() and not truncated.any()
    assert info["_terminal_distance"].all() and info["_reward_terms"].all()
    np.testing.assert_array_equal(obs[:, -1], 0.0)
    # The next call ignores the actions of the finished rows and starts new episodes.
    obs, reward, terminated, truncated, info = env.step(np.ones((N, 3), dtype=np.float32))
    np.testing.assert_array_equal(obs[:, -1], 1.0)
    np.testing.assert_array_equal(obs[:, :6], env.unwrapped.states.astype(np.float32))
    assert not terminated.any() and not truncated.any() and (reward == 0.0).all()
    state_keys = {"distance", "speed"} | ({"clearance", "in_koz"} if env_id == "CWHDockKOZ-v1" else set())
    assert set(info) == state_keys | {f"_{key}" for key in state_keys}  # exactly the reset info
    obs, reward, terminated, _, info = env.step(np.ones((N, 3), dtype=np.float32))
    assert not terminated.any() and (reward != 0.0).all() and info["_reward_terms"].all()
    np.testing.assert_allclose(obs[:, -1], (horizon - 1) / horizon)


@pytest.mark.parametrize("env_id", IDS)
def test_vector_seeding_is_deterministic(env_id):
    runs = []
    for seed in (7, 7, 8):
        env = make_native(env_id)
        obs, _ = env.reset(seed=seed)
        trace = [obs]
        for _ in range(env.unwrapped.problem.horizon + 2):  # through one autoreset: a fresh draw
            trace.append(env.step(np.full((N, 3), 0.3, dtype=np.float32))[0])
        runs.append(np.array(trace))
    np.testing.assert_array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0][0], runs[2][0])


@pytest.mark.parametrize(
    ("kwargs", "options", "error", "match"),
    [
        ({"num_envs": 0}, None, ValueError, "num_envs"),
        ({"render_mode": "rgb_array"}, None, ValueError, "render"),
        ({"cbf_margin": -0.1}, None, ValueError, "margin"),
        ({}, {"initial_state": np.zeros((N + 1, 6))}, ValueError, "shape"),
        ({}, {"goal": np.tile([1.0, 0.0, 0.0], (N, 1))}, ValueError, "keep-out"),
        ({}, {"seed": 3}, ValueError, "unknown reset option"),
    ],
)
def test_vector_bad_arguments(kwargs, options, error, match):
    with pytest.raises(error, match=match):
        env = CWHDockKOZVectorEnv(**{"num_envs": N, **kwargs})
        env.reset(options=options)


def test_vector_step_validation():
    env = make_native("CWHRendezvous-v0")
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros((N, 3)))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.full((N, 3), np.nan))
