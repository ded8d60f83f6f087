"""cwh_envs.compiled_filter and cwh_envs.compiled_navigation (issue 58's compute target): the compiled
filters answer what the numpy ones answer, on many draws and on every path through them (each
margin fraction, the zone rule, the stop line, the nominal filter's drops), and refuse bad input by
name."""

from __future__ import annotations

import numpy as np
import pytest

from cwh_envs.navigation import NavigationFilter
from cwh_envs.robust_cbf import ErrorBounds, robust_safe_actions

pytestmark = pytest.mark.needs("fast")

from test_robust_cbf import ONE_SIGMA, PROBLEM, approach  # noqa: E402

U_TOLERANCE = 1e-9  # N: the same arithmetic in another order (u_max is 1 N)
CASES = {
    "1 sigma at k=3, stop line": (ErrorBounds(**ONE_SIGMA, k_sigma=3.0), True, PROBLEM),
    "1 sigma at k=3": (ErrorBounds(**ONE_SIGMA, k_sigma=3.0), False, PROBLEM),
    "1 sigma at k=1, stop line": (ErrorBounds(**ONE_SIGMA, k_sigma=1.0), True, PROBLEM),
    # margins too wide for the corridor: every fraction and the nominal fallback are taken
    "wide navigation bounds, stop line": (ErrorBounds(**{**ONE_SIGMA, "nav_position": 0.5}), True, PROBLEM),
    "zero bounds: the nominal filter": (ErrorBounds(), False, PROBLEM),
    "keep-out only": (
        ErrorBounds(**ONE_SIGMA, k_sigma=3.0),
        False,
        PROBLEM.replace(speed_limit=None, approach_cone=None),
    ),
}


