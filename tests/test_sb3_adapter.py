"""cwh_envs.sb3.NativeVecEnv: SB3's VecEnv contract over the native vector env, against DummyVecEnv.

Seeding, so that the two are exactly comparable: ``make_vec_env(seed=s)`` resets single env i with
``s + i`` and each env then draws every later start from its own ``np_random``. With ``start_pool``
the native env gives row i its own generator seeded ``s + i`` and draws the row's starts from the
pool exactly as the single env does (cwh_envs.vector), so the adapter and DummyVecEnv must agree
bit for bit across autoresets without any explicit starts. Without a pool the native env draws
fresh starts for all rows in one batch; there the tests give both the same initial states through
reset options and compare the first episode up to its end (the next starts differ by design).
"""

from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

from cwh_envs import CBFSafetyFilter
from cwh_envs.controllers import capped_speed_action
from cwh_envs.sb3 import NativeVecEnv

pytestmark = pytest.mark.needs("sb3")

N = 3
CASES = {  # name: env id, adapter kwargs, make_vec_env wrapper
    "rendezvous": ("cwh_envs:CWHRendezvous-v0", {}, None),
    "docking+cbf": ("cwh_envs:CWHDockKOZ-v1", {"cbf_margin": 0.5}, CBFSafetyFilter),
}


def make_pair(case: str, seed: int, **env_kwargs):
    env_id, kwargs, wrapper = CASES[case]
    adapter = VecMonitor(NativeVecEnv(env_id, N, seed=seed, **kwargs, **env_kwargs))
    dummy = make_vec_env(env_id, n_envs=N, seed=seed, env_kwargs=env_kwargs, wrapper_class=wrapper)
    return adapter, dummy


def assert_step_equal(ours, theirs, step: int) -> int:
    """obs, rewards, dones and every info (terminal_observation, episode r/l included); returns episode ends."""
    for a, b in zip(ours[:3], theirs[:3], strict=True):
        assert a.dtype == b.dtype and a.shape == b.shape, step
        np.testing.assert_array_equal(a, b, err_msg=f"step {step}")
    ends = 0
    for info, expected in zip(ours[3], theirs[3], strict=True):
        info, expected = dict(info), dict(expected)
        ours_final, theirs_final = (
            info.pop("terminal_observation", None),
            expected.pop("terminal_observation", None),
        )
        assert (ours_final is None) == (theirs_final is None), step
        if ours_final is not None:
            ends += 1
            assert ours_final.dtype == theirs_final.dtype
            np.testing.assert_array_equal(ours_final, theirs_final)
            # Monitor sums float64 rewards, VecMonitor the float32 ones: the return agrees to float32.
            episode, expected_episode = info.pop("episode"), expected.pop("episode")
            assert episode["l"] == expected_episode["l"]
            assert episode["r"] == pytest.approx(expected_episode["r"], rel=1e-5, abs=1e-4)
        assert info == expected, f"step {step}"  # Python scalars, exactly
    return ends


@pytest.mark.parametrize("case", sorted(CASES))
def test_adapter_equals_dummy_vec_env_for_the_same_seeds_and_actions(case):
    adapter, dummy = make_pair(case, seed=5, start_pool=128)
    obs = adapter.reset()
    np.testing.assert_array_equal(obs, dummy.reset())
    assert adapter.unwrapped.reset_infos == dummy.reset_infos
    problem = adapter.get_attr("problem")[0]
    rng = np.random.default_rng(0)
    ends, filtered = 0, 0
    for step in range(2 * problem.horizon + 3):
        actions = rng.uniform(-1.2, 1.2, (N, 3))
        if case == "docking+cbf":  # straight at the goal, through the keep-out: the filter must act
            actions = 0.5 * actions + capped_speed_action(obs, 0.1, problem)
        ours = adapter.step(actions.astype(np.float32))
        ends += assert_step_equal(ours, dummy.step(actions.astype(np.float32)), step)
        assert adapter.unwrapped.reset_infos == dummy.reset_infos
        obs = ours[0]
        filtered += sum(info.get("cbf_active", False) for info in ours[3])
    assert ends == 2 * N
    if case == "docking+cbf":  # the filter acted, and its keys and the cost came through
        assert filtered > 0 and {"cost", "cbf_infeasible", "cbf_correction_norm"} <= set(ours[3][0])


