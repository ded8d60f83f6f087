"""The robust multi-constraint filter of :mod:`cwh_envs.robust_cbf`, compiled (numba) for one chaser.

Flight software filters one state per control step. The numpy filter is written for batches: on one
state its time is the overhead of some sixty small array calls (0.6-0.8 ms a step at the median,
measured alone: benchmarks/bench_flight_path.py), not arithmetic. :class:`CompiledRobustFilter` is the same algorithm, step for step, as scalar
loops that numba compiles to machine code once (cached on disk), so that one step costs microseconds:

    from cwh_envs.compiled_filter import CompiledRobustFilter

    safe = CompiledRobustFilter(problem, ErrorBounds.from_dispersions(spreads, k_sigma=3), stop_line=True)
    result = safe(u_nominal, estimate, goal, navigation_sigma=(s_r, s_v))  # a RobustCBFResult

It answers what :func:`cwh_envs.robust_cbf.robust_safe_actions` answers for one instance (the
same margins, the cone's zone rule, the stop line, the retries at :data:`MARGIN_SCALES` and the
nominal filter's drop rule at scale 0), to rounding: tests/test_compiled_filter.py flies both on
the same steps and compares. The constant parts of the margins (the spectral norms of blocks of
``A`` and ``A^2``) are computed once, at construction, with numpy.

numba is an optional dependency (``pip install 'cwh-autoresearch[fast]'``): ``import cwh_envs``
does not import this module.
"""

from __future__ import annotations

import math

import numpy as np

try:
    from numba import njit
except ModuleNotFoundError as err:
    raise ModuleNotFoundError(
        "cwh_envs.compiled_filter needs numba, which is not installed: pip install 'cwh-autoresearch[fast]'",
        name=err.name,
    ) from err

from cwh_envs.cbf import FALLBACK_DIRECTION
from cwh_envs.cbf_multi import (
    CONE_SLACK,
    DEGENERATE,
    FEASIBILITY_TOLERANCE,
    LINEARISATIONS,
    SPEED_SLACK,
    check_filter_inputs,
)
from cwh_envs.constraints import APEX, SPEED_TOLERANCE
from cwh_envs.problems import DockingProblem
from cwh_envs.robust_cbf import MARGIN_SCALES, ZONE_LOOKAHEAD, ErrorBounds, RobustCBFResult, _check_sigma

# The layout of the float parameters handed to the compiled code (one array: one argument to type).
(
    U_MAX,
    KOZ_RADIUS,
    STANDOFF,
    HAS_SPEED,
    V0,
    V1,
    HAS_CONE,
    HALF_ANGLE,
    CONE_RADIUS,
    CAPTURE_RADIUS,
    K_SIGMA,
    ACTUATION,
    STOP_LINE,
    N_POS_RR,  # ||(A^2)_rr||_2, ||(A^2)_rv||_2: the two-step position prediction's navigation error
    N_POS_RV,
    N_NAV_RR,  # ||A_rr||_2, ||A_rv||_2: the one-step position prediction's
    N_NAV_RV,
    N_SPD_VR,  # ||A_vr||_2, ||A_vv||_2: the one-step velocity prediction's
    N_SPD_VV,
    N_PARAMETERS,
) = range(20)
_FRACTIONS = np.array(MARGIN_SCALES, dtype=np.float64)
_FALLBACK = np.asarray(FALLBACK_DIRECTION, dtype=np.float64)


