"""Issue 28, item 2: the docking expert under the speed limit and the approach cone, and the env
agreeing with it (one physics): its thrust flown through the constrained env costs nothing."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import cwh_envs  # noqa: F401  (registers the ids)
from cwh_envs.constraints import cone_terms, speed_margin
from cwh_envs.datasets import evaluation_starts
from cwh_envs.experts import Infeasible, scp_docking
from cwh_envs.problems import DockingProblem

SPEED = (0.01, 0.00226)  # v1 = 2n: ACT3's docking limit
CONE = (30.0, 15.0)


@pytest.fixture(scope="module")
def starts():
    states, goals = evaluation_starts("docking", 8, DockingProblem())
    return states, goals


def fly_in_env(problem: DockingProblem, x0, goal, thrust) -> dict:
    """The final info of the expert's thrust flown open loop through CWHDockKOZ-v1 with the problem's
    constraints (the same keyword arguments)."""
    kwargs = {k: v for k, v in problem.as_dict().items() if v is not None}
    env = gym.make("CWHDockKOZ-v1", **kwargs)
    env.reset(options={"initial_state": x0, "goal": goal})
    costs = 0.0
    for u in thrust:
        _, _, terminated, _, info = env.step(u / problem.u_max)  # float64: the expert's own thrust
        costs += info["cost"]
    assert terminated
    return {**info, "costs": costs}


@pytest.mark.parametrize(
    ("limits", "case"),
    [({"speed_limit": SPEED}, 0), ({"approach_cone": CONE}, 0), ({"approach_cone": CONE}, 1)],
)
def test_each_constraint_binds_and_holds(starts, limits, case):
    x0, goal = starts[0][case], starts[1][case]
    plain = scp_docking(x0, goal, DockingProblem())
    problem = DockingProblem(**limits)
    solution = scp_docking(x0, goal, problem)
    after = solution.states[1:]
    goals = np.broadcast_to(goal, (len(after), 3))
    if "speed_limit" in limits:
        # the plain expert breaks the limit; the constrained one is tight against it and within it
        assert speed_margin(plain.states[1:], goals, SPEED).min() < 0
        assert 0 <= speed_margin(after, goals, SPEED).min() < 1e-4
    else:
        region, slack, angle = cone_terms(plain.states[1:], goals, CONE)
        assert (region & (slack < 0)).any()  # the plain expert arrives outside the cone
        region, slack, angle = cone_terms(after, goals, CONE)
        assert np.all(slack[region] >= -1e-9) and angle[region].max() <= 30.0
    assert np.linalg.norm(after[:, :3], axis=1).min() >= problem.koz_radius + problem.margin - 1e-6
    np.testing.assert_allclose(solution.states[-1], [*goal, 0, 0, 0], atol=1e-6)
    assert solution.cost > plain.cost  # the constraint costs energy
    final = fly_in_env(problem, x0, goal, solution.controls)
    assert final["costs"] == 0.0 and final["is_success"]  # the env counts nothing broken


def test_both_constraints_at_once(starts):
    x0, goal = starts[0][5], starts[1][5]  # a start the combined SCP settles on in about a second
    problem = DockingProblem(speed_limit=SPEED, approach_cone=CONE)
    solution = scp_docking(x0, goal, problem)
    final = fly_in_env(problem, x0, goal, solution.controls)
    assert final["costs"] == 0.0 and final["is_success"]
    assert final["min_speed_margin"] >= 0 and final["min_cone_margin"] >= 0
    assert final["speed_violation_rate"] == final["cone_violation_rate"] == final["violation_rate"] == 0.0


def test_a_speed_limit_too_tight_for_the_horizon_is_infeasible(starts):
    x0, goal = starts[0][0], starts[1][0]
    with pytest.raises(Infeasible):
        scp_docking(x0, goal, DockingProblem(speed_limit=(1e-4, 1e-5)))
