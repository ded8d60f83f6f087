"""Residual RL (issue 60): cwh_envs.sb3.ResidualVecEnv flies the agent's action as a bounded
correction on a base law, and residual_policy flies a trained correction the same way."""

from __future__ import annotations

import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

from cwh_envs.controllers import MinEnergyFeedback
from cwh_envs.problems import DockingProblem
from cwh_envs.rollout import fly
from cwh_envs.sb3 import NativeVecEnv, ResidualVecEnv, residual_policy

pytestmark = pytest.mark.needs("sb3")

ENV = "cwh_envs:CWHDockKOZ-v1"
PROBLEM = DockingProblem()
N = 3


def native(seed: int = 0) -> NativeVecEnv:
    return NativeVecEnv(ENV, N, seed=seed, cbf_margin=PROBLEM.margin, start_pool=64)


def test_a_zero_correction_flies_the_base_law_exactly_as_fly_does():
    law = MinEnergyFeedback(PROBLEM)
    envs = ResidualVecEnv(native(), law, 0.2)
    envs.reset()
    starts = np.array(envs.get_attr("state"))
    goals = np.array(envs.get_attr("goal"))
    for _ in range(PROBLEM.horizon - 1):  # the last step would autoreset the rows
        envs.step(np.zeros((N, 3), dtype=np.float32))
    flight = fly(PROBLEM, law, starts, goals, cbf_margin=PROBLEM.margin)
    np.testing.assert_array_equal(np.array(envs.get_attr("state")), flight.states[:, PROBLEM.horizon - 1])


def test_the_flown_action_is_the_base_plus_the_scaled_clipped_correction():
    law = MinEnergyFeedback(PROBLEM)
    residual, plain = ResidualVecEnv(native(seed=3), law, 0.5), native(seed=3)
    obs, same = residual.reset(), plain.reset()
    np.testing.assert_array_equal(obs, same)
    correction = np.array([[3.0, -0.4, 0.2], [-1.0, 1.0, 0.0], [0.1, 0.1, -2.0]], dtype=np.float32)
    flown = np.clip(law(obs) + 0.5 * np.clip(correction, -1, 1), -1, 1)
    ours = residual.step(correction)
    theirs = plain.step(flown)
    np.testing.assert_array_equal(ours[0], theirs[0])
    np.testing.assert_array_equal(ours[1], theirs[1])


def test_residual_policy_flies_the_same_composition():
    law = MinEnergyFeedback(PROBLEM)
    envs = native()
    envs.reset()
    starts, goals = np.array(envs.get_attr("state")), np.array(envs.get_attr("goal"))

    def nudge(obs):
        return np.tile([0.3, -0.2, 0.9], (len(obs), 1))

    flown = fly(PROBLEM, residual_policy(law, nudge, 0.1), starts, goals)
    by_hand = fly(PROBLEM, lambda obs: np.clip(law(obs) + 0.1 * nudge(obs), -1, 1), starts, goals)
    np.testing.assert_array_equal(flown.states, by_hand.states)
    assert not np.array_equal(flown.states, fly(PROBLEM, law, starts, goals).states)


@pytest.mark.parametrize("scale", [0, -0.1, 2.5, True, "0.2", float("nan")])
def test_a_bad_scale_is_refused_by_name(scale):
    with pytest.raises(ValueError, match="scale must be a number in"):
        ResidualVecEnv(native(), MinEnergyFeedback(PROBLEM), scale)
    with pytest.raises(ValueError, match="scale must be a number in"):
        residual_policy(MinEnergyFeedback(PROBLEM), MinEnergyFeedback(PROBLEM), scale)


def test_stepping_before_reset_is_refused_and_ppo_learns_under_vec_normalize():
    envs = ResidualVecEnv(VecMonitor(native()), MinEnergyFeedback(PROBLEM), 0.2)
    with pytest.raises(RuntimeError, match="before reset"):
        envs.step_async(np.zeros((N, 3)))
    model = PPO("MlpPolicy", VecNormalize(envs), n_steps=32, batch_size=32, n_epochs=1, seed=0)
    model.learn(96)
    assert model.num_timesteps == 96
