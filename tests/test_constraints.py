"""Issue 28, item 1: the docking env's optional speed limit and approach cone (cwh_envs.constraints)."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import cwh_envs  # noqa: F401  (registers the ids)
from cwh_envs.constraints import cone_terms, speed_margin
from cwh_envs.problems import DockingProblem

LIMITS = {"speed_limit": (0.01, 0.00226), "approach_cone": (30.0, 15.0)}
GOAL = np.array([8.0, 0.0, 0.0])  # the docking axis is +x


def stepped(state, action=(0.0, 0.0, 0.0), env_id="CWHDockKOZ-v1", **kwargs):
    """(info at reset, info after one step) from ``state`` with goal GOAL."""
    env = gym.make(env_id, **kwargs)
    _, first = env.reset(seed=0, options={"initial_state": np.asarray(state, float), "goal": GOAL})
    _, reward, _, _, info = env.step(np.asarray(action, np.float32))
    return env, first, reward, info


def test_the_defaults_are_the_papers_problem():
    _, first, _, info = stepped([40.0, 0, 0, 0, 0, 0])
    assert DockingProblem().speed_limit is None and DockingProblem().approach_cone is None
    assert set(first) == {"distance", "speed", "clearance", "in_koz"}
    assert set(info) == {"distance", "speed", "clearance", "in_koz", "cost", "reward_terms"}
    assert set(info["reward_terms"]) == {"progress", "effort", "terminal", "keep_out"}


def test_the_speed_limit_costs_each_step_over_it():
    # 20 m from the port the limit is 0.01 + 0.00226 * 20 = 0.0552 m/s.
    fast, slow = [28.0, 0, 0, -0.2, 0, 0], [28.0, 0, 0, -0.03, 0, 0]
    env, first, reward, info = stepped(fast, speed_limit=LIMITS["speed_limit"])
    core = env.unwrapped._core
    expected = 0.01 + 0.00226 * np.linalg.norm(core.states[0, :3] - GOAL) - np.linalg.norm(core.states[0, 3:])
    assert info["speed_margin"] == pytest.approx(expected) and expected < 0
    assert first["speed_margin"] == pytest.approx(0.01 + 0.00226 * 20.0 - 0.2)
    assert (info["cost_speed"], info["cost_keep_out"], info["cost"]) == (1.0, 0.0, 1.0)
    assert info["reward_terms"]["speed"] == -1.0 and sum(info["reward_terms"].values()) == pytest.approx(
        reward
    )
    _, _, _, info = stepped(slow, speed_limit=LIMITS["speed_limit"], speed_weight=3.0)
    assert info["speed_margin"] > 0 and info["cost_speed"] == 0.0 and info["reward_terms"]["speed"] == 0.0
    _, _, _, info = stepped(fast, speed_limit=LIMITS["speed_limit"], speed_weight=3.0)
    assert info["reward_terms"]["speed"] == -3.0
    assert "cost_cone" not in info and "cone_angle" not in info  # only the constraints asked for


@pytest.mark.parametrize(
    ("offset", "region", "broken"),
    [
        ([10.0, 0.0, 0.0], True, False),  # on the axis, outside the chief: inside the cone
        ([8.0, 5.0, 0.0], True, True),  # 32 degrees off the axis
        ([8.0, 4.0, 0.0], True, False),  # 26.6 degrees
        ([-2.0, 9.0, 0.0], True, True),  # beside the port, toward the chief's side
        ([0.0, 20.0, 0.0], False, False),  # outside the region: the cone does not apply
    ],
)
@pytest.mark.parametrize(
    ("env_id", "setback"), [("CWHDockKOZ-v0", 0.0), ("CWHDockKOZ-v1", 0.1 / np.tan(np.radians(30)))]
)
def test_the_approach_cone_costs_a_step_in_its_region_outside_it(offset, region, broken, env_id, setback):
    env, _, _, info = stepped(
        [*(GOAL + offset), 0, 0, 0], env_id=env_id, approach_cone=LIMITS["approach_cone"]
    )
    r = env.unwrapped._core.states[0, :3]  # one coasting step moves it a little
    apex = GOAL - [setback, 0.0, 0.0]  # v1: the capture envelope sets the apex behind the port
    angle = np.degrees(np.arccos((r - apex)[0] / np.linalg.norm(r - apex)))
    assert info["in_cone_region"] is region and info["cone_angle"] == pytest.approx(angle)
    assert info["cost_cone"] == float(broken) and info["cost"] == float(broken)
    assert info["reward_terms"]["cone"] == -float(broken)


def test_episode_end_reports_each_constraint_and_success_needs_all():
    env = gym.make("CWHDockKOZ-v1", **LIMITS)
    start = np.r_[GOAL + np.array([0.0, 12.0, 0.0]), 0.0, -0.1, 0.0]  # into the region from the side, fast
    env.reset(seed=0, options={"initial_state": start, "goal": GOAL})
    speed_broken = cone_broken = 0
    least_speed, least_cone = np.inf, np.inf
    for _ in range(env.unwrapped.problem.horizon):
        _, _, terminated, _, info = env.step(np.zeros(3, np.float32))
        speed_broken += info["cost_speed"]
        cone_broken += info["cost_cone"]
        least_speed = min(least_speed, info["speed_margin"])
        if info["in_cone_region"]:
            least_cone = min(least_cone, 30.0 - info["cone_angle"])
    assert terminated and speed_broken > 0 and cone_broken > 0
    assert (
        info["speed_violation_rate"] == speed_broken / 240
        and info["cone_violation_rate"] == cone_broken / 240
    )
    assert info["min_speed_margin"] == pytest.approx(least_speed) and info[
        "min_cone_margin"
    ] == pytest.approx(least_cone)
    assert info["is_success"] is False


def test_the_vector_env_reports_what_the_single_env_does():
    starts = np.array([[28.0, 0, 0, -0.2, 0, 0], [16.0, 6.0, 0, 0, 0, 0], [40.0, -30.0, 5.0, 0.05, 0.1, 0]])
    goals = np.tile(GOAL, (3, 1))
    vector = gym.make_vec("CWHDockKOZ-v1", num_envs=3, vectorization_mode="vector_entry_point", **LIMITS)
    vector.reset(seed=0, options={"initial_state": starts, "goal": goals})
    actions = np.random.default_rng(0).uniform(-1, 1, (5, 3, 3)).astype(np.float32)
    singles = [gym.make("CWHDockKOZ-v1", **LIMITS) for _ in range(3)]
    for env, start in zip(singles, starts, strict=True):
        env.reset(seed=0, options={"initial_state": start, "goal": GOAL})
    for batch in actions:
        _, _, _, _, infos = vector.step(batch)
        for i, env in enumerate(singles):
            _, _, _, _, info = env.step(batch[i])
            for key in ("speed_margin", "cone_angle", "cost_speed", "cost_cone", "cost"):
                assert infos[key][i] == info[key], key


def test_the_constraint_functions_match_their_definitions():
    rng = np.random.default_rng(1)
    states, goals = rng.normal(0, 10, (64, 6)), rng.normal(0, 8, (64, 3))
    margin = speed_margin(states, goals, (0.02, 0.003))
    d = np.linalg.norm(states[:, :3] - goals, axis=1)
    np.testing.assert_allclose(margin, 0.02 + 0.003 * d - np.linalg.norm(states[:, 3:], axis=1))
    region, slack, angle = cone_terms(states, goals, (25.0, 12.0))
    axis = goals / np.linalg.norm(goals, axis=1, keepdims=True)
    cosine = np.einsum("ij,ij->i", axis, states[:, :3] - goals) / d
    np.testing.assert_allclose(angle, np.degrees(np.arccos(cosine)))
    np.testing.assert_array_equal(slack < 0, angle > 25.0)
    np.testing.assert_array_equal(region, d <= 12.0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"speed_limit": (0.0, 0.001)}, "needs v0 > 0"),
        ({"speed_limit": (0.01, -1.0)}, "v1 >= 0"),
        ({"speed_limit": "fast"}, "must be a pair of numbers"),
        ({"speed_limit": (0.01, float("nan"))}, "must be finite"),
        ({"approach_cone": (90.0, 10.0)}, "0 < half_angle < 90"),
        ({"approach_cone": (30.0, 0.0)}, "radius > 0"),
    ],
)
def test_bad_constraints_are_refused_by_name(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make("CWHDockKOZ-v1", **kwargs)


@pytest.mark.needs("sb3")
def test_the_constrained_env_passes_gymnasiums_and_sb3s_checkers():
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(gym.make("CWHDockKOZ-v1", **LIMITS).unwrapped, skip_render_check=True)
        sb3_check_env(gym.make("CWHDockKOZ-v1", **LIMITS), warn=True)