@pytest.mark.parametrize("case", sorted(CASES))
def test_fresh_starts_from_reset_options_equal_dummy_vec_env_to_the_episode_end(case):
    adapter, dummy = make_pair(case, seed=1)
    probe = NativeVecEnv(CASES[case][0], N, seed=2)
    probe.reset()
    options = [{"initial_state": state} for state in probe.get_attr("state")]
    if case == "docking+cbf":
        for row, goal in zip(options, probe.get_attr("goal"), strict=True):
            row["goal"] = goal
    adapter.set_options(options)
    dummy.set_options(options)
    np.testing.assert_array_equal(adapter.reset(), dummy.reset())
    np.testing.assert_array_equal(adapter.get_attr("state"), probe.get_attr("state"))
    horizon = adapter.get_attr("problem")[0].horizon
    for step in range(horizon):
        actions = np.full((N, 3), 0.1 * (step % 3 - 1), dtype=np.float32)
        ours, theirs = adapter.step(actions), dummy.step(actions)
        if step < horizon - 1:
            assert_step_equal(ours, theirs, step)
    # The last step: dones, rewards, final observations and end-of-episode infos still agree.
    np.testing.assert_array_equal(ours[1], theirs[1])
    assert ours[2].all() and theirs[2].all()
    for info, expected in zip(ours[3], theirs[3], strict=True):
        np.testing.assert_array_equal(info["terminal_observation"], expected["terminal_observation"])
        assert info["terminal_distance"] == expected["terminal_distance"]
        assert info["is_success"] == expected["is_success"] and info["TimeLimit.truncated"] is False
    np.testing.assert_array_equal(ours[0][:, -1], 1.0)  # each row already began its next episode


def test_ppo_learns_on_the_adapter_under_vec_normalize_and_vec_monitor():
    envs = VecNormalize(VecMonitor(NativeVecEnv("cwh_envs:CWHRendezvous-v0", 8, seed=0, start_pool=128)))
    model = PPO("MlpPolicy", envs, n_steps=100, batch_size=200, n_epochs=1, seed=0, device="cpu")
    model.learn(1600)
    assert model.num_timesteps == 1600
    # 200 steps per row: two 80-step episodes each, every one monitored and carrying is_success.
    assert len(model.ep_info_buffer) == len(model.ep_success_buffer) == 16
    assert all(info["l"] == 80 for info in model.ep_info_buffer)
    assert envs.obs_rms.count > 1600  # VecNormalize saw the observations (terminal ones included)


def test_info_keys_keep_only_the_named_keys_and_sb3s_own():
    envs = NativeVecEnv("CWHDockKOZ-v1", N, seed=0, start_pool=128, info_keys=("is_success", "cost"))
    envs.reset()
    assert envs.reset_infos == [{}] * N
    horizon = envs.get_attr("problem")[0].horizon
    for _ in range(horizon):
        _, _, dones, infos = envs.step(np.zeros((N, 3), dtype=np.float32))
        if not dones.any():
            assert infos == [{"cost": 0.0, "TimeLimit.truncated": False}] * N
    assert set(infos[0]) == {"cost", "is_success", "terminal_observation", "TimeLimit.truncated"}
    with pytest.raises(TypeError, match="info_keys"):
        NativeVecEnv("CWHDockKOZ-v1", N, info_keys="is_success")


def test_attributes_methods_seeding_and_errors():
    envs = NativeVecEnv("CWHDockKOZ-v1", N, start_pool=128)
    envs.seed(7)
    first = envs.reset()
    native = envs.env.unwrapped
    assert envs.get_attr("problem") == [native.problem] * N
    np.testing.assert_array_equal(envs.get_attr("state", indices=[2])[0], native.states[2])
    np.testing.assert_array_equal(envs.get_attr("goal", indices=1)[0], native.goals[1])
    assert envs.env_is_wrapped(Monitor) == [False] * N
    with pytest.raises(ValueError, match="indices must be None"):
        envs.set_attr("cbf_margin", 0.5, indices=[0])
    envs.set_attr("cbf_margin", 0.5)
    assert native.cbf_margin == 0.5
    obs, _ = envs.env_method("reset", seed=7)[0]  # once on the native env: the same seeded starts
    np.testing.assert_array_equal(obs, first)
    with pytest.raises(ValueError, match="indices must be None"):
        envs.env_method("reset", indices=[1])
    with pytest.raises(IndexError):
        envs.get_attr("problem", indices=[N])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert envs.render() is None
    assert any("render_mode" in str(w.message) for w in caught)
    with pytest.raises(TypeError, match="autoreset_mode"):
        NativeVecEnv("CWHDockKOZ-v1", N, autoreset_mode="NextStep")
    envs.set_options([{"goal": [0.0, 0.0, 8.0]}, {}, {}])
    with pytest.raises(ValueError, match="same option keys"):
        envs.reset()
    envs.close()


def test_import_cwh_envs_does_not_import_stable_baselines3():
    code = (
        "import sys, gymnasium as gym, cwh_envs; "
        "gym.make_vec('CWHRendezvous-v0', num_envs=2, vectorization_mode='vector_entry_point').reset(seed=0); "
        "print(sorted(m for m in ('stable_baselines3', 'torch') if m in sys.modules))"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert result.stdout.strip() == "[]"
