"""The predictive CBF filter for every docking constraint at once: one QP per action, solved exactly
and batched.

    min ||u - u_0||^2   s.t.   G_i^T u >= h_i  for each barrier i that applies,   |u_j| <= u_max.

Each barrier is a half-space in ``u``, looked ahead by its relative degree under the action held:

| Barrier    | Relative degree | Predicted quantity                    | Half-space                                 |
|------------|-----------------|---------------------------------------|--------------------------------------------|
| keep-out   | two             | ``r_{t+2} = [A^2 x]_r + L u``         | :func:`cwh_envs.cbf.barrier_terms`, as alone |
| speed limit| one             | ``x_{t+1} = A x + B u``               | ``||v|| <= v0 + v1 ||r - g||`` linearised    |
| cone       | two             | ``r_{t+2} - g``                       | ``a^T d >= cos(theta) ||d||`` linearised     |

``L = [A B + B]_r``. The keep-out row is the one :mod:`cwh_envs.cbf` uses alone (a tangent plane of
the sphere: inside the safe set). The speed limit and the cone are convex sets, and their rows are
their tangent planes at the prediction under the nominal action ``clip(u_0)``. A tangent plane of a
convex set contains it, so these two rows are exact at the point of tangency and first-order
accurate away from it: under Euler, with no thrust bound active, the speed row's correction moves
``v_{t+1}`` along the ray it lies on, so the speed lands on the limit exactly; the cone row is
exact to first order in the correction. The env measures the true constraints (its costs), so
whatever this leaves is counted, never hidden. The cone applies where ``||r_{t+2} - g|| <=
radius`` under the nominal action, the speed row wherever ``v_{t+1} != 0``.

**Exact minimiser.** Write all constraints as ``R u >= d`` with rows normalised: up to three
barriers and six bounds. The minimiser is the projection of ``u_0`` onto the affine set of a
linearly independent subset of its active rows (Caratheodory on the KKT multipliers), so it is one
of finitely many candidates; among the feasible ones it is the closest. Three stages, each only on
the instances the previous left:

1. ``clip(u_0)`` is feasible: it is the answer.
2. For each barrier ``i`` it violates, the exact half-space-and-box minimiser of
   :func:`cwh_envs.cbf.project_halfspace_box` (a relaxation). One that satisfies the other barriers
   is the answer: it is optimal for a relaxation and feasible. One with no box action at all
   means the whole QP has none.
3. Otherwise at least two barriers are active at the minimiser. For each pair, the minimiser over
   their common line within the box (a clip of one parameter: it covers the pair with any bound
   active), and the vertex of all three: four closed-form candidates, of which the closest feasible
   is the answer. None feasible means no box action satisfies every barrier.

**When no box action satisfies every barrier**, the filter drops barriers in reverse priority --
the cone first, then the speed limit -- until one does, and with the keep-out alone it behaves as
:mod:`cwh_envs.cbf` (the action that best satisfies it). ``dropped`` says which were dropped.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from cwh_envs.cbf import barrier_terms, project_halfspace_box
from cwh_envs.constraints import APEX, SPEED_TOLERANCE, cone_axis, cone_terms, speed_margin
from cwh_envs.dynamics import apply

BARRIERS = ("keep_out", "speed", "cone")  # priority order: the last is dropped first
FEASIBILITY_TOLERANCE = 1e-10  # N, on normalised rows: a candidate this close to a face is on it
LINEARISATIONS = 3  # QPs per action: the speed and cone rows re-linearised at the previous answer
# The linearised speed row may leave up to this after LINEARISATIONS passes; the row aims this far
# inside the limit so that what it leaves is still within it (checked to SPEED_TOLERANCE).
SPEED_SLACK = 1e-4  # m/s
CONE_SLACK = 1e-3  # m: what the cone row may leave (not tightened: the cone narrows to its apex at the port)
DEGENERATE = 1e-12  # Gram determinant below which a candidate's rows count as dependent


class MultiCBFResult(NamedTuple):
    """Filtered thrust and diagnostics, leading dimension N (none for a single instance).

    ``u`` (N, 3) N; ``active`` (N,) bool: the filter changed the box-clipped nominal action;
    ``infeasible`` (N,) bool: no box action satisfies every barrier that applies; ``correction_norm``
    (N,) N: ``||u - clip(u_nominal)||``; ``dropped`` (N, 3) bool: the barriers, in
    :data:`BARRIERS` order, left out to find an action (all False unless infeasible).
    """

    u: np.ndarray
    active: np.ndarray
    infeasible: np.ndarray
    correction_norm: np.ndarray
    dropped: np.ndarray


def barrier_rows(states, goals, u_nominal, a, b, *, koz_radius, margin, speed_limit, approach_cone):
    """``G`` (N, 3, 3), ``h`` (N, 3) and ``applies`` (N, 3) bool of the barriers ``G_i^T u >= h_i``, in
    :data:`BARRIERS` order; a barrier the problem lacks never applies. ``u_nominal`` is box-clipped."""
    n = len(states)
    g_rows = np.zeros((n, 3, 3))
    h = np.zeros((n, 3))
    applies = np.zeros((n, 3), dtype=bool)
    g_rows[:, 0], h[:, 0] = barrier_terms(states, a, b, koz_radius + margin)
    applies[:, 0] = True
    coast = apply(a, states)
    if speed_limit is not None:
        v0, v1 = speed_limit
        nominal = coast + apply(b, u_nominal)  # x_{t+1} under the nominal action
        offset = nominal[:, :3] - goals
        speed, distance = np.linalg.norm(nominal[:, 3:], axis=1), np.linalg.norm(offset, axis=1)
        along_v = _unit(nominal[:, 3:], speed)
        along_r = _unit(offset, distance)
        # f(u) = ||v_{t+1}|| - v0 - v1 ||r_{t+1} - g|| <= 0, linearised at u_nominal: grad^T u <= ...
        grad = apply(b[3:].T, along_v) - v1 * apply(b[:3].T, along_r)
        excess = speed - (v0 - np.minimum(SPEED_SLACK, v0 / 2)) - v1 * distance  # tightened: see SPEED_SLACK
        g_rows[:, 1] = -grad
        h[:, 1] = excess - np.einsum("ni,ni->n", grad, u_nominal)
        applies[:, 1] = speed > 0.0
    if approach_cone is not None:
        half_angle, radius = approach_cone
        lever = (a @ b + b)[:3]
        drift = apply(a, coast)[:, :3] - goals  # r_{t+2} - g with no thrust
        offset = drift + apply(lever, u_nominal)
        distance = np.linalg.norm(offset, axis=1)
        axis = cone_axis(goals)
        cosine = np.cos(np.radians(half_angle))
        # h(d) = a^T d - cos ||d|| is 1-homogeneous, so its tangent plane passes through the apex.
        direction = np.where(distance[:, None] > APEX, _unit(offset, distance), axis)
        normal = axis - cosine * direction
        g_rows[:, 2] = apply(lever.T, normal)
        h[:, 2] = -np.einsum("ni,ni->n", normal, drift)
        applies[:, 2] = distance <= radius
    return g_rows, h, applies


def _unit(vectors: np.ndarray, norms: np.ndarray) -> np.ndarray:
    safe = np.where(norms > 0.0, norms, 1.0)[:, None]
    return np.where(norms[:, None] > 0.0, vectors / safe, 0.0)


def project_polytope_box(u0, g_rows, h, applies, u_max):
    """Exact ``argmin ||u - u0||^2 s.t. G_i^T u >= h_i (where applies), |u_j| <= u_max``.

    ``u0`` (N, 3), ``g_rows`` (N, 3, 3), ``h`` and ``applies`` (N, 3): three barrier rows, as
    :func:`barrier_rows` gives them. Returns ``u`` (N, 3)
    and ``feasible`` (N,); where infeasible ``u`` is ``clip(u0)`` (the caller decides what to do).
    """
    norms = np.sqrt(np.sum(g_rows**2, axis=2))
    live = applies & (norms > 0.0)
    # A zero row applies as 0 >= h: always met where h <= 0, never where h > 0.
    hopeless = np.any(applies & (norms == 0.0) & (h > 0.0), axis=1)
    scale = np.where(live, norms, 1.0)
    rows = np.where(live[:, :, None], g_rows / scale[:, :, None], 0.0)
    rhs = np.where(live, h / scale, -np.inf)
    u = np.clip(u0, -u_max, u_max)
    feasible = ~hopeless
    violated = _products(rows, u) < rhs - FEASIBILITY_TOLERANCE
    idx = np.flatnonzero(feasible & violated.any(axis=1))
    if not len(idx):
        return u, feasible
    # Stage 2: a relaxation to each violated barrier, all in one call; one that meets the others wins.
    rows_at, barrier = np.nonzero(violated[idx])  # one pair per (instance left, violated barrier)
    sub = idx[rows_at]
    relaxed = project_halfspace_box(u0[sub], rows[sub, barrier], rhs[sub, barrier], u_max)
    ok = ~relaxed.infeasible & _meets(relaxed.u, rows[sub], rhs[sub])
    u[sub[ok]] = relaxed.u[ok]  # several may meet them all: each is the one minimiser
    solved = np.bincount(rows_at[ok], minlength=len(idx)) > 0
    impossible = np.bincount(rows_at[relaxed.infeasible], minlength=len(idx)) > 0  # no box action at all
    feasible[idx[impossible]] = False
    rest = idx[~solved & ~impossible]
    if len(rest):  # stage 3: two or three barriers active
        u[rest], feasible[rest] = _enumerate(u0[rest], rows[rest], rhs[rest], u_max)
    return u, feasible


def _products(rows: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``rows @ u`` per instance, (N, M, 3) and (N, 3) to (N, M), without einsum's overhead."""
    return rows[:, :, 0] * u[:, None, 0] + rows[:, :, 1] * u[:, None, 1] + rows[:, :, 2] * u[:, None, 2]


