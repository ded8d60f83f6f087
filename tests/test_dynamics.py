"""The shared discrete CWH model against the paper's matrices and the analytic CW solution."""

from __future__ import annotations

import numpy as np
import pytest

from cwh_envs.dynamics import MASS, MEAN_MOTION, TIME_STEP, continuous_matrices, cwh_matrices, rollout, step
from cwh_envs.problems import DockingProblem, RendezvousProblem

N, DT, M = MEAN_MOTION, TIME_STEP, MASS


def clohessy_wiltshire_transition(n: float, t: float) -> np.ndarray:
    """The closed-form CW state-transition matrix (x radial, y along-track, z cross-track)."""
    c, s = np.cos(n * t), np.sin(n * t)
    return np.array(
        [
            [4 - 3 * c, 0, 0, s / n, 2 * (1 - c) / n, 0],
            [6 * (s - n * t), 1, 0, -2 * (1 - c) / n, (4 * s - 3 * n * t) / n, 0],
            [0, 0, c, 0, 0, s / n],
            [3 * n * s, 0, 0, c, 2 * s, 0],
            [-6 * n * (1 - c), 0, 0, -2 * s, 4 * c - 3, 0],
            [0, 0, -n * s, 0, 0, c],
        ]
    )


def test_euler_matrices_are_the_papers_entries():
    a, b = cwh_matrices()
    expected_a = np.eye(6)
    expected_a[0:3, 3:6] += DT * np.eye(3)
    expected_a[3, 0] = 3 * N**2 * DT
    expected_a[3, 4] = 2 * N * DT
    expected_a[4, 3] = -2 * N * DT
    expected_a[5, 2] = -(N**2) * DT
    np.testing.assert_array_equal(a, expected_a)
    expected_b = np.zeros((6, 3))
    expected_b[3:6] = DT / M * np.eye(3)
    np.testing.assert_array_equal(b, expected_b)
    a_c, b_c = continuous_matrices()
    np.testing.assert_array_equal(a, np.eye(6) + DT * a_c)
    np.testing.assert_array_equal(b, DT * b_c)


def test_problems_share_the_one_model():
    for problem in (RendezvousProblem(), DockingProblem()):
        a, b = problem.matrices()
        assert a is cwh_matrices()[0] and b is cwh_matrices()[1]  # the cached, read-only pair
        assert not a.flags.writeable and not b.flags.writeable


def test_exact_discretisation_is_the_cw_transition_and_zoh_input():
    a, b = cwh_matrices(discretization="exact")
    np.testing.assert_allclose(a, clohessy_wiltshire_transition(N, DT), rtol=0, atol=1e-12)
    # ZOH input matrix: integral of Phi(t) B_c over one step (Simpson on a fine grid).
    times = np.linspace(0.0, DT, 2001)
    _, b_c = continuous_matrices()
    integrand = np.stack([clohessy_wiltshire_transition(N, t) @ b_c for t in times])
    weights = np.ones(len(times))
    weights[1:-1:2], weights[2:-1:2] = 4.0, 2.0
    np.testing.assert_allclose(b, np.einsum("k,kij->ij", weights, integrand) * (times[1] / 3), atol=1e-14)


def test_euler_and_exact_differ_by_metres_over_the_docking_horizon():
    problem = DockingProblem()
    x0 = np.array([60.0, -40.0, 20.0, 0.02, -0.03, 0.01])
    controls = np.zeros((problem.horizon, 3))
    euler = rollout(x0, controls, *problem.matrices())
    exact = rollout(x0, controls, *problem.replace(discretization="exact").matrices())
    gap = np.linalg.norm(euler[-1, :3] - exact[-1, :3])
    assert 1.0 < gap  # comparable to the 5 m keep-out: hence one shared model
    np.testing.assert_allclose(
        exact[-1], clohessy_wiltshire_transition(N, problem.horizon * DT) @ x0, atol=1e-8
    )


def test_step_and_rollout_agree_for_single_and_batched_states():
    a, b = cwh_matrices()
    rng = np.random.default_rng(0)
    x0, controls = rng.normal(size=6), rng.normal(size=(5, 3))
    states = rollout(x0, controls, a, b)
    for k in range(5):
        np.testing.assert_allclose(states[k + 1], step(states[k], controls[k], a, b))
    batch = rng.normal(size=(4, 6))
    np.testing.assert_allclose(step(batch, controls[:4], a, b), batch @ a.T + controls[:4] @ b.T)


@pytest.mark.parametrize(
    "kwargs", [{"discretization": "rk4"}, {"n": -1.0}, {"dt": 0.0}, {"mass": float("nan")}]
)
def test_bad_model_arguments_raise(kwargs):
    with pytest.raises(ValueError):
        cwh_matrices(**kwargs)
