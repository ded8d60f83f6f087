"""The experts: optimality (KKT / an independent proxsuite solve), feasibility, and failure modes."""

from __future__ import annotations

import numpy as np
import pytest
from proxsuite import proxqp

from cwh_envs import experts
from cwh_envs.experts import (
    Infeasible,
    _halfspace_subproblem,
    koz_active,
    linear_model,
    scp_docking,
    solve_docking,
    solve_rendezvous,
    solve_rendezvous_many,
)
from cwh_envs.problems import DockingProblem, RendezvousProblem
from cwh_envs.sampling import sample_docking_starts

RDZV = RendezvousProblem()
DOCK = DockingProblem()
RADIUS = DOCK.koz_radius + DOCK.margin


def reference_qp(h, g, eq, eq_rhs, rows=None, rhs=None, u_max=None):
    """A fresh, tightly converged proxsuite dense QP: min 1/2 U^T h U + g^T U s.t. eq U = eq_rhs,
    rows U >= rhs, |U| <= u_max (native box)."""
    n_in = 0 if rows is None else len(rows)
    qp = proxqp.dense.QP(len(g), len(eq_rhs), n_in, box_constraints=u_max is not None)
    qp.settings.eps_abs = 1e-10
    qp.settings.eps_rel = 0.0
    qp.settings.check_duality_gap = True
    qp.settings.eps_duality_gap_abs = 1e-10
    qp.settings.eps_duality_gap_rel = 0.0
    box = () if u_max is None else (np.full(len(g), -u_max), np.full(len(g), u_max))
    upper = None if rows is None else np.full(n_in, np.inf)
    qp.init(h, g, eq, eq_rhs, rows, rhs, upper, *box)
    qp.solve()
    assert qp.results.info.status == proxqp.QPSolverOutput.PROXQP_SOLVED
    return qp.results.x.copy()


def rendezvous_starts(n, seed):
    rng = np.random.default_rng(seed)
    half = np.concatenate([RDZV.position_box, RDZV.velocity_box])
    return rng.uniform(-half, half, size=(n, 6))


# ------------------------------------------------------------------------------------ rendezvous


def test_fast_path_is_the_closed_form_and_equals_the_qp():
    model = linear_model(RDZV)
    x0 = np.array([10.0, -20.0, 5.0, 0.01, 0.0, -0.005])
    states, controls = solve_rendezvous(x0)
    closed_form = model.min_energy(x0, np.zeros(6))
    assert np.abs(closed_form).max() < RDZV.u_max  # the box does not bind: fast path
    np.testing.assert_array_equal(controls.ravel(), closed_form)
    size = 3 * RDZV.horizon
    qp = reference_qp(np.eye(size), np.zeros(size), model.terminal, -model.powers[-1] @ x0, u_max=RDZV.u_max)
    np.testing.assert_allclose(controls.ravel(), qp, atol=1e-7)
    assert np.abs(states[-1]).max() <= 1e-9


def test_box_binding_solutions_satisfy_kkt_and_match_an_independent_solve():
    model = linear_model(RDZV)
    starts = rendezvous_starts(120, seed=1)
    states, controls, solved = solve_rendezvous_many(starts)
    binding = [i for i in np.flatnonzero(solved) if np.abs(controls[i]).max() >= RDZV.u_max - 1e-12]
    assert len(binding) >= 30
    size = 3 * RDZV.horizon
    for i in binding[:12]:
        u = controls[i].ravel()
        # KKT of min 1/2||U||^2, G U = d, |U| <= u_max: U = clip(G^T nu) for one nu.
        free = np.abs(u) < RDZV.u_max - 1e-9
        nu = np.linalg.lstsq(model.terminal[:, free].T, u[free], rcond=None)[0]
        np.testing.assert_allclose(np.clip(model.terminal.T @ nu, -RDZV.u_max, RDZV.u_max), u, atol=1e-9)
        assert np.abs(states[i, -1]).max() <= RDZV.reach_tolerance
        gap = -model.powers[-1] @ starts[i]
        np.testing.assert_allclose(
            u, reference_qp(np.eye(size), np.zeros(size), model.terminal, gap, u_max=RDZV.u_max), atol=1e-6
        )


def test_newton_and_proxsuite_paths_agree(monkeypatch):
    """With no Newton steps every box-binding start goes to proxsuite (+ polish): same answers."""
    starts = rendezvous_starts(60, seed=4)
    _, newton_controls, newton_solved = solve_rendezvous_many(starts)
    monkeypatch.setattr(experts, "NEWTON_STEPS", 0)
    _, controls, solved = solve_rendezvous_many(starts)
    np.testing.assert_array_equal(solved, newton_solved)
    np.testing.assert_allclose(controls[solved], newton_controls[solved], atol=1e-9)
    binding = np.abs(controls[solved]).max(axis=(1, 2)) >= RDZV.u_max - 1e-12
    assert binding.sum() >= 10