def _meets(u, rows, rhs) -> np.ndarray:
    return np.all(_products(rows, u) >= rhs - FEASIBILITY_TOLERANCE, axis=1)


FIRST, SECOND = np.array([0, 0, 1]), np.array([1, 2, 2])  # the three pairs of barrier rows


def _enumerate(u0, rows, rhs, u_max):
    """The closest feasible of four candidates (module docstring, stage 3): for each pair of
    barriers, the point of their common line closest to ``u0`` within the box (this covers the pair
    with any bound active), and the vertex where all three meet. The minimiser is among them."""
    usable = np.isfinite(rhs)
    targets = np.where(usable, rhs, 0.0)
    # The three pairs at once, (n, 3 pairs, 3): unit rows c1, c2; u = u0 + y1 c1 + y2 c2 on both.
    c1, c2 = rows[:, FIRST], rows[:, SECOND]
    s1 = targets[:, FIRST] - _dot(c1, u0[:, None])
    s2 = targets[:, SECOND] - _dot(c2, u0[:, None])
    q = _dot(c1, c2)
    det = 1.0 - q**2  # Gram determinant of the two unit rows
    pair_ok = (det > DEGENERATE) & usable[:, FIRST] & usable[:, SECOND]
    det = np.where(pair_ok, det, 1.0)
    foot = u0[:, None] + ((s1 - q * s2) / det)[..., None] * c1 + ((s2 - q * s1) / det)[..., None] * c2
    along = _cross(c1, c2)
    along /= np.where(pair_ok, np.sqrt(_dot(along, along)), 1.0)[..., None]
    # The line foot + t along meets the box on [low, high]; |u - u0| grows with |t|.
    with np.errstate(divide="ignore", invalid="ignore"):
        to_low, to_high = (-u_max - foot) / along, (u_max - foot) / along  # (n, 3 pairs, 3 axes)
    flat = along == 0.0
    inside = np.abs(foot) <= u_max
    low = np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(to_low, to_high)).max(axis=2)
    high = np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(to_low, to_high)).min(axis=2)
    pair_ok &= low <= high
    lines = foot + np.where(pair_ok, np.clip(0.0, low, high), 0.0)[..., None] * along
    # The vertex of all three, by Cramer's rule with cross products.
    r1, r2, r3 = rows[:, 0], rows[:, 1], rows[:, 2]
    cross23, cross31, cross12 = _cross(r2, r3), _cross(r3, r1), _cross(r1, r2)
    volume = _dot(r1, cross23)
    vertex_ok = (np.abs(volume) > DEGENERATE) & np.all(usable, axis=1)
    volume = np.where(vertex_ok, volume, 1.0)
    vertex = (targets[:, :1] * cross23 + targets[:, 1:2] * cross31 + targets[:, 2:3] * cross12) / volume[
        :, None
    ]
    vertex_ok &= np.all(np.abs(vertex) <= u_max + FEASIBILITY_TOLERANCE, axis=1)
    candidates = np.concatenate([lines, vertex[:, None]], axis=1)  # (n, 4, 3)
    valid = np.concatenate([pair_ok, vertex_ok[:, None]], axis=1)
    slack = np.matmul(candidates, rows.transpose(0, 2, 1)) - rhs[:, None, :]  # (n, 4, 3)
    valid &= np.all(slack >= -FEASIBILITY_TOLERANCE, axis=2)
    cost = np.where(valid, np.sum((candidates - u0[:, None]) ** 2, axis=2), np.inf)
    pick = np.argmin(cost, axis=1)
    n = np.arange(len(u0))
    feasible = np.isfinite(cost[n, pick])
    u = np.where(feasible[:, None], candidates[n, pick], np.clip(u0, -u_max, u_max))
    return np.clip(u, -u_max, u_max), feasible


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return x[..., 0] * y[..., 0] + x[..., 1] * y[..., 1] + x[..., 2] * y[..., 2]


