"""CBFSafetyFilter: the paper's run-time predictive CBF filter as a Gymnasium action wrapper."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from cwh_envs.actions import check_actions
from cwh_envs.cbf_multi import BARRIERS
from cwh_envs.core import check_margin, filter_actions
from cwh_envs.dispersions import FILTER_SEES
from cwh_envs.docking import CWHDockKOZEnv
from cwh_envs.robust_cbf import ErrorBounds


class CBFSafetyFilter(gym.ActionWrapper, gym.utils.RecordConstructorArgs):
    """Minimally edit each action so the two-step-ahead position stays outside ``R + margin``.

    For ``CWHDockKOZ-v1`` (directly or under ``gym.make``'s wrappers). Each step the wrapper reads
    the unwrapped env's state, converts the clipped normalised action to newtons, applies
    :func:`cwh_envs.cbf.safe_actions` (the exact minimiser of ``||u - u_nominal||^2`` subject to
    the barrier ``beta^T u >= rho`` and the thrust box) and passes the result, normalised again,
    to the env. The reward's effort term therefore charges the thrust actually applied.

    What it guarantees, and what not: under the (default) Euler model ``u_t`` fixes ``r_{t+2}``
    exactly, so whenever the barrier is feasible at step ``t`` the state ``x_{t+2}`` lies outside
    ``R + margin``. With at most ``u_max`` per axis an approach that is already too fast cannot be
    stopped in two steps: the barrier is then infeasible (``cbf_infeasible``), the filter applies
    the thrust that best satisfies it, and the chaser may enter the sphere two steps later. Head-on
    approaches up to about 0.1 m/s are kept out, 0.2 m/s ones are not (docs/envs.md has the
    measured table). Under ``discretization="exact"`` the two-step prediction is approximate and
    the margin absorbs the error (measured: at least 0.27 m of the 0.5 m kept while feasible).

    Extra info on every step:

    | Key                    | Meaning                                                        |
    |------------------------|----------------------------------------------------------------|
    | ``cbf_active``         | the barrier changed the (box-clipped) action                   |
    | ``cbf_infeasible``     | no thrust in the box satisfies the barrier this step           |
    | ``cbf_correction_norm``| ``||u - clip(u_nominal)||`` in newtons, the barrier's edit     |
    | ``cbf_dropped``        | with a speed limit or a cone only: the barriers given up       |

    With a speed limit or an approach cone every barrier goes into one QP
    (:func:`cwh_envs.cbf_multi.safe_actions_multi`); ``cbf_infeasible`` then means that no box
    action met them all, and ``cbf_dropped`` names what was given up (the cone first).

    Under dispersions (:class:`cwh_envs.dispersions.Dispersions` below it, or the env's
    ``dispersions=`` option) the filter acts on the navigation estimate, ``navigation_state``, as flight
    software's run-time assurance does; ``sees="truth"`` feeds it the true state instead (a comparison
    that flatters the filter). Without dispersions the two are the same state.

    Args:
        env: a ``CWHDockKOZ`` env (``-v1`` or ``-v0``), possibly wrapped.
        margin: standoff ``delta`` in metres added to the keep-out radius; ``None`` (default) uses
            the env's ``problem.margin`` (0.5 m, the paper's value). Negative raises ``ValueError``.
        sees: ``"estimate"`` (default) or ``"truth"``: the state the filter acts on.
        bounds: a :class:`cwh_envs.robust_cbf.ErrorBounds` for the robust filter (margins sized from
            declared error bounds; ``info["cbf_margin_scale"]`` says how much of them each step
            kept), or ``None`` (default) for the nominal one.
    """

    def __init__(
        self,
        env: gym.Env,
        margin: float | None = None,
        sees: str = "estimate",
        bounds: ErrorBounds | None = None,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, margin=margin, sees=sees, bounds=bounds)
        if bounds is not None and not isinstance(bounds, ErrorBounds):
            raise ValueError(f"bounds must be an ErrorBounds or None, got {bounds!r}")
        self.bounds = bounds
        gym.ActionWrapper.__init__(self, env)
        if not isinstance(env.unwrapped, CWHDockKOZEnv):
            raise TypeError(
                f"CBFSafetyFilter needs a CWHDockKOZ env (the keep-out problem), got {env.unwrapped!r}"
            )
        if sees not in FILTER_SEES:
            raise ValueError(f"sees must be one of {FILTER_SEES}, got {sees!r}")
        self.margin = env.unwrapped.problem.margin if margin is None else check_margin(margin)
        self.sees = sees
        self._last = None

    def action(self, action: Any) -> np.ndarray:
        base = self.env.unwrapped
        state = base.state if self.sees == "truth" else self.env.get_wrapper_attr("navigation_state")
        safe, self._last = filter_actions(
            check_actions(action, (3,)), state, base.problem, self.margin, base.goal, self.bounds
        )
        return safe  # float64 on purpose: a float32 round-trip would shift the barrier's edit

    def step(self, action: Any):
        obs, reward, terminated, truncated, info = self.env.step(self.action(action))
        info["cbf_active"] = bool(self._last.active)
        info["cbf_infeasible"] = bool(self._last.infeasible)
        info["cbf_correction_norm"] = float(self._last.correction_norm)
        if hasattr(self._last, "margin_scale"):  # the robust filter
            info["cbf_margin_scale"] = float(self._last.margin_scale)
        if hasattr(self._last, "dropped"):  # a speed limit or an approach cone: several barriers
            info["cbf_dropped"] = tuple(
                name for name, out in zip(BARRIERS, self._last.dropped, strict=True) if out
            )
        return obs, reward, terminated, truncated, info
