"""Receding-horizon MPC: the task's own optimal-control expert, re-solved at every step.

At step k, with m = H - k steps to go, :class:`RecedingHorizon` solves the expert of its problem
from the observed state over the remaining m steps (the problem with ``horizon=m``), warm-started
from its previous plan shifted by one step, and applies the first control:

- rendezvous: the box-constrained minimum-energy QP (:func:`cwh_envs.experts.solve_rendezvous`; the
  warm start is the previous plan's saturation pattern);
- docking: the keep-out SCP (:func:`cwh_envs.experts.scp_docking`, linearised about the previous
  plan), with the speed limit and the approach cone as second-order cones when the problem has them.

On the nominal model the tail of an optimal plan is optimal for the rest (Bellman), so MPC flies
the open-loop expert's trajectory; what it adds is feedback when the model or the state is off.

**A re-solve that fails** (the expert raises :class:`~cwh_envs.experts.Infeasible`: no box thrust
reaches the target from the observed state, the state already breaks a constraint no thrust can
undo in time, or the SCP does not converge) is counted in ``infeasible``. What comes next is the
``on_failure`` choice:

- ``"previous_plan"`` (the controller's default): apply the next control of the previous plan,
  which was feasible for the state that plan predicted (counted in ``fallbacks``); with no plan yet,
  re-plan with the soft-terminal expert as below. Measured on rendezvous' test split: re-planning
  from float32 observations fails on 2.6k of 80k solves, on starts that ride the thrust box, and
  flying the previous plan there ends 1.4e-7 m off on average, where the soft re-plan ends 5e-3 m
  off (its exact penalty is outweighed by the large multipliers of those boundary states).
- ``"soft"`` (DAgger's relabelling, where a label must be the expert's answer *from this state*):
  re-plan with the soft-terminal expert (:func:`~cwh_envs.experts.solve_rendezvous_soft`,
  :func:`~cwh_envs.experts.soft_docking`: the terminal state and every path constraint as exact
  penalties, so it gets as close as it can), counted in ``soft``.

Should every option fail, the closed-form law (:class:`cwh_envs.controllers.MinEnergyFeedback`)
flies the step, counted in ``fallbacks``. **The last step** (m = 1) needs no solve: under Euler no
thrust moves the final position, and the law's one-step least-squares control is the only
candidate (the experts need a horizon of at least 2).

Flown over the states another policy visits, in time order, with ``on_failure="soft"``, it is
DAgger's relabelling expert: its action at each state is the expert's first control over the
remaining horizon.

**Plans are tightened** against the float32 rounding of the observed state (about 1e-6 m): the
approach cone's radius grows by RADIUS_MARGIN, so that a planned point just outside the port's ball
does not land inside it, off the cone (measured: a plan on the ball's surface did, on 2 of 3
starts). The speed limit and the cone's angle are already solved tighter (:mod:`cwh_envs.socp`).

**The robust MPC** (``RecedingHorizon.robust(problem, bounds)``; issue 58) plans against
constraints tightened by the same declared error bounds as the robust filter
(:class:`cwh_envs.robust_cbf.ErrorBounds`): the keep-out standoff grows by the k-sigma position
error of a two-step prediction plus the thrust error at full throttle, the speed limit's ``v0``
shrinks by the k-sigma speed error of a one-step prediction and its distance term's position error;
the cone keeps the planner's corridor to the port, already ``capture_radius cos(half_angle)`` (8.7
cm by default) inside the scored one. A hard re-solve that fails is answered by the soft expert,
whose exact penalties (Kerrigan and Maciejowski 2000) make every subproblem solvable while keeping
the hard answer wherever one exists: no stale plans; ``infeasible`` counts the hard failures,
``soft`` the answers that replaced them, ``fallbacks`` whatever neither answered.

It is a policy on observations like the others: ``mpc = RecedingHorizon(problem)``, then
``mpc(obs)`` for (N, obs_dim) or (obs_dim,); a row whose observed time-to-go is 1 starts a new
episode (its plan is dropped). The observation is float32, so the state it re-plans from is rounded
to about 1e-7 relative. ``solve_seconds`` keeps each row's solve time (model set-up excluded: the
condensed model of each remaining horizon is built once per step for the whole batch).
"""

from __future__ import annotations

import time

import numpy as np

