"""Two-step predictive discrete-time CBF safety filter (paper Eq. cbf_qp), exact and batched.

Relative degree two: under Euler the thrust u_t does not move r_{t+1}, so the filter looks two
steps ahead under a held action, ``x_{t+2} = A^2 x_t + (A B + B) u``, and keeps the predicted
position outside the standoff sphere along the radial direction ``n``:

    min ||u - u_0||^2   s.t.   beta^T u >= rho,   |u_i| <= u_max,
    beta = [(A B + B)^T n]_{pos rows},   rho = (R + delta) - n^T [A^2 x_t]_{1:3}.

``n`` is the unit radial direction of ``r_{t+1}``. Under Euler ``r_{t+1} = [A x_t]_{1:3}``
exactly; under the ``"exact"`` (ZOH) model u_t nudges r_{t+1}, and the filter anchors ``n`` at
the coasting prediction ``[A x_t]_{1:3}`` instead, which keeps the constraint linear in u. When
``r_{t+1} = 0`` (the chaser predicted at the centre) ``n`` falls back to +x, the LVLH radial
axis: any unit vector gives a valid outward constraint there.

The paper's "half-space projection, then box clip" is not the minimiser once the box binds
(the clip can re-violate the half-space, or a cheaper point exists along the box face). The
exact minimiser follows from the KKT conditions: ``u(lam) = clip(u_0 + lam beta, +-u_max)``,
``lam >= 0``; ``g(lam) = beta^T u(lam)`` is nondecreasing and piecewise linear with at most six
breakpoints, so the smallest ``lam`` with ``g(lam) >= rho`` is found exactly by evaluating g at
the sorted breakpoints and interpolating on the crossing segment -- vectorised over instances.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from cwh_envs.dynamics import apply

FALLBACK_DIRECTION = np.array([1.0, 0.0, 0.0])  # +x radial, used when r_{t+1} = 0


class CBFResult(NamedTuple):
    """Filtered thrust and diagnostics; leading dimension N, or none for a single instance.

    ``u`` (N, 3) N; ``active`` (N,) bool: the barrier changed the (box-clipped) nominal action;
    ``infeasible`` (N,) bool: no action in the box satisfies the barrier, ``u`` then maximises
    ``beta^T u`` over the box; ``correction_norm`` (N,) N: ``||u - clip(u_nominal)||``, the edit
    due to the barrier alone (saturating the nominal action is not counted).
    """

    u: np.ndarray
    active: np.ndarray
    infeasible: np.ndarray
    correction_norm: np.ndarray


def safe_actions(
    u_nominal, states, a: np.ndarray, b: np.ndarray, *, koz_radius: float, margin: float, u_max: float
) -> CBFResult:
    """Filter nominal thrust u_nominal (N, 3) [N] at states (N, 6) [m, m/s]; 1-D in, 1-D out."""
    u_nominal = np.asarray(u_nominal, dtype=np.float64)
    states = np.asarray(states, dtype=np.float64)
    single = states.ndim == 1
    if states.shape[-1] != 6 or states.ndim > 2 or u_nominal.shape != (*states.shape[:-1], 3):
        raise ValueError(
            f"states must be (6,) or (N, 6) and u_nominal (3,) or (N, 3) alike, got {states.shape} "
            f"and {u_nominal.shape}"
        )
    if not (np.all(np.isfinite(states)) and np.all(np.isfinite(u_nominal))):
        raise ValueError("states and u_nominal must be finite, got NaN/inf entries")
    if not (_number(koz_radius) and koz_radius > 0 and _number(margin) and margin >= 0):
        raise ValueError(f"need finite koz_radius > 0 and margin >= 0, got {koz_radius!r}, {margin!r}")
    beta, rho = barrier_terms(np.atleast_2d(states), a, b, koz_radius + margin)
    result = project_halfspace_box(np.atleast_2d(u_nominal), beta, rho, u_max)
    return CBFResult(*(field[0] for field in result)) if single else result


def _number(value) -> bool:
    return isinstance(value, int | float | np.number) and not isinstance(value, bool) and np.isfinite(value)


def barrier_terms(states: np.ndarray, a: np.ndarray, b: np.ndarray, radius: float):
    """beta (N, 3) [m/N] and rho (N,) [m] of the constraint ``beta^T u >= rho``; radius = R + delta."""
    # dynamics.apply, not @: a state is filtered to the same bits alone or in any batch.
    coast = apply(a, states)  # [A x_t]: r_{t+1} without the (Euler: zero) effect of u_t
    two_step = apply(a, coast)  # A^2 x_t
    r_next = coast[:, :3]
    norm = np.linalg.norm(r_next, axis=1, keepdims=True)
    normal = np.where(norm > 0.0, r_next / np.where(norm > 0.0, norm, 1.0), FALLBACK_DIRECTION)
    lever = (a @ b + b)[:3]  # (3, 3): position rows of A B + B
    beta = apply(lever.T, normal)
    rho = radius - np.einsum("ni,ni->n", normal, two_step[:, :3])
    return beta, rho


def project_halfspace_box(u0: np.ndarray, beta: np.ndarray, rho: np.ndarray, u_max: float) -> CBFResult:
    """Exact ``argmin ||u - u0||^2 s.t. beta^T u >= rho, |u_i| <= u_max`` for (N, 3) u0, beta, (N,) rho."""
    if not (np.isfinite(u_max) and u_max > 0):
        raise ValueError(f"u_max must be a positive finite number, got {u_max!r}")
    base = np.clip(u0, -u_max, u_max)
    with np.errstate(divide="ignore", invalid="ignore"):
        # Component i leaves one bound / reaches the other at lam = (+-u_max - u0_i) / beta_i.
        breaks = np.concatenate([(-u_max - u0) / beta, (u_max - u0) / beta], axis=1)
    breaks = np.where(np.isfinite(breaks) & (breaks > 0.0), breaks, 0.0)
    lams = np.concatenate([np.zeros((len(u0), 1)), np.sort(breaks, axis=1)], axis=1)  # (N, 7)
    # Past the last breakpoint every component with beta_i != 0 sits at u_max sign(beta_i),
    # so g(lams[:, -1]) is the largest value beta^T u takes on the box.
    g = np.einsum(
        "nkj,nj->nk", np.clip(u0[:, None, :] + lams[:, :, None] * beta[:, None, :], -u_max, u_max), beta
    )
    satisfied = g >= rho[:, None]
    infeasible = ~satisfied[:, -1]
    needs_push = ~satisfied[:, 0] & ~infeasible
    rows = np.arange(len(u0))
    upper = np.argmax(satisfied, axis=1)  # first breakpoint meeting rho (>= 1 where pushed)
    lower = np.maximum(upper - 1, 0)
    g_lo, g_hi = g[rows, lower], g[rows, upper]
    slope_den = np.where(needs_push, g_hi - g_lo, 1.0)  # > 0 on the crossing segment
    lam = lams[rows, lower] + (rho - g_lo) * (lams[rows, upper] - lams[rows, lower]) / slope_den
    lam = np.where(needs_push, lam, 0.0)
    u = np.clip(u0 + lam[:, None] * beta, -u_max, u_max)
    u = np.where(infeasible[:, None], np.where(beta != 0.0, u_max * np.sign(beta), base), u)
    correction = np.linalg.norm(u - base, axis=1)
    return CBFResult(u, needs_push | (infeasible & (correction > 0.0)), infeasible, correction)