def _cross(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.stack(
        [
            x[..., 1] * y[..., 2] - x[..., 2] * y[..., 1],
            x[..., 2] * y[..., 0] - x[..., 0] * y[..., 2],
            x[..., 0] * y[..., 1] - x[..., 1] * y[..., 0],
        ],
        axis=-1,
    )


def _linearised(u0, states, goals, a, b, dropped, u_max, terms):
    """The QP re-linearised LINEARISATIONS times, then checked on the exact held-action prediction:
    ``met`` where it is feasible and every barrier kept holds at ``x_{t+1}`` (speed) and ``x_{t+2}``
    (cone) to within the verification tolerances."""
    point = np.clip(u0, -u_max, u_max)
    u, feasible = point.copy(), np.ones(len(u0), dtype=bool)
    todo = np.arange(len(u0))
    for _ in range(LINEARISATIONS):
        g_rows, h, applies = barrier_rows(states[todo], goals[todo], point[todo], a, b, **terms)
        applies &= ~dropped[todo]
        found, ok = project_polytope_box(u0[todo], g_rows, h, applies, u_max)
        u[todo], feasible[todo] = found, ok
        # Re-linearise only where a speed or cone row applied and the answer left its tangent point.
        moved = ok & (applies[:, 1] | applies[:, 2]) & np.any(found != point[todo], axis=1)
        point[todo[ok]] = found[ok]
        todo = todo[moved]
        if not len(todo):
            break
    return u, feasible & ~np.any(broken_when_held(states, goals, u, a, b, terms)[1] & ~dropped, axis=1)


def broken_when_held(states, goals, u, a, b, terms) -> tuple[np.ndarray, np.ndarray]:
    """Which barriers apply to the held action ``u`` and which it breaks, each (N, 3) bool, from the
    exact prediction: the speed limit at ``x_{t+1}`` (beyond SPEED_TOLERANCE), the cone at ``x_{t+2}``
    within its radius (beyond CONE_SLACK). The keep-out always applies and is never counted broken
    here: its row is exact."""
    applies = np.zeros((len(u), 3), dtype=bool)
    broken = np.zeros((len(u), 3), dtype=bool)
    applies[:, 0] = True
    after = apply(a, states) + apply(b, u)
    if terms["speed_limit"] is not None:
        applies[:, 1] = True
        broken[:, 1] = speed_margin(after, goals, terms["speed_limit"]) < -SPEED_TOLERANCE
    if terms["approach_cone"] is not None:
        region, slack, _ = cone_terms(apply(a, after) + apply(b, u), goals, terms["approach_cone"])
        applies[:, 2] = region
        broken[:, 2] = region & (slack < -CONE_SLACK)
    return applies, broken


def check_filter_inputs(u_nominal, states, goals, state_name: str = "states"):
    """(u_nominal, states, goals) as float64 (N, 3), (N, 6), (N, 3) and whether one instance came in
    1-D; a shape or a non-finite entry raises ValueError naming it (``state_name``: what the states are)."""
    u_nominal = np.asarray(u_nominal, dtype=np.float64)
    states = np.asarray(states, dtype=np.float64)
    goals = np.asarray(goals, dtype=np.float64)
    if (
        states.shape[-1] != 6
        or states.ndim > 2
        or not (u_nominal.shape == goals.shape == (*states.shape[:-1], 3))
    ):
        raise ValueError(
            f"{state_name} must be (6,) or (N, 6), u_nominal and goals (3,) or (N, 3) alike, got "
            f"{states.shape}, {u_nominal.shape} and {goals.shape}"
        )
    if not all(np.all(np.isfinite(x)) for x in (states, u_nominal, goals)):
        raise ValueError(f"{state_name}, u_nominal and goals must be finite, got NaN/inf entries")
    return np.atleast_2d(u_nominal), np.atleast_2d(states), np.atleast_2d(goals), states.ndim == 1


def safe_actions_multi(
    u_nominal,
    states,
    goals,
    a: np.ndarray,
    b: np.ndarray,
    *,
    koz_radius: float,
    margin: float,
    u_max: float,
    speed_limit: tuple[float, float] | None = None,
    approach_cone: tuple[float, float] | None = None,
) -> MultiCBFResult:
    """Filter nominal thrust (N, 3) [N] at states (N, 6) docking at goals (N, 3); 1-D in, 1-D out."""
    u0, states, goals, single = check_filter_inputs(u_nominal, states, goals)
    if not (np.isfinite(u_max) and u_max > 0):
        raise ValueError(f"u_max must be a positive finite number, got {u_max!r}")
    base = np.clip(u0, -u_max, u_max)
    terms = dict(koz_radius=koz_radius, margin=margin, speed_limit=speed_limit, approach_cone=approach_cone)
    u = base.copy()
    dropped = np.zeros((len(u0), 3), dtype=bool)
    stuck = np.arange(len(u0))
    for drop in (None, 2, 1):  # every barrier; then without the cone; then without the speed limit
        if drop is not None:
            dropped[stuck, drop] = True
        found, met = _linearised(u0[stuck], states[stuck], goals[stuck], a, b, dropped[stuck], u_max, terms)
        u[stuck[met]] = found[met]
        stuck = stuck[~met]
        if not len(stuck):
            break
    if len(stuck):  # the keep-out alone is infeasible: the thrust that best satisfies it
        beta, rho = barrier_terms(states[stuck], a, b, koz_radius + margin)
        u[stuck] = project_halfspace_box(u0[stuck], beta, rho, u_max).u
    dropped &= broken_when_held(states, goals, u, a, b, terms)[
        0
    ]  # a barrier that does not apply was not given up
    correction = np.linalg.norm(u - base, axis=1)
    infeasible = np.any(dropped, axis=1)
    infeasible[stuck] = True
    result = MultiCBFResult(u, correction > 0.0, infeasible, correction, dropped)
    return MultiCBFResult(*(field[0] for field in result)) if single else result
