"""The CBF filter's exact minimiser against proxsuite, its infeasible branch, and its batching."""

from __future__ import annotations

import numpy as np
import pytest
from proxsuite import proxqp

from cwh_envs.cbf import CBFResult, barrier_terms, project_halfspace_box, safe_actions
from cwh_envs.problems import DockingProblem

PROBLEM = DockingProblem()
RADIUS = PROBLEM.koz_radius + PROBLEM.margin


def proxsuite_projection(u0, beta, rho, u_max, max_iter=100_000):
    """One dense proxsuite QP: min ||u - u0||^2 s.t. beta^T u >= rho, |u_i| <= u_max (native box)."""
    qp = proxqp.dense.QP(3, 0, 1, box_constraints=True)
    qp.settings.eps_abs = 1e-13
    qp.settings.eps_rel = 0.0
    qp.settings.max_iter = max_iter
    # Without the duality-gap test proxsuite stops ~1e-8 short of the optimum on box-binding cases.
    qp.settings.check_duality_gap = True
    qp.settings.eps_duality_gap_abs = 1e-13
    qp.settings.eps_duality_gap_rel = 0.0
    limit = np.full(3, u_max)
    qp.init(np.eye(3), -u0, None, None, beta[None, :], np.array([rho]), np.array([np.inf]), -limit, limit)
    qp.solve()
    return qp.results.x.copy(), qp.results.info.status


def random_instances(rng, n, u_max):
    """Nominal actions in and beyond the box, some zero beta components, and rho spanning the
    inactive, box-binding and infeasible regimes."""
    u0 = rng.normal(size=(n, 3)) * u_max
    beta = rng.normal(size=(n, 3)) * 0.2
    beta[rng.random((n, 3)) < 0.1] = 0.0
    reach = u_max * np.abs(beta).sum(axis=1)
    rho = rng.uniform(-1.2, 1.2, size=n) * reach
    return u0, beta, rho


def test_exact_minimiser_matches_proxsuite_on_thousands_of_instances():
    rng = np.random.default_rng(0)
    u_max = PROBLEM.u_max
    u0, beta, rho = random_instances(rng, 3000, u_max)
    result = project_halfspace_box(u0, beta, rho, u_max)
    feasible = np.flatnonzero(~result.infeasible)
    box_binding = np.abs(result.u[feasible]).max(axis=1) >= u_max - 1e-12
    assert len(feasible) >= 2000 and result.active[feasible].sum() >= 500
    assert (box_binding & result.active[feasible]).sum() >= 200  # the regime projection-then-clip gets wrong
    errors, unsolved = [], []
    for i in feasible:
        reference, status = proxsuite_projection(u0[i], beta[i], rho[i], u_max)
        if status == proxqp.QPSolverOutput.PROXQP_SOLVED:
            errors.append(np.abs(reference - result.u[i]).max())
        else:
            unsolved.append(i)
    assert len(errors) >= 2000 and max(errors) <= 1e-7
    # proxsuite gives up on a handful of barely feasible instances; the KKT test below covers them.
    assert len(unsolved) <= 5


def test_solution_satisfies_kkt_conditions():
    rng = np.random.default_rng(1)
    u_max = 0.25
    u0, beta, rho = random_instances(rng, 5000, u_max)
    result = project_halfspace_box(u0, beta, rho, u_max)
    ok = ~result.infeasible
    u, b, r, nominal = result.u[ok], beta[ok], rho[ok], u0[ok]
    assert np.all(np.abs(u) <= u_max)
    assert np.all(np.einsum("ni,ni->n", b, u) >= r - 1e-12)
    # u = clip(u0 + lam beta) for one lam >= 0, with lam > 0 only where the half-space is tight.
    moved = ~np.isclose(u, np.clip(nominal, -u_max, u_max), atol=1e-12, rtol=0) & (b != 0)
    lam = np.where(moved, (u - nominal) / np.where(b != 0, b, 1.0), np.nan)
    for row in range(len(u)):
        values = lam[row][~np.isnan(lam[row])]
        values = values[np.abs(u[row][moved[row]]) < u_max - 1e-12]  # interior components pin lam
        if len(values):
            assert values.min() >= -1e-12 and np.ptp(values) <= 1e-9 * max(1.0, values.max())
            assert abs(b[row] @ u[row] - r[row]) <= 1e-9


