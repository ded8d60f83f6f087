"""Cheap resets: the cached start pools, and the vector env's per-row pooled draws and same-step autoreset.

With ``start_pool`` a row of the native vector env is exactly a single env seeded ``seed + i``, so
the native env and ``SyncVectorEnv`` of single envs must agree bit for bit through autoresets, in
both of Gymnasium's autoreset modes.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode

import cwh_envs
from cwh_envs.datasets import CacheMiss, start_pool
from cwh_envs.experts import solve_rendezvous_many
from cwh_envs.problems import DockingProblem, RendezvousProblem

IDS = ("CWHRendezvous-v0", "CWHDockKOZ-v1")
TASKS = {"CWHRendezvous-v0": "rendezvous", "CWHDockKOZ-v1": "docking"}
POOL = 64
N = 4


def test_pool_is_screened_nested_cached_and_read_only(tmp_path):
    small = start_pool("rendezvous", 16, cache_dir=tmp_path)
    large = start_pool("rendezvous", 32, cache_dir=tmp_path)
    np.testing.assert_array_equal(large.starts[:16], small.starts)  # nested in n
    assert start_pool("rendezvous", 16, cache_dir=tmp_path) is small  # memoised in the process
    assert len(list(tmp_path.glob("start_pool-rendezvous-*.npz"))) == 2
    with pytest.raises(ValueError, match="read-only"):
        small.starts[0, 0] = 1.0
    assert solve_rendezvous_many(small.starts, RendezvousProblem())[2].all()  # the expert's screen
    assert np.all(np.abs(small.starts[:, :3]) <= RendezvousProblem().position_box)
    with pytest.raises(CacheMiss):
        start_pool("rendezvous", 17, cache_dir=tmp_path, build=False)
    docking = start_pool("docking", 16, cache_dir=tmp_path)
    np.testing.assert_allclose(np.linalg.norm(docking.goals, axis=1), DockingProblem().goal_radius)
    # Stored and reloaded by a fresh process-level cache: the same bits.
    cwh_envs.datasets._POOLS.clear()
    np.testing.assert_array_equal(start_pool("docking", 16, cache_dir=tmp_path).starts, docking.starts)


@pytest.mark.parametrize("env_id", IDS)
def test_single_env_draws_its_start_from_the_pool_with_np_random(env_id):
    env = gym.make(env_id, start_pool=POOL)
    pool = start_pool(TASKS[env_id], POOL)
    for seed in (0, 1, 2):
        env.reset(seed=seed)
        drawn = seeding.np_random(seed)[0].integers(POOL)
        np.testing.assert_array_equal(env.unwrapped.state, pool.starts[drawn])
        if env_id == "CWHDockKOZ-v1":
            np.testing.assert_array_equal(env.unwrapped.goal, pool.goals[drawn])
    # Explicit starts still win; a docking goal alone keeps the pooled start of the same draw.
    x0 = np.array([10.0, -20.0, 5.0, 0.0, 0.01, 0.0]) * (4 if env_id == "CWHDockKOZ-v1" else 1)
    env.reset(seed=0, options={"initial_state": x0})
    np.testing.assert_array_equal(env.unwrapped.state, x0)
    if env_id == "CWHDockKOZ-v1":
        goal = np.array([0.0, 0.0, 8.0])
        env.reset(seed=1, options={"goal": goal})
        np.testing.assert_array_equal(env.unwrapped.goal, goal)
        np.testing.assert_array_equal(
            env.unwrapped.state, pool.starts[seeding.np_random(1)[0].integers(POOL)]
        )


def test_pooled_vector_resets_cover_the_pool_uniformly():
    envs = gym.make_vec(
        "CWHRendezvous-v0", num_envs=2048, vectorization_mode="vector_entry_point", start_pool=8
    )
    envs.reset(seed=0)
    pool = start_pool("rendezvous", 8)
    matches = (envs.unwrapped.states[:, None, :] == pool.starts[None]).all(axis=2)
    assert matches.sum(axis=1).tolist() == [1] * 2048  # every start is a pool row
    counts = matches.sum(axis=0)
    assert counts.min() > 2048 / 8 * 0.75  # with replacement, uniformly: 256 +- 15 each


def assert_info_equal(native: dict, sync: dict, path: str = "info") -> None:
    """Equal keys, dtypes and values; ``final_obs`` is an object array of per-row observations."""
    assert set(native) == set(sync), f"{path}: {sorted(native)} != {sorted(sync)}"
    for key, value in sync.items():
        if isinstance(value, dict):
            assert_info_equal(native[key], value, f"{path}[{key!r}]")
        elif key == "final_obs":
            assert value.dtype == native[key].dtype == object
            for a, b in zip(native[key], value, strict=True):
                assert (a is None and b is None) or np.array_equal(a, b), f"{path}[final_obs]"
        else:
            assert native[key].dtype == value.dtype, f"{path}[{key!r}] dtype"
            np.testing.assert_array_equal(native[key], value, err_msg=f"{path}[{key!r}]")


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
@pytest.mark.parametrize(
    ("env_id", "cbf"), [("CWHRendezvous-v0", False), ("CWHDockKOZ-v1", False), ("CWHDockKOZ-v1", True)]
)
def test_pooled_native_rows_equal_sync_vector_env_through_autoresets(env_id, cbf, mode):
    """Same seed, same actions, no explicit starts: every output equal to the bit, over two episodes."""
    native = gym.make_vec(
        env_id,
        num_envs=N,
        vectorization_mode="vector_entry_point",
        start_pool=POOL,
        autoreset_mode=mode,
        **({"cbf_margin": 0.5} if cbf else {}),
    )
    sync = gym.make_vec(
        env_id,
        num_envs=N,
        vectorization_mode="sync",
        vector_kwargs={"autoreset_mode": mode},
        wrappers=(cwh_envs.CBFSafetyFilter,) if cbf else None,
        start_pool=POOL,
    )
    out_native, out_sync = native.reset(seed=11), sync.reset(seed=11)
    np.testing.assert_array_equal(out_native[0], out_sync[0])
    assert_info_equal(out_native[1], out_sync[1])
    rng = np.random.default_rng(3)
    horizon = native.unwrapped.problem.horizon
    ends = 0
    for _ in range(2 * horizon + 2):
        actions = rng.uniform(-1.5, 1.5, (N, 3)).astype(np.float32)
        out_native, out_sync = native.step(actions), sync.step(actions)
        for a, b in zip(out_native[:4], out_sync[:4], strict=True):
            assert a.dtype == b.dtype
            np.testing.assert_array_equal(a, b)
        assert_info_equal(out_native[4], out_sync[4])
        ends += int(out_native[2].sum())
    assert ends == 2 * N


def test_same_step_autoreset_returns_the_next_start_and_the_final_step_in_info():
    envs = gym.make_vec(
        "CWHDockKOZ-v1", num_envs=N, vectorization_mode="vector_entry_point", autoreset_mode="SameStep"
    )
    assert envs.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    envs.reset(seed=0)
    horizon = envs.unwrapped.problem.horizon
    for _ in range(horizon):
        obs, reward, terminated, truncated, info = envs.step(np.zeros((N, 3), dtype=np.float32))
    assert terminated.all() and not truncated.any() and (reward != 0).all()  # the final step's reward
    np.testing.assert_array_equal(obs[:, -1], 1.0)  # already the next episode's first observation
    np.testing.assert_array_equal(obs[:, :6], envs.unwrapped.states.astype(np.float32))
    final_obs = np.stack(info["final_obs"])
    np.testing.assert_array_equal(final_obs[:, -1], 0.0)
    assert info["_final_info"].all() and info["final_info"]["_terminal_distance"].all()
    np.testing.assert_allclose(
        info["final_info"]["terminal_distance"],
        np.linalg.norm(final_obs[:, :3] - final_obs[:, 6:9], axis=1),
        rtol=1e-6,
    )
    assert set(info) == {"distance", "speed", "clearance", "in_koz", "final_obs", "final_info"} | {
        f"_{key}" for key in ("distance", "speed", "clearance", "in_koz", "final_obs", "final_info")
    }  # the reset info and the final step; no step-only keys for rows that restarted
    obs, reward, terminated, _, info = envs.step(np.zeros((N, 3), dtype=np.float32))
    assert not terminated.any() and "final_obs" not in info and info["_reward_terms"].all()
    np.testing.assert_allclose(obs[:, -1], (horizon - 1) / horizon)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"start_pool": 0}, "start_pool"),
        ({"start_pool": True}, "start_pool"),
        ({"start_pool": 2.5}, "start_pool"),
        ({"autoreset_mode": AutoresetMode.DISABLED}, "autoreset_mode"),
        ({"autoreset_mode": "sometimes"}, "autoreset_mode"),
    ],
)
def test_bad_pool_and_autoreset_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make_vec("CWHRendezvous-v0", num_envs=2, vectorization_mode="vector_entry_point", **kwargs)
    if "start_pool" in kwargs:
        with pytest.raises(ValueError, match=match):
            gym.make("CWHDockKOZ-v1", **kwargs)


@pytest.mark.parametrize("env_id", IDS)
def test_a_pool_beyond_the_bound_is_refused_before_anything_is_built(env_id, tmp_path, monkeypatch):
    """start_pool=10**12 used to start screening a trillion starts; now a one-line ValueError."""
    from cwh_envs.datasets import MAX_POOL

    monkeypatch.setenv("CWH_ENVS_CACHE", str(tmp_path))
    with pytest.raises(ValueError, match=f"from 1 to {MAX_POOL}"):
        gym.make(env_id, start_pool=10**12)
    with pytest.raises(ValueError, match="start_pool"):
        start_pool(TASKS[env_id], MAX_POOL + 1, cache_dir=tmp_path)
    assert not list(tmp_path.iterdir())