class CompiledRobustFilter:
    """:func:`cwh_envs.robust_cbf.robust_safe_actions` for one instance, compiled (module docstring).

    ``problem`` a :class:`cwh_envs.problems.DockingProblem`, ``bounds`` an :class:`ErrorBounds`,
    ``margin`` the keep-out standoff (``problem.margin`` by default), ``stop_line`` the robust
    filter's stop line. Calling it with the nominal thrust (3,) [N], the estimated state (6,), the
    port (3,) and optionally the estimate's one-sigma errors ``navigation_sigma`` (2,) returns a
    single-instance :class:`RobustCBFResult`."""

    def __init__(
        self,
        problem: DockingProblem,
        bounds: ErrorBounds,
        margin: float | None = None,
        stop_line: bool = False,
    ) -> None:
        if not isinstance(problem, DockingProblem):
            raise ValueError(f"problem must be a DockingProblem, got {type(problem).__name__}")
        if not isinstance(bounds, ErrorBounds):
            raise ValueError(f"bounds must be an ErrorBounds, got {type(bounds).__name__}")
        if not isinstance(stop_line, bool | np.bool_):
            raise ValueError(f"stop_line must be True or False, got {stop_line!r}")
        a, b = problem.matrices()
        self.a, self.b = np.ascontiguousarray(a), np.ascontiguousarray(b)
        self.lever = np.ascontiguousarray((a @ b + b)[:3])
        self.bounds = bounds
        p = np.zeros(N_PARAMETERS)
        p[U_MAX], p[KOZ_RADIUS] = problem.u_max, problem.koz_radius
        p[STANDOFF] = problem.margin if margin is None else float(margin)
        if problem.speed_limit is not None:
            p[HAS_SPEED], (p[V0], p[V1]) = 1.0, problem.speed_limit
        if problem.approach_cone is not None:
            p[HAS_CONE] = 1.0
            p[HALF_ANGLE], p[CONE_RADIUS] = np.radians(problem.approach_cone[0]), problem.approach_cone[1]
        p[CAPTURE_RADIUS] = problem.capture_radius
        p[K_SIGMA], p[ACTUATION], p[STOP_LINE] = bounds.k_sigma, bounds.actuation(), float(stop_line)
        two = a @ a
        for index, block in (
            (N_POS_RR, two[:3, :3]),
            (N_POS_RV, two[:3, 3:]),
            (N_NAV_RR, a[:3, :3]),
            (N_NAV_RV, a[:3, 3:]),
            (N_SPD_VR, a[3:, :3]),
            (N_SPD_VV, a[3:, 3:]),
        ):
            p[index] = np.linalg.norm(block, 2)
        self.parameters = p
        self._bounds_sigma = np.array([bounds.nav_position, bounds.nav_velocity])

    def __call__(self, u_nominal, estimate, goal, navigation_sigma=None) -> RobustCBFResult:
        # The checks of check_filter_inputs, on one instance and without its batch handling: at a few
        # microseconds a step, numpy's own checks would cost as much as the filter.
        u0 = np.asarray(u_nominal, dtype=np.float64)
        x = np.asarray(estimate, dtype=np.float64)
        g = np.asarray(goal, dtype=np.float64)
        if u0.shape != (3,) or x.shape != (6,) or g.shape != (3,):
            check_filter_inputs(
                u0, x, g, state_name="estimates"
            )  # names a wrong shape, as the numpy filter does
            raise ValueError(
                f"CompiledRobustFilter filters one instance: u_nominal (3,), estimate (6,) and goal (3,), "
                f"got {u0.shape}, {x.shape} and {g.shape}"
            )
        sigma = self._bounds_sigma if navigation_sigma is None else _check_sigma(navigation_sigma, 1)[0]
        if not (_finite(u0) and _finite(x) and _finite(g)):
            raise ValueError("estimates, u_nominal and goals must be finite, got NaN/inf entries")
        u, scale, dropped, correction = _robust(u0, x, g, self.a, self.b, self.lever, self.parameters, sigma)
        return RobustCBFResult(u, correction > 0.0, scale < 1.0, correction, dropped, scale)


# ------------------------------------------------------------------ small vector arithmetic


@njit(cache=True)
def _finite(values):
    for value in values:
        if not math.isfinite(value):
            return False
    return True


@njit(cache=True)
def _dot3(x, y):
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]


@njit(cache=True)
def _norm3(x):
    return math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])


@njit(cache=True)
def _cross3(x, y):
    out = np.empty(3)
    out[0] = x[1] * y[2] - x[2] * y[1]
    out[1] = x[2] * y[0] - x[0] * y[2]
    out[2] = x[0] * y[1] - x[1] * y[0]
    return out


@njit(cache=True)
def _mat_vec(m, v):
    out = np.zeros(m.shape[0])
    for i in range(m.shape[0]):
        total = 0.0
        for j in range(m.shape[1]):
            total += m[i, j] * v[j]
        out[i] = total
    return out


@njit(cache=True)
def _clip3(u, u_max):
    out = np.empty(3)
    for j in range(3):
        out[j] = min(max(u[j], -u_max), u_max)
    return out


@njit(cache=True)
def _axis(goal):
    """cwh_envs.constraints.cone_axis for one goal."""
    norm = _norm3(goal)
    out = np.empty(3)
    if norm > 0.0:
        for j in range(3):
            out[j] = goal[j] / norm
    else:
        out[0], out[1], out[2] = 1.0, 0.0, 0.0
    return out