from cwh_envs import experts
from cwh_envs.controllers import MinEnergyFeedback
from cwh_envs.observations import DOCKING_OBS_DIM
from cwh_envs.problems import DockingProblem, RendezvousProblem
from cwh_envs.robust_cbf import ErrorBounds

RADIUS_MARGIN = 1e-3  # m, added to the approach cone's radius in every plan
ON_FAILURE = ("previous_plan", "soft")  # what a failed re-solve does (module docstring)


class RecedingHorizon:
    """Receding-horizon MPC on a :class:`RendezvousProblem` or :class:`DockingProblem` (module docstring).

    Counters, per row of the batch it was last called with (reset when a row starts an episode):
    ``solves``, ``infeasible`` (failed hard re-solves), ``soft`` (of those, answered by the
    soft-terminal expert) and ``fallbacks`` (steps flown on the previous plan or the law);
    ``solve_seconds`` lists every solve's wall time (a soft re-plan's included).
    """

    def __init__(
        self,
        problem: RendezvousProblem | DockingProblem,
        on_failure: str = "previous_plan",
        bounds: ErrorBounds | None = None,
    ) -> None:
        if on_failure not in ON_FAILURE:
            raise ValueError(f"on_failure must be one of {ON_FAILURE}, got {on_failure!r}")
        if not isinstance(problem, RendezvousProblem | DockingProblem):
            raise ValueError(
                f"problem must be a RendezvousProblem or DockingProblem, got {type(problem).__name__}"
            )
        if bounds is not None and not (
            isinstance(bounds, ErrorBounds) and isinstance(problem, DockingProblem)
        ):
            raise ValueError(f"bounds must be an ErrorBounds, on a DockingProblem; got {bounds!r}")
        self.problem, self.on_failure = problem, on_failure
        self.planned = problem if bounds is None else tightened(problem, bounds)
        if isinstance(problem, DockingProblem):
            self.planned = corridor(self.planned)
        self.law = MinEnergyFeedback(problem)
        self.solve_seconds: list[float] = []
        self._resize(0)

    @classmethod
    def robust(cls, problem: DockingProblem, bounds: ErrorBounds) -> RecedingHorizon:
        """The robust MPC (module docstring): tightened plans, every failed re-solve answered softly."""
        return cls(problem, on_failure="soft", bounds=bounds)

    def _resize(self, rows: int) -> None:
        self.plans: list[np.ndarray | None] = [None] * rows
        self.solves = np.zeros(rows, dtype=np.int64)
        self.infeasible = np.zeros(rows, dtype=np.int64)
        self.soft = np.zeros(rows, dtype=np.int64)
        self.fallbacks = np.zeros(rows, dtype=np.int64)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs)
        single = obs.ndim == 1
        batch, docking = self._batch(obs)
        if len(batch) != len(self.plans):
            self._resize(len(batch))
        horizon = self.problem.horizon
        steps_to_go = np.rint(batch[:, -1] * horizon).astype(np.int64)
        thrust = self.law.thrust(batch)  # m = 1, and the fallback
        for row in np.flatnonzero(steps_to_go == horizon):  # a new episode
            self.plans[row] = None
            self.solves[row] = self.infeasible[row] = self.soft[row] = self.fallbacks[row] = 0
        for row in np.flatnonzero(steps_to_go >= 2):
            plan = self.plans[row]
            warm = plan[1:] if plan is not None and len(plan) == steps_to_go[row] + 1 else None
            thrust[row] = self._replan(row, batch[row], int(steps_to_go[row]), docking, warm, self.on_failure)
        for row in np.flatnonzero(steps_to_go < 2):
            self.plans[row] = None
        actions = np.clip(thrust / self.problem.u_max, -1.0, 1.0)
        return actions[0] if single else actions

    def answer(self, obs: np.ndarray, warm: list[np.ndarray | None]) -> np.ndarray:
        """Actions (N, 3) for N unrelated states: each row's first control of the expert re-solved
        from it over its steps to go, as ``__call__`` would, but warm-started from ``warm[row]`` (a
        control sequence over those steps, e.g. what another policy flew from there, or None) instead
        of a previous plan of the row. A failed hard re-solve is answered by the soft expert whatever
        ``on_failure`` says: the warm start is no plan of this expert. DAgger's relabelling of a random
        subsample of visited states, where no row has a previous plan; the counters restart here."""
        batch, docking = self._batch(obs)
        if len(warm) != len(batch):
            raise ValueError(f"warm has {len(warm)} rows for {len(batch)} observations")
        self._resize(len(batch))
        steps_to_go = np.rint(batch[:, -1] * self.problem.horizon).astype(np.int64)
        thrust = self.law.thrust(batch)
        for row in np.flatnonzero(steps_to_go >= 2):
            start = warm[row]
            if start is not None and len(start) != steps_to_go[row]:
                raise ValueError(f"warm[{row}] has {len(start)} controls for {steps_to_go[row]} steps to go")
            thrust[row] = self._replan(row, batch[row], int(steps_to_go[row]), docking, start, "soft")
        self.plans = [None] * len(batch)  # no row goes on as an episode of __call__
        return np.clip(thrust / self.problem.u_max, -1.0, 1.0)

    def _batch(self, obs: np.ndarray) -> tuple[np.ndarray, bool]:
        batch = np.atleast_2d(np.asarray(obs)).astype(np.float64)
        docking = isinstance(self.problem, DockingProblem)
        if batch.shape[-1] != (DOCKING_OBS_DIM if docking else DOCKING_OBS_DIM - 3):
            raise ValueError(f"observations of width {batch.shape[-1]} do not fit this problem")
        return batch, docking

    def _replan(
        self, row: int, obs: np.ndarray, steps_to_go: int, docking: bool, warm, on_failure: str
    ) -> np.ndarray:
        problem = self.planned.replace(horizon=steps_to_go)
        experts.linear_model(problem)  # built once per remaining horizon, outside the timed solve
        self.solves[row] += 1
        started = time.perf_counter()
        try:
            controls = _solve(obs, problem, warm, docking, soft=False)
        except experts.Infeasible:
            self.infeasible[row] += 1
            if on_failure == "previous_plan" and warm is not None:
                controls = warm
                self.fallbacks[row] += 1
            else:
                controls = self._soft(row, obs, problem, warm, docking)
        finally:
            self.solve_seconds.append(time.perf_counter() - started)
        self.plans[row] = controls
        if controls is None:
            self.fallbacks[row] += 1
            return self.law.thrust(obs)
        return controls[0]

    def _soft(self, row: int, obs: np.ndarray, problem, warm, docking: bool) -> np.ndarray | None:
        """The soft-terminal expert's controls from the observed state (counted), or None."""
        try:
            controls = _solve(obs, problem, warm, docking, soft=True)
        except experts.Infeasible:
            return None
        self.soft[row] += 1
        return controls


