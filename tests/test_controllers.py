"""The reference controllers: the laws they state, batched and single alike, and a PD rollout."""

import gymnasium as gym
import numpy as np

from cwh_envs.controllers import capped_speed_action, pd_action
from cwh_envs.problems import DockingProblem, RendezvousProblem


def test_pd_is_the_critically_damped_law_in_box_units_and_saturates():
    problem, omega = RendezvousProblem(), 0.01
    accel_max = problem.u_max / problem.mass
    obs = np.array([2.0, -2.0, 1.0, 0.01, 0.0, -0.02, 0.5])  # rendezvous: the target is the origin
    expected = (-(omega**2) * obs[:3] - 2 * omega * obs[3:6]) / accel_max
    assert np.all(np.abs(expected) < 1)  # inside the box: the law itself
    np.testing.assert_allclose(pd_action(obs, problem), expected, rtol=1e-12)
    far = obs.copy()
    far[:3] = [1e4, -1e4, 0.0]
    np.testing.assert_array_equal(pd_action(far, problem), [-1.0, 1.0, pd_action(far, problem)[2]])
    batch = np.stack([obs, far])
    np.testing.assert_array_equal(
        pd_action(batch, problem), [pd_action(obs, problem), pd_action(far, problem)]
    )


def test_pd_aims_at_dockings_observed_goal():
    problem = DockingProblem()
    obs = np.zeros(10)
    obs[6:9] = [8.0, 0.0, 0.0]  # at rest at the origin, the goal 8 m along +x
    action = pd_action(obs, problem)
    assert action[0] > 0 and action[1] == action[2] == 0
    obs[:3] = obs[6:9]
    np.testing.assert_array_equal(pd_action(obs, problem), 0.0)  # at the goal, at rest: no thrust


def test_capped_speed_flies_at_the_goal_and_brakes_to_the_cap():
    problem = DockingProblem()
    obs = np.zeros((2, 10), dtype=np.float32)
    obs[:, 6:9] = [-8.0, 0.0, 0.0]
    obs[0, :3] = [40.0, 0.0, 0.0]  # at rest, 48 m away: accelerate toward the goal
    obs[1, :3], obs[1, 3] = [40.0, 0.0, 0.0], -0.5  # far faster than the cap: brake
    action = capped_speed_action(obs, 0.02, problem)
    assert action.dtype == np.float32 and action.shape == (2, 3)
    dv_max = problem.u_max / problem.mass * problem.dt
    np.testing.assert_allclose(action[0], [-0.02 / dv_max, 0, 0], rtol=1e-6)  # -0.5: inside the box
    np.testing.assert_array_equal(action[1], [1.0, 0.0, 0.0])


def test_pd_docks_most_starts_through_the_filter():
    envs = gym.make_vec(
        "cwh_envs:CWHDockKOZ-v1", num_envs=32, vectorization_mode="vector_entry_point", cbf_margin=0.5
    )
    obs, _ = envs.reset(seed=0)
    problem = envs.unwrapped.problem
    for _ in range(problem.horizon):
        obs, _, terminated, _, info = envs.step(pd_action(obs, problem))
    assert terminated.all() and np.mean(info["is_success"]) > 0.9
