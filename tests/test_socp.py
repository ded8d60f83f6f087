"""Issue 28, item 2: the constrained docking expert's convex subproblem as one Clarabel SOCP
(cwh_envs.socp), checked against two independent solvers of the same subproblem: the exact
least-distance NNLS where only the keep-out applies, and tangent-plane cuts (the polyhedral method it
replaced, kept in benchmarks/bench_expert_solvers.py) under the cone and the speed limit."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from cwh_envs import experts, socp
from cwh_envs.constraints import CONE_TOLERANCE
from cwh_envs.datasets import evaluation_starts
from cwh_envs.problems import DockingProblem

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_expert_solvers import PROBLEM, Polyhedral

PLAIN = DockingProblem()
RADIUS = PLAIN.koz_radius + PLAIN.margin


@pytest.fixture(scope="module")
def start():
    states, goals = evaluation_starts("docking", 2, PLAIN)
    return states[1], goals[1]


def anchor_of(model, x0, goal):
    """The expert's first iterate under the cone: the waypoint path, and its positions."""
    gap = model.terminal_gap(x0, np.concatenate([goal, np.zeros(3)]))
    controls = experts._waypoint_controls(model, x0, gap, goal, PROBLEM.approach_cone[1])
    return gap, model.positions(x0, controls)


def test_with_the_keepout_alone_the_socp_is_the_exact_least_distance_solve(start):
    x0, goal = start
    model = experts.linear_model(PLAIN)
    gap, positions = anchor_of(model, x0, goal)
    exact = experts._halfspace_subproblem(model, x0, gap, positions, RADIUS, PLAIN.u_max)
    path = socp.PathConstraints.about(positions, goal, PLAIN, model.horizon, model.controllable)
    assert path.speed is None and not path.held.any() and not path.away.any()
    steps = np.flatnonzero(experts._keepout_steps(model))
    conic = socp.solve(model, x0, goal, steps, experts._keepout_normals(positions), RADIUS, PLAIN.u_max, path)
    assert np.abs(conic - exact).max() < 1e-5  # N; the cost agrees far closer
    assert abs(conic @ conic - exact @ exact) <= 1e-7 * (exact @ exact)
    assert (exact @ exact) > (model.terminal_pinv @ gap) @ (model.terminal_pinv @ gap)  # the keep-out binds


@pytest.mark.parametrize("stage", ["cone", "cone and speed limit"])
def test_under_the_cone_and_speed_limit_the_socp_agrees_with_tangent_plane_cuts(start, stage):
    """Each stage's first subproblem, as the expert meets it: the cone's about the waypoint path, the
    speed limit's about the converged cone-only trajectory (the limit joins only then)."""
    x0, goal = start
    cone_only = PROBLEM.replace(speed_limit=None)
    model = experts.linear_model(PROBLEM)
    cuts = Polyhedral()
    cuts.start(x0, goal)
    if stage == "cone":
        problem, (_, positions) = cone_only, anchor_of(model, x0, goal)
    else:
        problem, solution = PROBLEM, experts.scp_docking(x0, goal, cone_only)
        positions, cuts.previous = solution.states[:, :3], solution.controls.ravel()
    conic = experts._path_subproblem(model, x0, goal, positions, RADIUS, problem, False)
    polyhedral = cuts(model, x0, goal, positions, RADIUS, problem)
    assert abs(conic @ conic - polyhedral @ polyhedral) <= 1e-6 * (polyhedral @ polyhedral)
    assert np.abs(conic - polyhedral).max() < 1e-4  # N, against thrusts of ~0.1 N
    path = socp.PathConstraints.about(
        positions, goal, problem, experts._approach_step(model), model.controllable
    )
    states = model.rollout(x0, conic)
    offset = states[:, :3] - goal
    if problem.speed_limit is not None:  # met, and tight somewhere: it binds
        v0, v1 = path.speed
        slack = (
            v0
            + v1 * np.einsum("ki,ki->k", path.unit[1:], offset[1:])
            - np.linalg.norm(states[1:, 3:], axis=1)
        )
        assert -1e-7 < slack.min() < 1e-6
    # Within Clarabel's tolerance of the tightened cone (1.1e-7 m seen with clarabel 0.9), so well
    # inside the exact one, as the env counts it.
    distance = np.linalg.norm(offset, axis=1)
    assert (offset @ path.axis - path.cosine * distance)[path.held].min() > -1e-6 and path.held.sum() > 0
    exact = np.cos(np.radians(PROBLEM.approach_cone[0]))
    assert (offset @ path.axis - exact * distance)[path.held].min() > -CONE_TOLERANCE


def test_a_subproblem_no_thrust_in_the_box_can_meet_is_infeasible_by_name(start):
    x0, goal = start
    problem = PROBLEM.replace(u_max=1e-4)  # N: far below what reaching the port takes
    model = experts.linear_model(problem)
    _, positions = anchor_of(model, x0, goal)
    with pytest.raises(experts.Infeasible, match=r"constrained subproblem: Clarabel: \w*Infeasible"):
        experts._path_subproblem(model, x0, goal, positions, RADIUS, problem, False)
