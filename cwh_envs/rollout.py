"""Closed-loop flights of a policy from many starts at once, through the envs' own batched core.

The one place a policy is scored: :func:`fly` steps :class:`cwh_envs.core.RendezvousCore` /
:class:`~cwh_envs.core.DockingCore`, the code behind ``gym.make`` and the vector envs, with the
same action check and the same CBF filter as :class:`cwh_envs.CBFSafetyFilter`. The step, the
keep-out violation, the clearance and success are therefore computed in one place, and a start
flown here ends exactly (to the bit) where the same start flown through ``gym.make`` ends, given
the same actions (tests/test_rollout.py).

A policy maps the observations the env would show, float32 (N, 7 | 10), to actions in the env's
units: thrust as a fraction of ``u_max`` per axis, clipped to [-1, 1] as the env clips them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cwh_envs.actions import check_actions
from cwh_envs.constraints import path_constrained
from cwh_envs.core import (
    DockingCore,
    DockingReward,
    RendezvousCore,
    RendezvousReward,
    check_goals,
    check_margin,
    check_states,
    filter_actions,
)
from cwh_envs.dispersions import FILTER_SEES, check_spreads, draw_episode, episode_rng, noisy
from cwh_envs.navigation import NavigationFilter
from cwh_envs.problems import DockingProblem, RendezvousProblem

CBF_NAVIGATION = ("bounds", "covariance")  # what sizes the robust filter's navigation margins (fly)

Policy = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Flight:
    """N episodes flown to the horizon H. Per start: the env's end-of-episode info.

    ``states`` (N, H+1, 6) [m, m/s]; ``thrust`` (N, H, 3) [N], what was applied (after the filter);
    ``terminal_distance``, ``terminal_speed`` (N,); ``is_success`` (N,) bool; docking only (else
    None): ``violation_rate`` (N,) share of steps 1..H ending inside the keep-out, ``min_clearance``
    (N,) [m], and, with the filter, ``cbf_active`` / ``cbf_infeasible`` (N, H) bool and, with a speed
    limit or a cone, ``cbf_dropped`` (N, H, 3) bool (:data:`cwh_envs.cbf_multi.BARRIERS` order).
    ``speed_violation_rate`` / ``cone_violation_rate`` (N,): the share of steps 1..H breaking the
    speed limit / the cone, on a problem that has it (else None). ``keep_out_depth`` (N,) [m],
    ``speed_depth`` (N,) [m/s] and ``cone_depth`` (N,) [m]: the deepest violation of each constraint
    over steps 1..H (0 where kept; :func:`cwh_envs.constraints.violation_depths`), on a problem that
    has it (else None).
    """

    states: np.ndarray
    thrust: np.ndarray
    goals: np.ndarray
    terminal_distance: np.ndarray
    terminal_speed: np.ndarray
    is_success: np.ndarray
    violation_rate: np.ndarray | None = None
    min_clearance: np.ndarray | None = None
    cbf_active: np.ndarray | None = None
    cbf_infeasible: np.ndarray | None = None
    cbf_dropped: np.ndarray | None = None
    speed_violation_rate: np.ndarray | None = None
    cone_violation_rate: np.ndarray | None = None
    keep_out_depth: np.ndarray | None = None
    speed_depth: np.ndarray | None = None
    cone_depth: np.ndarray | None = None
    cbf_margin_scale: np.ndarray | None = None


def fly(
    problem: RendezvousProblem | DockingProblem,
    policy: Policy,
    starts,
    goals=None,
    *,
    cbf_margin: float | None = None,
    dispersions: dict | None = None,
    dispersion_seed: int = 0,
    filter_sees: str = "estimate",
    cbf_bounds=None,
    navigation=None,
    cbf_navigation: str = "bounds",
    cbf_stop_line: bool = False,
) -> Flight:
    """Fly ``policy`` from every start (N, 6) at once (docking: to ``goals`` (N, 3)) for H steps.

    ``cbf_margin`` (docking, metres) passes every action through the predictive CBF filter first,
    as ``CBFSafetyFilter(env, margin=cbf_margin)`` does.

    ``dispersions`` (standard deviations, :mod:`cwh_envs.dispersions`) flies start ``i`` under the
    draw of seed ``dispersion_seed + i``, as ``CBFSafetyFilter(Dispersions(env))`` reset with that
    seed would: the policy and the filter act on the navigation estimate (the true state plus that
    step's noise), the env scores the true state, and the plant's errors act on the filtered action
    before the box clip; ``thrust`` is then the effective thrust. ``filter_sees="truth"`` feeds the
    filter the true state instead, the flight before flight software's view was modelled (it
    flatters the filter; kept for comparison).

    ``cbf_bounds`` (:class:`cwh_envs.robust_cbf.ErrorBounds`, with ``cbf_margin``) flies the robust
    filter instead of the nominal one; ``cbf_margin_scale`` (N, H) then says how much of its margin
    each step kept.

    ``navigation`` (:class:`cwh_envs.robust_cbf.ErrorBounds`, docking) puts flight software's
    navigation filter between the measurement and everything that acts on it: a
    :class:`cwh_envs.navigation.NavigationFilter` sized by those bounds estimates ``[r, v]`` and the
    episode's thrust error from the measurements and the thrust commanded; the policy observes its
    estimate, the CBF filter acts on it (unless ``filter_sees="truth"``), and the thrust is commanded
    through the estimated thrust error, ``G_hat^-1 u`` (clipped to the box), so that the plant's
    ``G`` delivers about ``u``. A nominal flight sees no innovation and flies as without it (to
    rounding).

    ``cbf_navigation`` says what the robust filter's navigation margins are sized by: ``"bounds"``,
    the declared one-sigma errors of ``cbf_bounds`` (a raw measurement's), or ``"covariance"``, each
    row's navigation filter's own covariance at that step (:meth:`NavigationFilter.sigma`, at
    ``cbf_bounds.k_sigma``), the estimate's error where the filter has converged; it needs
    ``navigation`` and ``cbf_bounds``.

    ``cbf_stop_line`` gives the robust filter its stop line (it needs ``cbf_bounds``): the chaser
    does not cross the plane in front of the port where the corridor the margins leave is narrower
    than the margin (:mod:`cwh_envs.robust_cbf`), so that large margins stop it short instead of
    leaving the filter without an action at the eroded apex.
    """
    docking = isinstance(problem, DockingProblem)
    if not docking and not isinstance(problem, RendezvousProblem):
        raise ValueError(
            f"problem must be a RendezvousProblem or DockingProblem, got {type(problem).__name__}"
        )
    starts = np.asarray(starts, dtype=np.float64)
    n = len(starts) if starts.ndim == 2 else 0
    if n < 1:
        raise ValueError(f"starts must have shape (N, 6) with N >= 1, got {starts.shape}")
    starts = check_states(starts, n)
    if docking:
        if goals is None:
            raise ValueError("docking needs goals (N, 3)")
        goals = check_goals(goals, problem, n)
        core = DockingCore(problem, DockingReward(), n)
    else:
        if goals is not None or cbf_margin is not None:
            raise ValueError("rendezvous takes no goals and no CBF filter (it has no keep-out)")
        core = RendezvousCore(problem, RendezvousReward(), n)
    margin = None if cbf_margin is None else check_margin(cbf_margin)
    if cbf_bounds is not None and margin is None:
        raise ValueError("cbf_bounds sizes the filter's margins: it needs cbf_margin (the filter) too")
    if filter_sees not in FILTER_SEES:
        raise ValueError(f"filter_sees must be one of {FILTER_SEES}, got {filter_sees!r}")
    if navigation is not None and not docking:
        raise ValueError("navigation (a navigation filter) is for docking problems")
    if cbf_navigation not in CBF_NAVIGATION:
        raise ValueError(f"cbf_navigation must be one of {CBF_NAVIGATION}, got {cbf_navigation!r}")
    if cbf_navigation == "covariance" and (
        navigation is None or cbf_bounds is None or filter_sees == "truth"
    ):
        raise ValueError(
            'cbf_navigation="covariance" sizes the robust filter (cbf_bounds) by the navigation '
            "filter's covariance (navigation): it needs both, and the filter on the estimate "
            f'(filter_sees="estimate", got {filter_sees!r})'
        )
    if cbf_stop_line and cbf_bounds is None:
        raise ValueError("cbf_stop_line is the robust filter's (cbf_bounds): it needs cbf_bounds too")
    horizon = problem.horizon
    gains = nav = None
    if dispersions is not None:
        spreads = check_spreads(dispersions)
        draws = [draw_episode(spreads, episode_rng(dispersion_seed + i), horizon) for i in range(n)]
        gains, nav = np.stack([d.gain for d in draws]), np.stack([d.nav for d in draws])
    core.start(slice(None), starts, goals)
    states = np.empty((n, horizon + 1, 6))
    thrust = np.empty((n, horizon, 3))
    active = np.zeros((n, horizon), dtype=bool) if margin is not None else None
    infeasible = np.zeros((n, horizon), dtype=bool) if margin is not None else None
    several = docking and path_constrained(problem)  # the filter then says what it dropped
    dropped = np.zeros((n, horizon, 3), dtype=bool) if margin is not None and several else None
    kept = np.ones((n, horizon)) if cbf_bounds is not None else None
    navigator = None if navigation is None else NavigationFilter(problem, navigation)
    commanded = np.zeros((n, 3))  # N: the thrust last commanded, which the navigation filter predicts with
    states[:, 0] = core.states
    final = None
    for k in range(horizon):
        observed = core.observe() if nav is None else noisy(core.observe(), nav[:, k])
        measured = core.states if nav is None else core.states + nav[:, k]
        if navigator is not None:  # the filter's estimate replaces the measurement everywhere
            if k == 0:
                navigator.start(np.ones(n, dtype=bool), measured)
            else:
                measured = navigator.step(commanded, measured)
            observed[:, :6] = measured
        actions = check_actions(policy(observed), (n, 3))
        if margin is not None:
            seen = core.states if filter_sees == "truth" else measured
            sigma = navigator.sigma() if cbf_navigation == "covariance" else None
            actions, result = filter_actions(
                actions, seen, problem, margin, core.goals, cbf_bounds, sigma, cbf_stop_line
            )
            active[:, k], infeasible[:, k] = result.active, result.infeasible
            if dropped is not None:
                dropped[:, k] = result.dropped
            if kept is not None:
                kept[:, k] = result.margin_scale
        if navigator is not None:
            actions = np.clip(np.linalg.solve(navigator.thrust_gain(), actions[..., None])[..., 0], -1.0, 1.0)
            commanded = actions * problem.u_max
        if gains is not None:
            actions = np.clip(np.einsum("nij,nj->ni", gains, actions), -1.0, 1.0)
        thrust[:, k] = actions * problem.u_max  # exactly what the core applies
        _, _, _, final = core.step(actions)
        states[:, k + 1] = core.states
    return Flight(
        states=states,
        thrust=thrust,
        goals=core.goals.copy(),
        terminal_distance=final["terminal_distance"],
        terminal_speed=final["terminal_speed"],
        is_success=final["is_success"],
        violation_rate=final.get("violation_rate"),
        min_clearance=final.get("min_clearance"),
        speed_violation_rate=final.get("speed_violation_rate"),
        cone_violation_rate=final.get("cone_violation_rate"),
        keep_out_depth=final.get("keep_out_depth"),
        speed_depth=final.get("speed_depth"),
        cone_depth=final.get("cone_depth"),
        cbf_active=active,
        cbf_infeasible=infeasible,
        cbf_dropped=dropped,
        cbf_margin_scale=kept,
    )


def control_effort(thrust, problem) -> tuple[np.ndarray, np.ndarray]:
    """(energy, delta-v) of thrust sequences (N, H, 3) [N]: sum of |u|^2 dt [N^2 s], the quantity the
    minimum-energy experts minimise, and sum of |u| dt / m [m/s], the fuel a thruster spends."""
    thrust = np.asarray(thrust, dtype=np.float64)
    if thrust.ndim != 3 or thrust.shape[-1] != 3:
        raise ValueError(f"thrust must have shape (N, H, 3), got {thrust.shape}")
    energy = np.einsum("nki,nki->n", thrust, thrust) * problem.dt
    delta_v = np.linalg.norm(thrust, axis=2).sum(axis=1) * problem.dt / problem.mass
    return energy, delta_v
