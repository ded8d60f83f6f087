"""Issue 58, item 4: the robust MPC (cwh_envs.mpc.RecedingHorizon.robust): plans tightened by the
declared bounds, and every failed hard re-solve answered by the soft expert."""

from __future__ import annotations

import numpy as np
import pytest

from cwh_envs.mpc import RecedingHorizon, tightened
from cwh_envs.observations import docking_observation
from cwh_envs.problems import DockingProblem
from cwh_envs.robust_cbf import ErrorBounds

PROBLEM = DockingProblem(speed_limit=(0.01, 2 * DockingProblem().n), approach_cone=(30.0, 15.0), horizon=30)
BOUNDS = ErrorBounds(thrust_scale=0.02, misalignment_deg=1.0, mass=0.02, nav_position=0.05, nav_velocity=5e-4)


def test_the_plans_are_tightened_by_the_bounds_and_zero_bounds_tighten_nothing():
    planned = tightened(PROBLEM, BOUNDS)
    a, _ = PROBLEM.matrices()
    assert (
        planned.margin - PROBLEM.margin > BOUNDS.navigation(a @ a) > 0.05 * 3
    )  # at least the k-sigma nav error
    assert 0 < planned.speed_limit[0] < PROBLEM.speed_limit[0] - 3 * 5e-4
    assert planned.approach_cone == PROBLEM.approach_cone
    assert tightened(PROBLEM, ErrorBounds()) == PROBLEM
    with pytest.raises(ValueError, match="leaves no speed at the port"):
        tightened(PROBLEM, ErrorBounds(nav_velocity=0.01))
    with pytest.raises(ValueError, match="bounds must be an ErrorBounds"):
        RecedingHorizon(PROBLEM, bounds={"nav_position": 0.05})


def test_a_state_outside_the_planned_cone_is_answered_softly_never_by_a_stale_plan():
    goal = np.array([8.0, 0.0, 0.0])
    # 3 m out, 2.5 m off the axis: outside the cone inside its zone; the hard planner has no answer.
    state = np.array([11.0, 2.5, 0.0, -0.002, 0.0, 0.0])
    obs = docking_observation(state[None], goal[None], np.array([PROBLEM.horizon - 10]), PROBLEM.horizon)
    mpc = RecedingHorizon.robust(PROBLEM, BOUNDS)
    action = mpc(obs)
    assert mpc.infeasible.sum() == 1 and mpc.soft.sum() == 1 and mpc.fallbacks.sum() == 0
    assert action.shape == (1, 3) and np.all(np.abs(action) <= 1.0)
    plain = RecedingHorizon(PROBLEM)  # the default: no previous plan yet, so it too re-plans softly
    plain(obs)
    assert plain.infeasible.sum() == 1