# ------------------------------------------------------------------ the QP (cbf.py, cbf_multi.py)


@njit(cache=True)
def _halfspace_box(u0, beta, rho, u_max):
    """cwh_envs.cbf.project_halfspace_box for one instance: (u, infeasible)."""
    breaks = np.zeros(6)
    for j in range(3):
        if beta[j] != 0.0:
            low, high = (-u_max - u0[j]) / beta[j], (u_max - u0[j]) / beta[j]
            breaks[j] = low if (math.isfinite(low) and low > 0.0) else 0.0
            breaks[3 + j] = high if (math.isfinite(high) and high > 0.0) else 0.0
    lams = np.zeros(7)
    lams[1:] = np.sort(breaks)
    g = np.zeros(7)
    for k in range(7):
        total = 0.0
        for j in range(3):
            total += min(max(u0[j] + lams[k] * beta[j], -u_max), u_max) * beta[j]
        g[k] = total
    infeasible = not (g[6] >= rho)
    needs_push = not (g[0] >= rho) and not infeasible
    upper = 0
    for k in range(7):
        if g[k] >= rho:
            upper = k
            break
    lower = max(upper - 1, 0)
    lam = 0.0
    if needs_push:
        lam = lams[lower] + (rho - g[lower]) * (lams[upper] - lams[lower]) / (g[upper] - g[lower])
    u = np.empty(3)
    for j in range(3):
        u[j] = min(max(u0[j] + lam * beta[j], -u_max), u_max)
        if infeasible:
            if beta[j] != 0.0:
                u[j] = u_max * (1.0 if beta[j] > 0.0 else -1.0)
            else:
                u[j] = min(max(u0[j], -u_max), u_max)
    return u, infeasible


@njit(cache=True)
def _meets(u, rows, rhs):
    for i in range(3):
        if not (_dot3(rows[i], u) >= rhs[i] - FEASIBILITY_TOLERANCE):
            return False
    return True


@njit(cache=True)
def _enumerate(u0, rows, rhs, u_max):
    """cwh_envs.cbf_multi._enumerate for one instance: (u, feasible)."""
    usable = np.empty(3, dtype=np.bool_)
    targets = np.empty(3)
    for i in range(3):
        usable[i] = math.isfinite(rhs[i])
        targets[i] = rhs[i] if usable[i] else 0.0
    candidates = np.zeros((4, 3))
    valid = np.zeros(4, dtype=np.bool_)
    firsts, seconds = (0, 0, 1), (1, 2, 2)
    for p in range(3):
        c1, c2 = rows[firsts[p]], rows[seconds[p]]
        s1 = targets[firsts[p]] - _dot3(c1, u0)
        s2 = targets[seconds[p]] - _dot3(c2, u0)
        q = _dot3(c1, c2)
        det = 1.0 - q * q
        ok = det > DEGENERATE and usable[firsts[p]] and usable[seconds[p]]
        if not ok:
            det = 1.0
        y1, y2 = (s1 - q * s2) / det, (s2 - q * s1) / det
        foot = np.empty(3)
        for j in range(3):
            foot[j] = u0[j] + y1 * c1[j] + y2 * c2[j]
        along = _cross3(c1, c2)
        if ok:
            length = math.sqrt(_dot3(along, along))
            for j in range(3):
                along[j] /= length
        low, high = -np.inf, np.inf
        for j in range(3):
            if along[j] == 0.0:
                inside = abs(foot[j]) <= u_max
                low = max(low, -np.inf if inside else np.inf)
                high = min(high, np.inf if inside else -np.inf)
            else:
                to_low, to_high = (-u_max - foot[j]) / along[j], (u_max - foot[j]) / along[j]
                low = max(low, min(to_low, to_high))
                high = min(high, max(to_low, to_high))
        ok = ok and low <= high
        t = min(max(0.0, low), high) if ok else 0.0
        for j in range(3):
            candidates[p, j] = foot[j] + t * along[j]
        valid[p] = ok
    cross23, cross31, cross12 = (
        _cross3(rows[1], rows[2]),
        _cross3(rows[2], rows[0]),
        _cross3(rows[0], rows[1]),
    )
    volume = _dot3(rows[0], cross23)
    ok = abs(volume) > DEGENERATE and usable[0] and usable[1] and usable[2]
    if not ok:
        volume = 1.0
    for j in range(3):
        candidates[3, j] = (
            targets[0] * cross23[j] + targets[1] * cross31[j] + targets[2] * cross12[j]
        ) / volume
        ok = ok and abs(candidates[3, j]) <= u_max + FEASIBILITY_TOLERANCE
    valid[3] = ok
    best, pick = np.inf, -1
    for c in range(4):
        if valid[c]:
            for i in range(3):
                if not (_dot3(candidates[c], rows[i]) - rhs[i] >= -FEASIBILITY_TOLERANCE):
                    valid[c] = False
        if valid[c]:
            cost = 0.0
            for j in range(3):
                cost += (candidates[c, j] - u0[j]) ** 2
            if cost < best:
                best, pick = cost, c
    if pick < 0:
        return _clip3(u0, u_max), False
    return _clip3(candidates[pick], u_max), True