def test_batched_rendezvous_equals_single_solves():
    starts = rendezvous_starts(40, seed=2)
    states, controls, solved = solve_rendezvous_many(starts)
    assert solved.any() and (~solved).any()
    for i, x0 in enumerate(starts):
        if solved[i]:
            single_states, single_controls = solve_rendezvous(x0)
            np.testing.assert_allclose(single_controls, controls[i], atol=1e-12)
            np.testing.assert_allclose(single_states, states[i], atol=1e-9)
            assert np.abs(controls[i]).max() <= RDZV.u_max + 1e-9
        else:
            assert np.isnan(states[i]).all()
            with pytest.raises(Infeasible):
                solve_rendezvous(x0)


def test_unreachable_rendezvous_start_raises_infeasible():
    with pytest.raises(Infeasible):
        solve_rendezvous(np.array([0.0, 0.0, 0.0, 5.0, -5.0, 5.0]))  # 5 m/s against 0.25 N
    # A certified-infeasible start is confirmed by proxsuite.
    model = linear_model(RDZV)
    x0 = np.array([75.0, 75.0, 37.5, 0.08, 0.08, 0.04])
    with pytest.raises(Infeasible):
        solve_rendezvous(x0)
    size = 3 * RDZV.horizon
    qp = proxqp.dense.QP(size, 6, 0, box_constraints=True)
    limit = np.full(size, RDZV.u_max)
    qp.init(
        np.eye(size), np.zeros(size), model.terminal, -model.powers[-1] @ x0, None, None, None, -limit, limit
    )
    qp.solve()
    assert qp.results.info.status != proxqp.QPSolverOutput.PROXQP_SOLVED


def test_parameters_override_problem_fields():
    x0 = np.array([0.0, 0.0, 0.0, 0.3, 0.0, 0.0])
    with pytest.raises(Infeasible):
        solve_rendezvous(x0)
    states, controls = solve_rendezvous(x0, u_max=2.0, horizon=60)
    assert controls.shape == (60, 3) and np.abs(states[-1]).max() <= 1e-6
    same = solve_rendezvous(x0, problem=RendezvousProblem(u_max=2.0, horizon=60))
    np.testing.assert_array_equal(same[1], controls)


# --------------------------------------------------------------------------------------- docking


@pytest.fixture(scope="module")
def docking_cases():
    starts, goals = sample_docking_starts(np.random.default_rng(7), 24, DOCK)
    return starts, goals, [scp_docking(x0, g, DOCK) for x0, g in zip(starts, goals, strict=True)]


def test_docking_demos_are_feasible_and_hug_the_keep_out(docking_cases):
    starts, goals, solutions = docking_cases
    a, b = DOCK.matrices()
    for x0, goal, solution in zip(starts, goals, solutions, strict=True):
        states, controls = solution.states, solution.controls
        assert states.shape == (DOCK.horizon + 1, 6) and controls.shape == (DOCK.horizon, 3)
        np.testing.assert_allclose(states[1:], states[:-1] @ a.T + controls @ b.T, atol=1e-9)
        np.testing.assert_array_equal(states[0], x0)
        assert np.abs(states[-1] - np.concatenate([goal, np.zeros(3)])).max() <= 1e-6
        assert np.abs(controls).max() <= DOCK.u_max
        assert (
            np.linalg.norm(states[:, :3], axis=1).min() >= RADIUS - 1e-6
        )  # every step, not just half-spaces
        assert solution.iterations < 60
    active = koz_active(np.stack([s.states for s in solutions]), DOCK)
    assert active.mean() >= 0.8  # by construction of the screen it is 1.0


def test_docking_solution_is_a_fixed_point_of_its_convex_subproblem(docking_cases):
    """Re-linearising at the SCP answer and solving that QP independently (proxsuite, full
    constraint set) reproduces it: the answer is a KKT point of Eq. expert_rpo."""
    starts, goals, solutions = docking_cases
    model = linear_model(DOCK)
    size = 3 * DOCK.horizon
    for x0, goal, solution in list(zip(starts, goals, solutions, strict=True))[:4]:
        positions = solution.states[:, :3]
        normals = positions / np.linalg.norm(positions, axis=1, keepdims=True)
        steps = np.arange(2, DOCK.horizon)  # k = 1 does not depend on U under Euler
        rows = np.einsum("ki,kij->kj", normals[steps], model.position_response[steps])
        rhs = RADIUS - np.einsum("ki,kij,j->k", normals[steps], model.powers[steps, :3], x0)
        gap = np.concatenate([goal, np.zeros(3)]) - model.powers[-1] @ x0
        reference = reference_qp(np.eye(size), np.zeros(size), model.terminal, gap, rows, rhs, DOCK.u_max)
        np.testing.assert_allclose(solution.controls.ravel(), reference, atol=1e-5)
        assert abs(solution.cost - reference @ reference) <= 1e-6 * solution.cost
        # The subproblem solver itself (least-distance programming by NNLS) is exact.
        exact = _halfspace_subproblem(model, x0, gap, positions, RADIUS, DOCK.u_max)
        np.testing.assert_allclose(exact, reference, atol=1e-9)