def corridor(problem: DockingProblem) -> DockingProblem:
    """The problem as every plan is solved: the approach cone's radius grown by RADIUS_MARGIN (module
    docstring); unchanged without a cone."""
    if problem.approach_cone is None:
        return problem
    half_angle, radius = problem.approach_cone
    return problem.replace(approach_cone=(half_angle, radius + RADIUS_MARGIN))


def tightened(problem: DockingProblem, bounds: ErrorBounds) -> DockingProblem:
    """The problem the robust MPC plans (module docstring): a wider keep-out standoff, a lower v0."""
    a, b = problem.matrices()
    lever = np.linalg.norm((a @ b + b)[:3], 2)
    standoff = bounds.position_margin(a) + bounds.actuation() * lever * problem.u_max * np.sqrt(3.0)
    out = problem.replace(margin=problem.margin + standoff)
    if problem.speed_limit is not None:
        v0, v1 = problem.speed_limit
        shrink = bounds.speed_margin(a, v1)
        if shrink >= v0:
            raise ValueError(
                f"the speed margin {shrink:.3g} m/s of these bounds leaves no speed at the port (v0 = {v0:g} m/s)"
            )
        out = out.replace(speed_limit=(v0 - shrink, v1))
    return out


def _solve(obs: np.ndarray, problem, warm, docking: bool, soft: bool) -> np.ndarray:
    """The (hard or soft-terminal) expert's controls (m, 3) from the observed state."""
    if docking:
        if soft:
            return experts.soft_docking(obs[:6], obs[6:9], problem, warm_start=warm).controls
        return experts.solve_docking(obs[:6], obs[6:9], problem, warm_start=warm)[1]
    if soft:
        return experts.solve_rendezvous_soft(obs[:6], problem)[1]
    return experts.solve_rendezvous(obs[:6], problem, warm_start=warm)[1]
