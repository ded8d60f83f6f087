"""A robust multi-constraint CBF filter: the filter of :mod:`cwh_envs.cbf_multi` with every barrier
tightened by margins sized from declared error bounds, acting on the navigation estimate.

Anchors: Breeden and Panagou's robust CBF for HCW docking (L-CSS 2022: a margin from the bounds on
disturbance and actuation) and Cosner et al.'s measurement-robust CBF (2021: a margin for the
state-estimate error). Nothing here is specific to one controller: the nominal action comes from
any policy.

**The bounds** (:class:`ErrorBounds`) are one-sigma errors, as :mod:`cwh_envs.dispersions` draws
them, and ``k_sigma``, how many sigmas the margins cover. Each barrier is a half-space in the
predicted state, so what matters is each error's component along the barrier's normal; for the
isotropic navigation noise that component has exactly the per-axis sigma. The margins hold for
any error whose component along every normal is within its k sigmas (a bounded error, not a
Gaussian one: the position and velocity terms add). Per step:

| Error                  | Enters the prediction as                   | Margin (k sigmas along the normal)               |
|------------------------|--------------------------------------------|--------------------------------------------------|
| navigation ``r, v``    | ``x_hat - x``, propagated by ``A`` / ``A^2`` | ``k (s_r ||M_rr|| + s_v ||M_rv||)``               |
| thrust scale, mass, misalignment | ``(G - I) u``, ``G = s/m R(alpha)`` | ``e_u ||row|| ||u||``, ``e_u = (1+k s_s)/(1-k s_m) (1 + 2 sin(k alpha / 2)) - 1`` |

``M`` is ``A^2`` for the keep-out and the cone (relative degree two), ``A`` for the speed limit;
the speed limit's distance term adds ``v1`` times the position margin of ``x_{t+1}``. The thrust
term depends on the action: it is linearised at the same point as the speed and cone rows
(:data:`cwh_envs.cbf_multi.LINEARISATIONS` passes).

**The tightened constraints:** the keep-out radius grows by the position margin ``eps``; the speed
limit's ``v0`` shrinks by the speed margin; the approach cone is eroded by ``eps`` (Euclidean): its
apex moves ``eps / sin(half_angle)`` toward the chaser, from where the env scores it
(``capture_radius / tan(half_angle)`` behind the port). An erosion larger than the capture
envelope puts the apex in front of the port, where no docking chaser can stay inside: the filter
then needs the rule below.

**The cone's zone is anticipated.** The cone is a union (inside the cone, or outside its zone), and
a chaser that crosses into the zone outside the cone cannot be turned in the two steps the row
looks ahead. So the third row is chosen per instance from ``x_{t+1}``: outside the cone and outside
the zone, the zone's ball about the port is a keep-out (``||r_{t+2} - g|| >= radius + eps``, linearised as the
keep-out row is), so the chaser enters the zone only inside the cone; inside the cone, the cone's
row holds from ZONE_LOOKAHEAD beyond the zone on. (Measured on 64 constrained search starts, 1
sigma: without this, one start of the routed law entered the zone 0.7 m outside the cone.)

**A stop line where the eroded corridor is narrower than its margin** (``stop_line=True``). Near
the eroded apex the corridor left by the erosion is a few centimetres wide; an estimate that moves
by as much from one step to the next leaves it, and the full margin then has no action (measured:
``results/robust-safety/why_covariance_misses_3sigma.txt``: with margins sized by a navigation
filter's covariance at 3x the noise, the eroded apex lies in front of the port, every start lost
first has no action three steps from the end, where the nominal law drives it at the port). With
the stop line, the chaser does not cross the plane normal to the cone's axis at which the eroded
corridor's half-width equals the position margin ``eps``, ``max(0, eps / tan(theta) - setback)`` in
front of the port (``setback``: how far behind the port the eroded apex lies): where the two-step
prediction comes nearer the port than twice the line's distance, the plane replaces the cone's row
(exact: it is linear in the thrust), and the exact check still holds the cone. Where the margins leave the corridor wide
at the port (``eps <= setback tan(theta)``) the line is at the port or behind it and never binds, so
a chaser whose margins are small (a converged filter, 1 sigma) still docks, and one whose margins
are large (3 sigma) stops short where the corridor has room. Off by default: the robust rows
committed before it was built fly without it.

**Where no action satisfies every tightened constraint** the filter answers by least violation of
the margin, never by a stale action: it retries with the margins scaled by each of
:data:`MARGIN_SCALES` in turn and keeps the first scale that has an action; at scale 0 it is the
nominal multi-constraint filter on the scored corridor, which then drops the cone, then the speed
limit (:mod:`cwh_envs.cbf_multi`). ``margin_scale`` says, per instance, how much of the margin was
kept, ``infeasible`` that the full margin was not, and ``dropped`` what the nominal filter gave up.

With every bound zero, every margin is zero and the filter is the nominal one on the scored
corridor (tests/test_robust_cbf.py).

**Margins from an estimator's own error** (``navigation_sigma``). The declared navigation bounds are
a raw measurement's. Behind a navigation filter the estimate's error is the filter's covariance,
a third to a tenth of the raw noise once it has converged (:meth:`cwh_envs.navigation.NavigationFilter.sigma`).
Given per row, those one-sigma errors replace the bounds' in the navigation margins, at the same
``k_sigma``; the thrust-error margin stays the bounds'. This is the measurement-robust CBF of Cosner
et al. with the estimator's error bound at each step, not a constant one. The guarantee is the
covariance's: k sigmas of a Gaussian error, where the filter's model holds (its ``noise_scale``
widens it where the measurements are noisier than the filter was sized for).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np

from cwh_envs.cbf_multi import (
    CONE_SLACK,
    LINEARISATIONS,
    barrier_rows,
    broken_when_held,
    check_filter_inputs,
    project_polytope_box,
    safe_actions_multi,
)
from cwh_envs.constraints import cone_axis, cone_terms
from cwh_envs.dynamics import apply

MARGIN_SCALES = (1.0, 0.5, 0.25, 0.0)  # fractions of the margins tried in turn (module docstring)
# m: the cone's row holds this far beyond its zone for a chaser inside the cone, so that one headed
# into the zone is already held there when it crosses (two steps of a 0.05 m/s approach).
ZONE_LOOKAHEAD = 1.0


@dataclass(frozen=True)
class ErrorBounds:
    """One-sigma errors the filter is sized for, and ``k_sigma``: how many sigmas its margins cover.

    ``thrust_scale`` and ``mass`` are fractions, ``misalignment_deg`` degrees, ``nav_position`` m and
    ``nav_velocity`` m/s per axis: the arguments of :class:`cwh_envs.dispersions.Dispersions`.
    """

    thrust_scale: float = 0.0
    misalignment_deg: float = 0.0
    mass: float = 0.0
    nav_position: float = 0.0
    nav_velocity: float = 0.0
    k_sigma: float = 3.0

    def __post_init__(self) -> None:
        for field in fields(self):
            value = getattr(self, field.name)
            numeric = isinstance(value, int | float | np.integer | np.floating) and not isinstance(
                value, bool
            )
            if not (numeric and np.isfinite(value) and value >= 0):
                raise ValueError(f"ErrorBounds.{field.name} must be a finite number >= 0, got {value!r}")
        for name in ("thrust_scale", "mass"):
            if self.k_sigma * getattr(self, name) >= 1.0:
                raise ValueError(
                    f"ErrorBounds.{name} at k_sigma={self.k_sigma:g} reaches 100 % "
                    f"({self.k_sigma * getattr(self, name):g}): no margin bounds a thrust that may vanish"
                )

    @classmethod
    def from_dispersions(cls, spreads: dict, k_sigma: float = 3.0) -> ErrorBounds:
        """Bounds from the standard deviations a dispersed flight draws (missing ones 0)."""
        from cwh_envs.dispersions import check_spreads

        return cls(**check_spreads(spreads), k_sigma=k_sigma)

    def actuation(self) -> float:
        """``e_u``: the relative thrust error ``||(G - I) u|| / ||u||`` at k sigmas."""
        k = self.k_sigma
        gain = (1.0 + k * self.thrust_scale) / (1.0 - k * self.mass)
        return gain * (1.0 + 2.0 * np.sin(np.radians(k * self.misalignment_deg) / 2.0)) - 1.0

    def navigation(self, propagate: np.ndarray, sigma: np.ndarray | None = None) -> float | np.ndarray:
        """The k-sigma position error along any unit normal of ``[propagate @ (x_hat - x)]_r``; per
        row (N,) where ``sigma`` (N, 2) gives each row's one-sigma errors instead of the bounds'."""
        s_r, s_v = self._navigation_sigma(sigma)
        rr, rv = propagate[:3, :3], propagate[:3, 3:]
        return self.k_sigma * (s_r * np.linalg.norm(rr, 2) + s_v * np.linalg.norm(rv, 2))

    def speed(self, a: np.ndarray, sigma: np.ndarray | None = None) -> float | np.ndarray:
        """The k-sigma error of the estimated ``||v_{t+1}||``, m/s (``sigma`` as :meth:`navigation`)."""
        s_r, s_v = self._navigation_sigma(sigma)
        vr, vv = a[3:, :3], a[3:, 3:]
        return self.k_sigma * (s_r * np.linalg.norm(vr, 2) + s_v * np.linalg.norm(vv, 2))

    def position_margin(self, a: np.ndarray, sigma: np.ndarray | None = None) -> float | np.ndarray:
        """The k-sigma navigation error of a two-step position prediction (keep-out, cone), m."""
        return self.navigation(a @ a, sigma)

    def speed_margin(self, a: np.ndarray, v1: float, sigma: np.ndarray | None = None) -> float | np.ndarray:
        """The k-sigma navigation error of the speed limit ``||v|| <= v0 + v1 ||r - g||`` one step
        ahead: the speed's and ``v1`` times the position's, m/s."""
        return self.speed(a, sigma) + v1 * self.navigation(a, sigma)

    def _navigation_sigma(self, sigma):
        if sigma is None:
            return self.nav_position, self.nav_velocity
        return sigma[:, 0], sigma[:, 1]


class RobustCBFResult(NamedTuple):
    """As :class:`cwh_envs.cbf_multi.MultiCBFResult`, plus ``margin_scale`` (N,): the fraction of
    the robust margins the answer keeps (1 where the full tightening had an action). ``infeasible``
    is True wherever it is below 1."""

    u: np.ndarray
    active: np.ndarray
    infeasible: np.ndarray
    correction_norm: np.ndarray
    dropped: np.ndarray
    margin_scale: np.ndarray


def robust_safe_actions(
    u_nominal,
    estimates,
    goals,
    problem,
    bounds: ErrorBounds,
    margin: float | None = None,
    navigation_sigma=None,
    stop_line: bool = False,
) -> RobustCBFResult:
    """Filter nominal thrust (N, 3) [N] at the estimated states (N, 6) docking at goals (N, 3) on a
    :class:`cwh_envs.problems.DockingProblem`, robust to ``bounds`` (module docstring). ``margin`` is
    the keep-out standoff (``problem.margin`` by default). ``navigation_sigma`` (N, 2), each row's
    one-sigma estimate error (position m, velocity m/s), replaces the bounds' navigation errors per
    row: a navigation filter's own covariance (:meth:`cwh_envs.navigation.NavigationFilter.sigma`),
    as Cosner et al.'s measurement-robust CBF sizes its margin by the estimator's error bound.
    ``stop_line`` holds the chaser short of the port where the eroded corridor is narrower than the
    margin (module docstring). 1-D in, 1-D out."""
    if not isinstance(bounds, ErrorBounds):
        raise ValueError(f"bounds must be an ErrorBounds, got {type(bounds).__name__}")
    if not isinstance(stop_line, bool | np.bool_):
        raise ValueError(f"stop_line must be True or False, got {stop_line!r}")
    u0, states, goals2, single = check_filter_inputs(u_nominal, estimates, goals, state_name="estimates")
    sigma = None if navigation_sigma is None else _check_sigma(navigation_sigma, len(states))
    standoff = problem.margin if margin is None else float(margin)
    a, b = problem.matrices()
    u_max = problem.u_max
    n = len(states)
    u = np.clip(u0, -u_max, u_max)
    scale = np.zeros(n)
    dropped = np.zeros((n, 3), dtype=bool)
    todo = np.arange(n)
    for fraction in MARGIN_SCALES:
        if fraction == 0.0:  # the nominal filter on the scored corridor, with its own drop rule
            tight = _Tightened(problem, bounds, a, b, 0.0, goals2[todo], standoff, None)
            nominal = safe_actions_multi(u0[todo], states[todo], tight.apex, a, b, u_max=u_max, **tight.terms)
            u[todo], dropped[todo] = nominal.u, nominal.dropped
            break
        rows = None if sigma is None else sigma[todo]
        tight = _Tightened(problem, bounds, a, b, fraction, goals2[todo], standoff, rows, stop_line)
        found, ok = _solve(u0[todo], states[todo], tight, a, b, u_max)
        u[todo[ok]], scale[todo[ok]] = found[ok], fraction
        todo = todo[~ok]
        if not len(todo):
            break
    correction = np.linalg.norm(u - np.clip(u0, -u_max, u_max), axis=1)
    result = RobustCBFResult(u, correction > 0.0, scale < 1.0, correction, dropped, scale)
    return RobustCBFResult(*(field[0] for field in result)) if single else result


def _check_sigma(navigation_sigma, n: int) -> np.ndarray:
    """``navigation_sigma`` as (n, 2) float64; (2,) for one instance; anything else raises, naming it."""
    try:
        sigma = np.asarray(navigation_sigma, dtype=np.float64)
    except (TypeError, ValueError):
        sigma = np.full(0, np.nan)
    if sigma.shape == (2,) and n == 1:
        sigma = sigma[None]
    if sigma.shape != (n, 2) or not np.all(np.isfinite(sigma)) or np.any(sigma < 0.0):
        raise ValueError(
            f"navigation_sigma must be finite one-sigma errors >= 0 of shape ({n}, 2) (position m, "
            f"velocity m/s per estimate), got {navigation_sigma!r}"
        )
    return sigma


class _Tightened:
    """The tightened constraints of one margin fraction, for a batch of goals (module docstring);
    with ``sigma`` (N, 2), the navigation margins are per row (N,)."""

    def __init__(
        self,
        problem,
        bounds: ErrorBounds,
        a,
        b,
        fraction: float,
        goals,
        standoff: float,
        sigma,
        stop_line: bool = False,
    ) -> None:
        self.eps = fraction * bounds.position_margin(a, sigma)  # m
        self.actuation = fraction * bounds.actuation()
        self.goals = goals  # the ports: the cone's zone is the ball of its radius about the port, as scored
        self.apex = goals
        self.stop = None  # m in front of the port: the stop line (module docstring), where asked for
        speed_limit, cone = problem.speed_limit, problem.approach_cone
        setback = 0.0
        if cone is not None:
            half_angle = np.radians(cone[0])
            setback = problem.capture_radius / np.tan(half_angle) - self.eps / np.sin(half_angle)
            self.apex = goals - np.reshape(setback, (-1, 1)) * cone_axis(goals)
            if stop_line:
                self.stop = np.broadcast_to(
                    np.maximum(0.0, self.eps / np.tan(half_angle) - setback), (len(goals),)
                )
        if speed_limit is not None:
            v0, v1 = speed_limit
            # The speed row measures distance from the apex: |d(apex) - d(g)| <= |setback|.
            shrink = fraction * bounds.speed_margin(a, v1, sigma) + v1 * np.abs(setback)
            speed_limit = (np.maximum(v0 - shrink, 1e-9), v1)
        self.terms = dict(
            koz_radius=problem.koz_radius,
            margin=standoff + self.eps,
            speed_limit=speed_limit,
            approach_cone=cone,
        )


def _solve(u0, states, tight: _Tightened, a, b, u_max):
    """The tightened QP, re-linearised at its answer LINEARISATIONS times, with the thrust-error
    term ``e_u ||row|| ||u||`` evaluated at the linearisation point; then checked on the exact
    prediction. Returns (u, met)."""
    point = np.clip(u0, -u_max, u_max)
    u, feasible = point.copy(), np.ones(len(u0), dtype=bool)
    cone = tight.terms["approach_cone"] is not None
    outside = _outside_cone_and_zone(states, tight, a) if cone else None
    for _ in range(LINEARISATIONS):
        # The keep-out's eps is in its radius and the cone's in its apex (terms); the thrust error here.
        rows, h, applies = barrier_rows(states, tight.apex, point, a, b, **tight.terms)
        if cone:
            rows[:, 2], h[:, 2], applies[:, 2] = _zone_rows(
                states, tight, a, b, point, outside, rows[:, 2], h[:, 2]
            )
        h += tight.actuation * np.linalg.norm(rows, axis=2) * np.linalg.norm(point, axis=1)[:, None]
        u, feasible = project_polytope_box(u0, rows, h, applies, u_max)
        if np.array_equal(u[feasible], point[feasible]):
            break
        point = np.where(feasible[:, None], u, point)
    return u, feasible & _met(states, tight, u, a, b, outside)


def _outside_cone_and_zone(states, tight: _Tightened, a) -> np.ndarray:
    """True where the chaser, at ``x_{t+1}``, is outside the cone and outside the zone: the zone's
    ball is then its barrier (:func:`_zone_rows`)."""
    radius = tight.terms["approach_cone"][1]
    r_next = apply(a, states)[:, :3]
    _, slack, _ = cone_terms(
        np.concatenate([r_next, np.zeros_like(r_next)], axis=1), tight.apex, tight.terms["approach_cone"]
    )
    return (slack < 0.0) & (np.linalg.norm(r_next - tight.goals, axis=1) > radius)


def _zone_rows(states, tight: _Tightened, a, b, point, outside, cone_row, cone_h):
    """The third barrier row per instance: the tightened cone where the chaser is inside it, or
    headed into the zone while inside it (anticipated ZONE_LOOKAHEAD beyond the zone); outside the
    cone and outside the zone, the zone's ball as a keep-out, ``||r_{t+2} - g|| >= radius + eps``
    about the port ``g`` (the zone the env scores, not one about the moved apex: that ball is
    ``setback`` smaller on the chaser's side), linearised at ``r_{t+1}`` as the keep-out row is.
    Returns (row, h, applies)."""
    radius = tight.terms["approach_cone"][1]
    coast = apply(a, states)
    r_next = coast[:, :3] - tight.goals
    two_step = apply(a, coast)[:, :3] - tight.goals
    norm = np.linalg.norm(r_next, axis=1, keepdims=True)
    normal = r_next / np.where(norm > 0.0, norm, 1.0)
    ball_row = apply((a @ b + b)[:3].T, normal)
    ball_h = radius + tight.eps - np.einsum("ni,ni->n", normal, two_step)
    predicted = two_step + apply((a @ b + b)[:3], point)
    near = np.linalg.norm(predicted, axis=1) <= radius + ZONE_LOOKAHEAD
    row = np.where(outside[:, None], ball_row, cone_row)
    h = np.where(outside, ball_h, cone_h)
    if tight.stop is not None:  # the stop line replaces the cone's row where the prediction crosses it
        axis = cone_axis(tight.goals)
        # within twice the line's distance of the port, so that the row stays on the re-linearisations
        # once an answer sits on the line
        crossing = ~outside & (tight.stop > 0.0) & (np.einsum("ni,ni->n", predicted, axis) < 2.0 * tight.stop)
        row = np.where(crossing[:, None], apply((a @ b + b)[:3].T, axis), row)
        h = np.where(crossing, tight.stop - np.einsum("ni,ni->n", axis, two_step), h)
    return row, h, outside | near


def _met(states, tight: _Tightened, u, a, b, outside) -> np.ndarray:
    """Whether the held action meets the tightened speed limit and cone on the exact prediction
    from the estimate, as the nominal filter checks its own (:func:`cwh_envs.cbf_multi.broken_when_held`),
    or, for a chaser outside the cone and the zone, the zone's ball (the keep-out row is exact). The
    thrust-error term is first-order: not checked."""
    broken = broken_when_held(states, tight.apex, u, a, b, tight.terms)[1]
    ok = ~broken[:, 1]
    if outside is not None:
        two_step = apply(a, apply(a, states) + apply(b, u)) + apply(b, u)
        distance = np.linalg.norm(two_step[:, :3] - tight.goals, axis=1)
        radius = tight.terms["approach_cone"][1]
        ok &= np.where(outside, distance >= radius + tight.eps - CONE_SLACK, ~broken[:, 2])
    return ok