def test_docking_unconstrained_case_returns_the_closed_form():
    model = linear_model(DOCK)
    x0, goal = np.array([0.0, 60.0, 0.0, 0.0, 0.0, 0.0]), np.array([0.0, 8.0, 0.0])  # same side
    states, controls = solve_docking(x0, goal)
    assert np.linalg.norm(states[:, :3], axis=1).min() > RADIUS + 1.0  # never near the keep-out
    np.testing.assert_allclose(controls.ravel(), model.min_energy(x0, np.r_[goal, 0, 0, 0]), atol=1e-12)


def test_docking_with_a_binding_thrust_box():
    starts, goals = sample_docking_starts(np.random.default_rng(3), 2, DOCK)
    free = scp_docking(starts[1], goals[1], DOCK)
    problem = DOCK.replace(u_max=0.8 * np.abs(free.controls).max())  # ~0.04 N: now the box binds
    bound = scp_docking(starts[1], goals[1], problem)
    assert abs(np.abs(bound.controls).max() - problem.u_max) <= 1e-9
    assert bound.cost >= free.cost
    assert np.abs(bound.states[-1] - np.r_[goals[1], 0, 0, 0]).max() <= 1e-6
    assert np.linalg.norm(bound.states[:, :3], axis=1).min() >= RADIUS - 1e-6


def test_start_inside_the_keep_out_raises_infeasible():
    with pytest.raises(Infeasible, match="inside"):
        solve_docking(np.array([3.0, 0.0, 0.0, 0.0, 0.0, 0.0]), np.array([8.0, 0.0, 0.0]))
    with pytest.raises(Infeasible, match="inside"):  # Euler: r_1 = r_0 + dt v_0 is fixed too
        solve_docking(np.array([6.0, 0.0, 0.0, -0.1, 0.0, 0.0]), np.array([0.0, 8.0, 0.0]))


def test_exact_discretisation_docking_is_consistent():
    problem = DOCK.replace(discretization="exact")
    starts, goals = sample_docking_starts(np.random.default_rng(5), 3, problem)
    a, b = problem.matrices()
    for x0, goal in zip(starts, goals, strict=True):
        states, controls = solve_docking(x0, goal, problem)
        np.testing.assert_allclose(states[1:], states[:-1] @ a.T + controls @ b.T, atol=1e-9)
        assert np.linalg.norm(states[:, :3], axis=1).min() >= RADIUS - 1e-6


def test_bad_arguments_raise_clear_value_errors():
    with pytest.raises(ValueError, match="goal"):
        solve_docking(np.r_[-50.0, 0, 0, 0, 0, 0], np.array([3.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="x0"):
        solve_rendezvous(np.zeros(5))
    with pytest.raises(ValueError, match=r"x0 must be a finite vector of shape \(6,\), got one with NaN/inf"):
        solve_docking(np.full(6, np.nan), np.array([8.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match=r"goal .* got one with NaN/inf"):
        solve_docking(np.zeros(6), np.array([8.0, np.inf, 0.0]))
    with pytest.raises(ValueError, match=r"x0 must be a finite vector of shape \(6,\), got shape \(5,\)"):
        solve_rendezvous(np.zeros(5))
    with pytest.raises(ValueError, match="problem"):
        solve_docking(np.zeros(6), np.array([8.0, 0.0, 0.0]), problem=RDZV)
    with pytest.raises(ValueError, match="koz_radius"):
        DockingProblem(koz_radius=-1.0)
    with pytest.raises(ValueError, match="koz_radius"):
        DockingProblem(koz_radius=True)  # a bool is not a number of metres
    with pytest.raises(ValueError, match="margin"):
        DockingProblem(margin=True)
    with pytest.raises(ValueError, match="goal_radius"):
        DockingProblem(goal_radius=5.2)
    with pytest.raises(ValueError, match="start_cone_deg"):
        DockingProblem(start_cone_deg=95.0)
    with pytest.raises(ValueError, match="pierce_depth"):
        DockingProblem(pierce_depth=6.0)
    with pytest.raises(ValueError, match="velocity_box"):
        DockingProblem(velocity_box=(0.1, -0.1, 0.0))
    with pytest.raises(ValueError, match="horizon"):
        RendezvousProblem(horizon=1)