@njit(cache=True)
def _polytope_box(u0, g_rows, h, applies, u_max):
    """cwh_envs.cbf_multi.project_polytope_box for one instance: (u, feasible)."""
    rows = np.zeros((3, 3))
    rhs = np.empty(3)
    hopeless = False
    for i in range(3):
        norm = _norm3(g_rows[i])
        if applies[i] and norm > 0.0:
            for j in range(3):
                rows[i, j] = g_rows[i, j] / norm
            rhs[i] = h[i] / norm
        else:
            rhs[i] = -np.inf
            if applies[i] and norm == 0.0 and h[i] > 0.0:
                hopeless = True
    u = _clip3(u0, u_max)
    if hopeless:
        return u, False
    violated = np.zeros(3, dtype=np.bool_)
    for i in range(3):
        violated[i] = _dot3(rows[i], u) < rhs[i] - FEASIBILITY_TOLERANCE
    if not (violated[0] or violated[1] or violated[2]):
        return u, True
    solved = impossible = False
    for i in range(3):  # stage 2: a relaxation to each violated barrier; one that meets the others wins
        if violated[i]:
            relaxed, infeasible = _halfspace_box(u0, rows[i], rhs[i], u_max)
            if infeasible:
                impossible = True
            elif _meets(relaxed, rows, rhs):
                u, solved = relaxed, True  # as numpy's assignment: the last such relaxation
    if impossible:
        return u, False
    if solved:
        return u, True
    return _enumerate(u0, rows, rhs, u_max)  # stage 3: two or three barriers active


@njit(cache=True)
def _keep_out(coast, two_step, lever, radius):
    """cwh_envs.cbf.barrier_terms for one instance from ``A x`` and ``A^2 x``: (beta, rho) of
    ``beta^T u >= rho``, ``radius`` the keep-out's plus its standoff."""
    norm = _norm3(coast[:3])
    normal = coast[:3] / norm if norm > 0.0 else _FALLBACK.copy()
    return _mat_vec(lever.T, normal), radius - _dot3(normal, two_step[:3])


@njit(cache=True)
def _barrier_rows(
    x, goal, point, a, b, lever, koz, standoff, has_speed, v0, v1, has_cone, half_angle, radius
):
    """cwh_envs.cbf_multi.barrier_rows for one instance, the keep-out's radius ``koz + standoff``."""
    rows = np.zeros((3, 3))
    h = np.zeros(3)
    applies = np.zeros(3, dtype=np.bool_)
    coast = _mat_vec(a, x)
    two_step = _mat_vec(a, coast)
    rows[0], h[0] = _keep_out(coast, two_step, lever, koz + standoff)
    applies[0] = True
    if has_speed:
        nominal = coast + _mat_vec(b, point)
        offset = nominal[:3] - goal
        speed, distance = _norm3(nominal[3:]), _norm3(offset)
        along_v = nominal[3:] / speed if speed > 0.0 else np.zeros(3)
        along_r = offset / distance if distance > 0.0 else np.zeros(3)
        grad = _mat_vec(b[3:].T, along_v) - v1 * _mat_vec(b[:3].T, along_r)
        excess = speed - (v0 - min(SPEED_SLACK, v0 / 2.0)) - v1 * distance
        rows[1] = -grad
        h[1] = excess - _dot3(grad, point)
        applies[1] = speed > 0.0
    if has_cone:
        drift = two_step[:3] - goal
        offset = drift + _mat_vec(lever, point)
        distance = _norm3(offset)
        axis = _axis(goal)
        direction = offset / distance if distance > APEX else axis
        normal = axis - math.cos(half_angle) * direction
        rows[2] = _mat_vec(lever.T, normal)
        h[2] = -_dot3(normal, drift)
        applies[2] = distance <= radius
    return rows, h, applies