def draws(seed: int, n: int):
    """Chasers on the approach, a third pushed off it (outside the cone, into the zone), and nominal
    thrusts inside and outside the box."""
    rng = np.random.default_rng(seed)
    goals, states = approach(rng, n)
    states[: n // 3, :3] += rng.normal(scale=2.0, size=(n // 3, 3))
    return rng, goals, states, rng.uniform(-1.5, 1.5, (n, 3)) * PROBLEM.u_max


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_compiled_robust_filter_answers_what_the_numpy_one_answers(case):
    from cwh_envs.compiled_filter import CompiledRobustFilter

    bounds, stop_line, problem = CASES[case]
    rng, goals, states, u0 = draws(sum(map(ord, case)), 600)
    sigma = np.abs(rng.normal(scale=[0.02, 2e-4], size=(len(states), 2)))
    per_row = rng.uniform(size=len(states)) < 0.5  # half the rows sized by their own sigma
    compiled = CompiledRobustFilter(problem, bounds, stop_line=stop_line)
    for rows, row_sigma in ((per_row, sigma[per_row]), (~per_row, None)):
        expected = robust_safe_actions(
            u0[rows],
            states[rows],
            goals[rows],
            problem,
            bounds,
            navigation_sigma=row_sigma,
            stop_line=stop_line,
        )
        got = [
            compiled(u, x, g, None if row_sigma is None else s)
            for u, x, g, s in zip(u0[rows], states[rows], goals[rows], sigma[rows], strict=True)
        ]
        np.testing.assert_allclose(np.array([r.u for r in got]), expected.u, rtol=0, atol=U_TOLERANCE)
        np.testing.assert_array_equal([r.margin_scale for r in got], expected.margin_scale)
        np.testing.assert_array_equal([r.dropped for r in got], expected.dropped)
        np.testing.assert_array_equal([r.infeasible for r in got], expected.infeasible)
        np.testing.assert_allclose(
            [r.correction_norm for r in got], expected.correction_norm, atol=U_TOLERANCE
        )
    if problem.approach_cone is not None and bounds.nav_position > 0:
        # not a vacuous comparison: the draws took the robust answer and at least one fallback
        assert np.any(expected.margin_scale == 1.0) and np.any(expected.margin_scale < 1.0), case


def test_the_compiled_robust_filter_refuses_bad_input_by_name():
    from cwh_envs.compiled_filter import CompiledRobustFilter

    compiled = CompiledRobustFilter(PROBLEM, ErrorBounds(**ONE_SIGMA))
    u, x, g = np.zeros(3), np.array([20.0, 0, 0, 0, 0, 0]), np.array([10.0, 0, 0])
    with pytest.raises(ValueError, match="finite"):
        compiled(u, x + np.array([np.nan, 0, 0, 0, 0, 0]), g)
    with pytest.raises(ValueError, match=r"estimates must be \(6,\)"):
        compiled(u, x[:5], g)
    with pytest.raises(ValueError, match="one instance"):
        compiled(np.zeros((2, 3)), np.stack([x, x]), np.stack([g, g]))
    with pytest.raises(ValueError, match="navigation_sigma"):
        compiled(u, x, g, navigation_sigma=(-1.0, 0.0))
    with pytest.raises(ValueError, match="ErrorBounds"):
        CompiledRobustFilter(PROBLEM, {"nav_position": 0.05})
    with pytest.raises(ValueError, match="DockingProblem"):
        CompiledRobustFilter(object(), ErrorBounds())
    with pytest.raises(ValueError, match="stop_line"):
        CompiledRobustFilter(PROBLEM, ErrorBounds(), stop_line="yes")


def test_the_compiled_navigation_filter_tracks_the_numpy_one_through_a_dispersed_episode():
    """The same thrusts and noisy measurements, a thrust error in the plant: the same estimate,
    sigma and thrust gain at every step, to rounding; refused input named."""
    from cwh_envs.compiled_navigation import CompiledNavigationFilter

    bounds = ErrorBounds(**ONE_SIGMA)
    rng = np.random.default_rng(3)
    a, b = PROBLEM.matrices()
    gain = np.eye(3) + rng.normal(scale=0.03, size=(3, 3))
    noise = np.array([bounds.nav_position] * 3 + [bounds.nav_velocity] * 3)
    x = np.array([30.0, -8.0, 4.0, 0.0, 0.0, 0.0])
    reference, compiled = NavigationFilter(PROBLEM, bounds), CompiledNavigationFilter(PROBLEM, bounds)
    with pytest.raises(RuntimeError, match="start"):
        compiled.step(np.zeros(3), x)
    y = x + noise * rng.normal(size=6)
    reference.start(np.ones(1, dtype=bool), y[None])
    compiled.start(y)
    np.testing.assert_allclose(compiled.sigma(), reference.sigma()[0], rtol=1e-12)
    for _ in range(240):
        u = rng.uniform(-1.0, 1.0, 3) * PROBLEM.u_max
        x = a @ x + b @ (gain @ u)
        y = x + noise * rng.normal(size=6)
        np.testing.assert_allclose(
            compiled.step(u, y), reference.step(u[None], y[None])[0], rtol=0, atol=1e-10
        )
        np.testing.assert_allclose(compiled.sigma(), reference.sigma()[0], rtol=1e-9)
        np.testing.assert_allclose(compiled.thrust_gain(), reference.thrust_gain()[0], rtol=0, atol=1e-12)
        action = rng.uniform(-1.2, 1.2, 3)
        expected = np.clip(
            np.linalg.solve(reference.thrust_gain(), action[None, :, None])[0, :, 0], -1.0, 1.0
        )
        np.testing.assert_allclose(compiled.command(action), expected, rtol=0, atol=1e-12)
    assert np.abs(compiled.thrust_gain() - gain).max() < np.abs(gain - np.eye(3)).max()  # it learnt G
    with pytest.raises(ValueError, match="measurement"):
        compiled.step(np.zeros(3), np.full(6, np.inf))
    with pytest.raises(ValueError, match="thrust"):
        compiled.step(np.zeros(2), y)
    with pytest.raises(ValueError, match="nav_position"):
        CompiledNavigationFilter(PROBLEM, ErrorBounds())