def test_infeasible_branch_maximises_beta_over_the_box():
    u_max = 2.0
    u0 = np.array([[0.3, -0.4, 5.0], [1.0, 1.0, 1.0]])
    beta = np.array([[0.2, -0.1, 0.0], [0.1, 0.1, 0.1]])
    rho = np.array([0.61, 0.61])  # above u_max * ||beta||_1 = 0.6 for both
    result = project_halfspace_box(u0, beta, rho, u_max)
    assert result.infeasible.all()
    np.testing.assert_array_equal(result.u[0], [2.0, -2.0, 2.0])  # beta_z = 0 keeps clip(u0_z)
    np.testing.assert_array_equal(result.u[1], [2.0, 2.0, 2.0])
    assert result.active.all()
    status = proxsuite_projection(u0[1], beta[1], rho[1], u_max, max_iter=200)[1]
    assert status != proxqp.QPSolverOutput.PROXQP_SOLVED


def test_projection_then_clip_is_not_the_minimiser_when_the_box_binds():
    """The paper's closed form (half-space projection, then box clip) can leave the half-space."""
    u_max, u0, beta, rho = 1.0, np.array([0.8, 0.0, 0.0]), np.array([1.0, 1.0, 0.0]), 1.6
    projected = u0 + (rho - beta @ u0) / (beta @ beta) * beta
    clipped = np.clip(projected, -u_max, u_max)
    assert beta @ clipped < rho - 0.1  # (1.0, 0.4, 0) violates the barrier
    exact = project_halfspace_box(u0[None], beta[None], np.array([rho]), u_max).u[0]
    np.testing.assert_allclose(exact, [1.0, 0.6, 0.0], atol=1e-12)
    reference, status = proxsuite_projection(u0, beta, rho, u_max)
    assert status == proxqp.QPSolverOutput.PROXQP_SOLVED
    np.testing.assert_allclose(exact, reference, atol=1e-7)


def random_states(rng, n):
    positions = rng.normal(size=(n, 3))
    positions *= rng.uniform(4.0, 12.0, size=(n, 1)) / np.linalg.norm(positions, axis=1, keepdims=True)
    return np.concatenate([positions, rng.normal(size=(n, 3)) * 0.1], axis=1)


def test_batched_equals_per_instance_and_one_dimensional_calls():
    rng = np.random.default_rng(2)
    a, b = PROBLEM.matrices()
    states = random_states(rng, 200)
    nominal = rng.normal(size=(200, 3))
    kwargs = dict(koz_radius=PROBLEM.koz_radius, margin=PROBLEM.margin, u_max=PROBLEM.u_max)
    batched = safe_actions(nominal, states, a, b, **kwargs)
    assert isinstance(batched, CBFResult) and batched.u.shape == (200, 3) and batched.active.dtype == bool
    assert batched.active.any() and (~batched.active).any()
    for i in range(200):
        single = safe_actions(nominal[i], states[i], a, b, **kwargs)
        assert single.u.shape == (3,) and np.ndim(single.active) == 0
        np.testing.assert_allclose(single.u, batched.u[i], rtol=0, atol=1e-13)  # BLAS round-off only
        assert single.active == batched.active[i] and single.infeasible == batched.infeasible[i]
        np.testing.assert_allclose(single.correction_norm, batched.correction_norm[i], rtol=0, atol=1e-13)