@njit(cache=True)
def _broken_when_held(x, goal, u, a, b, has_speed, v0, v1, has_cone, half_angle, radius):
    """cwh_envs.cbf_multi.broken_when_held for one instance: (applies, broken), each (3,)."""
    applies = np.zeros(3, dtype=np.bool_)
    broken = np.zeros(3, dtype=np.bool_)
    applies[0] = True
    after = _mat_vec(a, x) + _mat_vec(b, u)
    if has_speed:
        applies[1] = True
        margin = v0 + v1 * _norm3(after[:3] - goal) - _norm3(after[3:])
        broken[1] = margin < -SPEED_TOLERANCE
    if has_cone:
        r = (_mat_vec(a, after) + _mat_vec(b, u))[:3]
        offset = r - goal  # the apex is the goal here (capture radius 0), as the filters pass it
        distance = _norm3(offset)
        slack = _dot3(_axis(goal), offset) - math.cos(half_angle) * distance
        if distance <= APEX:
            slack = max(slack, 0.0)
        applies[2] = distance <= radius
        broken[2] = applies[2] and slack < -CONE_SLACK
    return applies, broken


@njit(cache=True)
def _nominal(u0, x, goal, a, b, lever, u_max, koz, standoff, has_speed, v0, v1, has_cone, half_angle, radius):
    """cwh_envs.cbf_multi.safe_actions_multi for one instance: (u, dropped)."""
    dropped = np.zeros(3, dtype=np.bool_)
    u = _clip3(u0, u_max)
    met = False
    for drop in (-1, 2, 1):  # every barrier; then without the cone; then without the speed limit
        if drop >= 0:
            dropped[drop] = True
        point = _clip3(u0, u_max)
        found, feasible = point.copy(), True
        for _ in range(LINEARISATIONS):
            rows, h, applies = _barrier_rows(
                x, goal, point, a, b, lever, koz, standoff, has_speed, v0, v1, has_cone, half_angle, radius
            )
            for i in range(3):
                applies[i] = applies[i] and not dropped[i]
            found, feasible = _polytope_box(u0, rows, h, applies, u_max)
            moved = feasible and (applies[1] or applies[2])
            moved = moved and (found[0] != point[0] or found[1] != point[1] or found[2] != point[2])
            if feasible:
                point = found
            if not moved:
                break
        if feasible:
            held, broken = _broken_when_held(
                x, goal, found, a, b, has_speed, v0, v1, has_cone, half_angle, radius
            )
            met = not (
                (broken[0] and not dropped[0])
                or (broken[1] and not dropped[1])
                or (broken[2] and not dropped[2])
            )
        if met:
            u = found
            break
    if not met:  # the keep-out alone is infeasible: the thrust that best satisfies it
        coast = _mat_vec(a, x)
        beta, rho = _keep_out(coast, _mat_vec(a, coast), lever, koz + standoff)
        u, _ = _halfspace_box(u0, beta, rho, u_max)
    held, _ = _broken_when_held(x, goal, u, a, b, has_speed, v0, v1, has_cone, half_angle, radius)
    for i in range(3):  # a barrier that does not apply was not given up
        dropped[i] = dropped[i] and held[i]
    return u, dropped


# ------------------------------------------------------------------ the robust filter (robust_cbf.py)


@njit(cache=True)
def _robust(u0, x, g, a, b, lever, p, sigma):
    """cwh_envs.robust_cbf.robust_safe_actions for one instance: (u, margin_scale, dropped, the
    correction's norm ``||u - clip(u0)||``)."""
    u, scale, dropped = _robust_action(u0, x, g, a, b, lever, p, sigma)
    return u, scale, dropped, _norm3(u - _clip3(u0, p[U_MAX]))


