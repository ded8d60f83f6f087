"""Issue 58, items 1 and 2: the capture envelope at the port, the depth of every violation, and
dispersed flights whose filter acts on the navigation estimate."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import cwh_envs
from cwh_envs import splits
from cwh_envs.constraints import CAPTURE_RADIUS, cone_apex, cone_depth, cone_terms, violation_depths
from cwh_envs.dispersions import Dispersions
from cwh_envs.problems import DockingProblem
from cwh_envs.rollout import fly

CONE = (30.0, 15.0)
GOAL = np.array([8.0, 0.0, 0.0])  # the docking axis is +x
CONSTRAINED = dict(speed_limit=(0.01, 2 * DockingProblem().n), approach_cone=CONE)


def at(dx, dy, dz):
    """A chaser at rest at GOAL + (dx, dy, dz)."""
    return np.r_[GOAL + np.array([dx, dy, dz]), 0.0, 0.0, 0.0]


def hold(env_id, state, **kwargs):
    """The info after one coasting step from ``state`` (a chaser at rest stays within 1e-3 m)."""
    env = gym.make(env_id, approach_cone=CONE, **kwargs)
    env.reset(seed=0, options={"initial_state": np.asarray(state, float), "goal": GOAL})
    return env.step(np.zeros(3, np.float32))[-1]


@pytest.mark.filterwarnings("ignore:.*CWHDockKOZ-v0 is out of date")
def test_a_chaser_beside_the_axis_at_the_port_is_captured_under_v1_and_outside_the_cone_under_v0():
    beside = at(0.002, 0.05, 0.0)  # 5 cm off the axis, 2 mm out from the port
    assert hold("CWHDockKOZ-v0", beside)["cost_cone"] == 1.0
    assert hold("CWHDockKOZ-v1", beside)["cost_cone"] == 0.0
    wide = at(0.002, 0.15, 0.0)  # 15 cm off: beyond the 0.1 m envelope
    assert hold("CWHDockKOZ-v1", wide)["cost_cone"] == 1.0
    assert gym.make("CWHDockKOZ-v1").unwrapped.problem.capture_radius == CAPTURE_RADIUS == 0.1


def test_the_corridor_is_capture_radius_wide_at_the_port():
    problem = DockingProblem(approach_cone=CONE, capture_radius=0.2)
    apex = cone_apex(GOAL[None], CONE, 0.2)[0]
    np.testing.assert_allclose(apex, GOAL - [0.2 / np.tan(np.radians(30.0)), 0, 0])
    at_port = np.array([at(0.0, r, 0.0) for r in (0.199, 0.201)])
    _, slack, _ = cone_terms(at_port, np.tile(GOAL, (2, 1)), CONE, problem.capture_radius)
    assert slack[0] > 0 > slack[1]


def test_cone_depth_is_the_euclidean_distance_to_the_corridor():
    goals = np.tile(GOAL, (4, 1))
    # From the apex at GOAL (capture 0): 45 degrees off at 2 m; behind the apex; inside; out of the zone.
    points = np.array(
        [
            np.r_[GOAL + 2.0 * np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0]), 0, 0, 0],
            at(-3.0, 0.0, 0.0),
            at(5.0, 1.0, 0.0),
            at(0.0, 20.0, 0.0),
        ]
    )
    depth = cone_depth(points, goals, CONE)
    np.testing.assert_allclose(depth, [2.0 * np.sin(np.radians(15.0)), 3.0, 0.0, 0.0], atol=1e-12)


def test_every_constraint_reports_its_deepest_violation_at_the_episode_end():
    env = gym.make("CWHDockKOZ-v1", **CONSTRAINED)
    # Driven straight at the chief through the port's region, fast: all three constraints break.
    env.reset(seed=0, options={"initial_state": np.array([20.0, 3.0, 0.0, -0.3, 0.0, 0.0]), "goal": GOAL})
    deepest = {"keep_out": 0.0, "speed": 0.0, "cone": 0.0}
    problem = env.unwrapped.problem
    done = False
    while not done:
        _, _, done, _, info = env.step(np.zeros(3, np.float32))
        state = env.unwrapped.state[None]
        for name, depth in violation_depths(state, GOAL[None], problem).items():
            deepest[name] = max(deepest[name], float(depth[0]))
    assert all(value > 0 for value in deepest.values())
    assert (
        info["keep_out_depth"] == pytest.approx(deepest["keep_out"]) == pytest.approx(-info["min_clearance"])
    )
    assert info["speed_depth"] == pytest.approx(deepest["speed"]) == pytest.approx(-info["min_speed_margin"])
    assert info["cone_depth"] == pytest.approx(deepest["cone"])


def test_a_clean_flight_reports_zero_depths():
    problem = DockingProblem()
    from cwh_envs.datasets import start_pool

    pool = start_pool("docking", 2, problem)
    from cwh_envs.controllers import MinEnergyFeedback

    flight = fly(problem, MinEnergyFeedback(problem), pool.starts, pool.goals, cbf_margin=0.5)
    assert flight.keep_out_depth is not None and np.all(flight.keep_out_depth == 0.0)
    assert flight.speed_depth is None and flight.cone_depth is None  # the problem has neither


def test_the_capture_radius_is_scoring_only_so_the_shipped_splits_serve_every_envelope():
    for capture in (0.0, 0.1, 0.5):
        problem = DockingProblem(**CONSTRAINED, capture_radius=capture)
        assert splits.find("docking", problem, "test")["identity"] == "e0d45611f81d3533"


@pytest.mark.parametrize(
    ("capture", "message"),
    [
        (-0.1, "finite number of metres >= 0"),
        (float("nan"), "finite"),
        (True, "finite"),
        (15.0, "zone radius"),
    ],
)
def test_a_bad_capture_radius_is_refused_by_name(capture, message):
    with pytest.raises(ValueError, match=f"capture_radius.*{message}"):
        DockingProblem(approach_cone=CONE, capture_radius=capture)


NAV = {"nav_position": 0.05, "nav_velocity": 5e-4}


def flights_under_noise():
    from cwh_envs.controllers import pd_action
    from cwh_envs.datasets import start_pool

    problem = DockingProblem()
    pool = start_pool("docking", 3, problem)
    law = lambda obs: pd_action(obs, problem)  # noqa: E731
    common = dict(cbf_margin=0.5, dispersions=NAV, dispersion_seed=7)
    return (
        problem,
        pool,
        law,
        {
            sees: fly(problem, law, pool.starts, pool.goals, filter_sees=sees, **common)
            for sees in ("estimate", "truth")
        },
    )


def test_under_noise_the_filter_acts_on_the_estimate_and_truth_is_an_explicit_comparison():
    _problem, pool, law, flights = flights_under_noise()
    assert np.abs(flights["estimate"].states - flights["truth"].states).max() > 1e-6
    for sees, wrapped in (
        ("estimate", lambda: cwh_envs.CBFSafetyFilter(Dispersions(gym.make("CWHDockKOZ-v1"), **NAV))),
        (
            "truth",
            lambda: cwh_envs.CBFSafetyFilter(Dispersions(gym.make("CWHDockKOZ-v1"), **NAV), sees="truth"),
        ),
        ("estimate", lambda: cwh_envs.CBFSafetyFilter(gym.make("CWHDockKOZ-v1", dispersions=NAV))),
    ):
        env = wrapped()
        obs, _ = env.reset(seed=7, options={"initial_state": pool.starts[0], "goal": pool.goals[0]})
        states, done = [env.unwrapped.state], False
        while not done:
            estimate = env.get_wrapper_attr("navigation_state")
            np.testing.assert_allclose(estimate[:3], obs[:3], atol=1e-4)  # what the policy was shown
            obs, _, done, _, _ = env.step(law(obs[None])[0])
            states.append(env.unwrapped.state)
        np.testing.assert_array_equal(np.array(states), flights[sees].states[0])


def test_without_dispersions_the_estimate_is_the_state():
    env = cwh_envs.CBFSafetyFilter(gym.make("CWHDockKOZ-v1"))
    env.reset(seed=3)
    np.testing.assert_array_equal(env.get_wrapper_attr("navigation_state"), env.unwrapped.state)
    with pytest.raises(ValueError, match="sees must be one of"):
        cwh_envs.CBFSafetyFilter(gym.make("CWHDockKOZ-v1"), sees="oracle")
    with pytest.raises(ValueError, match="filter_sees must be one of"):
        start = np.array([[50.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
        fly(DockingProblem(), lambda o: np.zeros((1, 3)), start, GOAL[None], filter_sees="x")