@pytest.mark.parametrize("discretization", ["euler", "exact"])
def test_filtered_action_keeps_the_two_step_prediction_outside(discretization):
    problem = PROBLEM.replace(discretization=discretization)
    a, b = problem.matrices()
    rng = np.random.default_rng(3)
    states = random_states(rng, 500)
    nominal = rng.normal(size=(500, 3)) * 2.0
    result = safe_actions(nominal, states, a, b, koz_radius=5.0, margin=0.5, u_max=2.0)
    two_step = states @ (a @ a).T + result.u @ (a @ b + b).T
    coast = (states @ a.T)[:, :3]
    normal = coast / np.linalg.norm(coast, axis=1, keepdims=True)
    radial = np.einsum("ni,ni->n", normal, two_step[:, :3])
    assert np.all(radial[~result.infeasible] >= RADIUS - 1e-9)
    np.testing.assert_allclose(
        result.correction_norm, np.linalg.norm(result.u - np.clip(nominal, -2.0, 2.0), axis=1)
    )


def test_barrier_terms_follow_the_paper():
    a, b = PROBLEM.matrices()
    state = np.array([[6.0, 1.0, -2.0, -0.05, 0.02, 0.01]])
    beta, rho = barrier_terms(state, a, b, RADIUS)
    r_next = (a @ state[0])[:3]
    normal = r_next / np.linalg.norm(r_next)
    np.testing.assert_allclose(beta[0], ((a @ b + b).T @ np.concatenate([normal, np.zeros(3)])))
    np.testing.assert_allclose(rho[0], RADIUS - normal @ (a @ a @ state[0])[:3])
    np.testing.assert_array_equal(b[:3], 0.0)  # Euler: u_t does not move r_{t+1}, hence two steps


def test_centre_prediction_uses_the_fallback_direction():
    a, b = PROBLEM.matrices()
    # Chosen so that r_{t+1} = [A x]_{1:3} is exactly zero.
    state = np.array([1.0, 0.0, 0.0, -0.1, 0.0, 0.0])
    np.testing.assert_array_equal((a @ state)[:3], 0.0)
    result = safe_actions(np.zeros(3), state, a, b, koz_radius=5.0, margin=0.5, u_max=2.0)
    assert np.all(np.isfinite(result.u)) and result.active
    beta, _ = barrier_terms(state[None], a, b, RADIUS)
    np.testing.assert_allclose(beta[0], (a @ b + b)[0])  # +x row


def test_bad_arguments_raise_clear_errors():
    a, b = PROBLEM.matrices()
    with pytest.raises(ValueError, match="states"):
        safe_actions(np.zeros(3), np.zeros(5), a, b, koz_radius=5.0, margin=0.5, u_max=2.0)
    with pytest.raises(ValueError, match="koz_radius"):
        safe_actions(np.zeros(3), np.ones(6), a, b, koz_radius=-1.0, margin=0.5, u_max=2.0)
    with pytest.raises(ValueError, match="u_max"):
        safe_actions(np.zeros(3), np.ones(6), a, b, koz_radius=5.0, margin=0.5, u_max=0.0)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_states_or_thrust_raise_instead_of_full_thrust(bad):
    a, b = PROBLEM.matrices()
    state, thrust = np.array([6.0, 1.0, -2.0, -0.05, 0.02, 0.01]), np.array([0.1, 0.0, 0.0])
    with pytest.raises(ValueError, match="must be finite, got NaN/inf"):
        safe_actions(thrust, np.r_[state[:5], bad], a, b, koz_radius=5.0, margin=0.5, u_max=2.0)
    with pytest.raises(ValueError, match="must be finite, got NaN/inf"):
        safe_actions(np.r_[bad, 0.0, 0.0], state, a, b, koz_radius=5.0, margin=0.5, u_max=2.0)
    batch = np.stack([state, np.r_[state[:2], bad, state[3:]]])
    with pytest.raises(ValueError, match="must be finite"):
        safe_actions(np.zeros((2, 3)), batch, a, b, koz_radius=5.0, margin=0.5, u_max=2.0)


@pytest.mark.parametrize("margin", [True, np.nan, np.inf, "0.5"])
def test_a_margin_must_be_a_finite_number(margin):
    a, b = PROBLEM.matrices()
    with pytest.raises(ValueError, match="margin"):
        safe_actions(np.zeros(3), np.ones(6), a, b, koz_radius=5.0, margin=margin, u_max=2.0)