@njit(cache=True)
def _robust_action(u0, x, g, a, b, lever, p, sigma):
    """The filtered thrust, margin_scale and dropped of :func:`_robust`."""
    u_max, koz, standoff = p[U_MAX], p[KOZ_RADIUS], p[STANDOFF]
    has_speed, v0, v1 = p[HAS_SPEED] > 0.0, p[V0], p[V1]
    has_cone, half_angle, radius = p[HAS_CONE] > 0.0, p[HALF_ANGLE], p[CONE_RADIUS]
    k, s_r, s_v = p[K_SIGMA], sigma[0], sigma[1]
    position = k * (s_r * p[N_POS_RR] + s_v * p[N_POS_RV])
    speed_error = k * (s_r * p[N_SPD_VR] + s_v * p[N_SPD_VV]) + v1 * k * (
        s_r * p[N_NAV_RR] + s_v * p[N_NAV_RV]
    )
    port_axis = _axis(g)
    for fraction in _FRACTIONS:
        # the tightened constraints of this fraction (robust_cbf._Tightened)
        eps = fraction * position
        actuation = fraction * p[ACTUATION]
        apex = g.copy()
        setback, stop = 0.0, 0.0
        if has_cone:
            setback = p[CAPTURE_RADIUS] / math.tan(half_angle) - eps / math.sin(half_angle)
            apex = g - setback * port_axis
            if p[STOP_LINE] > 0.0 and fraction > 0.0:
                stop = max(0.0, eps / math.tan(half_angle) - setback)
        v0_tight = max(v0 - (fraction * speed_error + v1 * abs(setback)), 1e-9) if has_speed else v0
        if fraction == 0.0:  # the nominal filter on the scored corridor, with its own drop rule
            u, dropped = _nominal(
                u0,
                x,
                apex,
                a,
                b,
                lever,
                u_max,
                koz,
                standoff,
                has_speed,
                v0_tight,
                v1,
                has_cone,
                half_angle,
                radius,
            )
            return u, 0.0, dropped
        # robust_cbf._solve
        point = _clip3(u0, u_max)
        u, feasible = point.copy(), True
        outside = False
        coast = _mat_vec(a, x)
        two = _mat_vec(a, coast)
        if has_cone:  # robust_cbf._outside_cone_and_zone
            offset = coast[:3] - apex
            distance = _norm3(offset)
            slack = _dot3(_axis(apex), offset) - math.cos(half_angle) * distance
            if distance <= APEX:
                slack = max(slack, 0.0)
            outside = slack < 0.0 and _norm3(coast[:3] - g) > radius
        for _ in range(LINEARISATIONS):
            rows, h, applies = _barrier_rows(
                x,
                apex,
                point,
                a,
                b,
                lever,
                koz,
                standoff + eps,
                has_speed,
                v0_tight,
                v1,
                has_cone,
                half_angle,
                radius,
            )
            if has_cone:  # robust_cbf._zone_rows
                r_next = coast[:3] - g
                two_step = two[:3] - g
                norm = _norm3(r_next)
                normal = r_next / norm if norm > 0.0 else r_next
                predicted = two_step + _mat_vec(lever, point)
                near = _norm3(predicted) <= radius + ZONE_LOOKAHEAD
                if outside:
                    rows[2] = _mat_vec(lever.T, normal)
                    h[2] = radius + eps - _dot3(normal, two_step)
                if stop > 0.0 and not outside and _dot3(predicted, port_axis) < 2.0 * stop:
                    rows[2] = _mat_vec(lever.T, port_axis)
                    h[2] = stop - _dot3(port_axis, two_step)
                applies[2] = outside or near
            size = _norm3(point)
            for i in range(3):
                h[i] += actuation * _norm3(rows[i]) * size
            u, feasible = _polytope_box(u0, rows, h, applies, u_max)
            if not feasible or (u[0] == point[0] and u[1] == point[1] and u[2] == point[2]):
                break
            point = u
        if feasible:  # robust_cbf._met: the exact prediction from the estimate
            _, broken = _broken_when_held(
                x, apex, u, a, b, has_speed, v0_tight, v1, has_cone, half_angle, radius
            )
            met = not broken[1]
            if has_cone:
                if outside:
                    after = _mat_vec(a, x) + _mat_vec(b, u)
                    held = _mat_vec(a, after) + _mat_vec(b, u)
                    met = met and _norm3(held[:3] - g) >= radius + eps - CONE_SLACK
                else:
                    met = met and not broken[2]
            if met:
                return u, fraction, np.zeros(3, dtype=np.bool_)
    return _clip3(u0, u_max), 0.0, np.zeros(3, dtype=np.bool_)  # not reached: scale 0 always answers
