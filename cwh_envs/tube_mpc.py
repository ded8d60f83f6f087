"""The robust MPC of issue 58: a tube MPC (Mayne, Seron and Raković 2005) on the navigation estimate.

At an episode's first step :class:`TubeMPC` plans once, from the navigation estimate, the docking
expert's trajectory (nominal states ``z``, controls ``v``) on constraints tightened by the tube below;
every step then flies the plan's control plus an ancillary feedback on the estimate's deviation
from the plan,

    u_k = v_k + K (x_hat_k - z_k),

clipped to the thrust box. ``K`` is the discrete LQR gain of the CWH model whose weights give a
critically damped response with time constant ``time_constant`` (Q = m^2 diag(w^4 I, 2 w^2 I), R = I,
w = 1 / time_constant).

**Why it plans once.** On a shrinking horizon the nominal plan re-solved from its own state ``z_k``
returns its own tail (Bellman), so the nominal's re-solve adds nothing; what keeps the chaser on it
is ``K``. Re-solving from the estimate instead (:meth:`cwh_envs.mpc.RecedingHorizon.robust`) is what
failed: near the port the noisy estimate lies outside the planner's cone, and the re-solves have no
hard answer (measured in ``results/robust-safety``). Here no step flies a stale plan: every step is
the plan's control corrected by the feedback, and the plan is only ever the one of this episode.

**The tube.** With ``e = x - z`` the true deviation, ``e_{k+1} = (A + B K) e_k + B K n_k + B (G - I) u_k``:
the navigation noise ``n`` enters through the gain, the thrust error ``(G - I) u`` (scale, mass,
misalignment; bounded by ``e_u ||u||``, :meth:`ErrorBounds.actuation`) as a disturbance. The tube is,
per axis of position and velocity,

    k * (stationary standard deviation of e under the navigation noise, exact: a Lyapunov sum)
      + e_u * reference_thrust * (the l1 gain of the loop from a constant thrust error to e).

The second term is a bound for any thrust error up to ``e_u`` of ``reference_thrust``; the thrust
error is proportional to the thrust, which is small in the final approach where the speed limit
and the cone bind. ``reference_thrust`` (0.05 N by default) is a choice, not a bound on the whole
flight: set by looking at the 64 first constrained-docking search starts (their plans' thrust in
the final approach). The plan's constraints are tightened by the tube:

- the keep-out standoff grows by the position tube (Euclidean, over the three axes);
- the speed limit's ``v0`` shrinks by the velocity tube along one axis (the speed's error along its
  own direction) plus ``v1`` times the position tube;
- the approach cone's zone radius grows by the position tube (the chaser enters the zone inside the
  cone with that much to spare); its angle is not tightened: the planner's corridor to the port is
  already ``capture_radius cos(half_angle)`` (8.7 cm by default) inside the scored one.

**Where the expert has no answer.** The tightened expert is an SCP and may not converge from a
given estimate (on about 5 % of constrained search starts, from the estimate's velocity noise).
The plan then falls back, each step counted in :attr:`counts`: the tightened problem warm-started
from the untightened corridor's plan (``warm``); the same from the estimate with its velocity put
back into the problem's declared start box (``boxed``: the tube's initial deviation then includes
that velocity, within the navigation bound); the soft expert of the tightened problem, exact
penalties (``soft``); the untightened corridor's plan itself, found on the way (``corridor``: the
tube's margins given up for that episode, the corridor's own kept); the closed-form routed law for the
episode (``law``).

**On a navigation filter** (``navigation=True``): the feedback and the law act on the estimate of
:class:`cwh_envs.navigation.NavigationFilter` instead of the raw navigation estimate, and the thrust
is commanded through the filter's estimated thrust error, ``G_hat^-1 u``. The plan starts from the
first measurement, as without it; the tube stays the one above, sized for the raw estimate (the
filter's error is not white, and no bound is claimed for it): the filter's gain is measured, not
proven. On the 64 first constrained search starts under 3-sigma dispersions (the design probe) the
raw estimate's 67 % success rose to 88 % with the filter and to 92 % commanding through ``G_hat``.

It is a policy on observations like :class:`cwh_envs.mpc.RecedingHorizon`: ``mpc(obs)`` for
(N, obs_dim) or (obs_dim,); a row whose observed time-to-go is the horizon starts a new episode.
``plan_seconds`` lists each plan's wall time; a step without a plan is a matrix product.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from cwh_envs import experts
from cwh_envs.controllers import MinEnergyFeedback, WaypointFeedback
from cwh_envs.mpc import RADIUS_MARGIN, corridor
from cwh_envs.navigation import NavigationFilter
from cwh_envs.observations import DOCKING_OBS_DIM
from cwh_envs.problems import DockingProblem
from cwh_envs.robust_cbf import ErrorBounds

TIME_CONSTANT = 60.0  # s: the ancillary loop's; measured on the search split (module docstring)
REFERENCE_THRUST = 0.05  # N: the thrust level at which the thrust error is sized
# how each episode's plan was found, in the order tried
PLANS = ("cold", "warm", "boxed", "soft", "corridor", "law")
_TUBE_STEPS = 2000  # terms of the tube's sums: the loop's response is below 1e-100 of its start by then


@dataclass(frozen=True)
class Tube:
    """The tube's half-widths per axis: ``position`` m, ``velocity`` m/s (module docstring)."""

    position: float
    velocity: float

    @classmethod
    def of(
        cls, problem: DockingProblem, bounds: ErrorBounds, gain: np.ndarray, reference_thrust: float
    ) -> Tube:
        a, b = problem.matrices()
        closed = a + b @ gain
        noise = b @ gain @ np.diag([bounds.nav_position] * 3 + [bounds.nav_velocity] * 3)
        covariance = scipy.linalg.solve_discrete_lyapunov(closed, noise @ noise.T)
        spread = bounds.k_sigma * np.sqrt(np.diag(covariance))
        response, power = np.zeros(6), np.eye(6)
        for _ in range(_TUBE_STEPS):
            response += np.abs(power @ b).sum(axis=1)
            power = closed @ power
        bias = bounds.actuation() * reference_thrust * response
        per_axis = spread + bias
        return cls(position=float(per_axis[:3].max()), velocity=float(per_axis[3:].max()))


def ancillary_gain(problem: DockingProblem, time_constant: float) -> np.ndarray:
    """The LQR gain K (3, 6), u = K e, of the module docstring."""
    if not (isinstance(time_constant, int | float) and np.isfinite(time_constant) and time_constant > 0):
        raise ValueError(f"time_constant must be a positive number of seconds, got {time_constant!r}")
    a, b = problem.matrices()
    w = 1.0 / time_constant
    q = problem.mass**2 * np.diag([w**4] * 3 + [2.0 * w**2] * 3)
    r = np.eye(3)
    p = scipy.linalg.solve_discrete_are(a, b, q, r)
    return -np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)


def tube_tightened(problem: DockingProblem, tube: Tube) -> DockingProblem:
    """The problem the tube MPC plans (module docstring)."""
    out = problem.replace(margin=problem.margin + np.sqrt(3.0) * tube.position)
    if problem.speed_limit is not None:
        v0, v1 = problem.speed_limit
        shrink = tube.velocity + v1 * np.sqrt(3.0) * tube.position
        if shrink >= v0:
            raise ValueError(
                f"the tube's speed margin {shrink:.3g} m/s leaves no speed at the port (v0 = {v0:g} m/s)"
            )
        out = out.replace(speed_limit=(v0 - shrink, v1))
    if problem.approach_cone is not None:
        half_angle, radius = problem.approach_cone
        out = out.replace(approach_cone=(half_angle, radius + RADIUS_MARGIN + np.sqrt(3.0) * tube.position))
    return out


class TubeMPC:
    """The tube MPC of the module docstring, on a :class:`DockingProblem`.

    ``counts`` says, over the episodes it has planned, how many plans each way of :data:`PLANS`
    found; ``plan_seconds`` each plan's wall time.
    """

    def __init__(
        self,
        problem: DockingProblem,
        bounds: ErrorBounds,
        time_constant: float = TIME_CONSTANT,
        reference_thrust: float = REFERENCE_THRUST,
        navigation: bool = False,
    ) -> None:
        if not isinstance(problem, DockingProblem):
            raise ValueError(f"problem must be a DockingProblem, got {type(problem).__name__}")
        if not isinstance(bounds, ErrorBounds):
            raise ValueError(f"bounds must be an ErrorBounds, got {bounds!r}")
        if not (isinstance(reference_thrust, int | float) and 0 <= reference_thrust <= problem.u_max):
            raise ValueError(
                f"reference_thrust must be in [0, u_max = {problem.u_max}] N, got {reference_thrust!r}"
            )
        self.problem, self.bounds = problem, bounds
        self.gain = ancillary_gain(problem, time_constant)
        self.navigation = NavigationFilter(problem, bounds) if navigation else None
        self.tube = Tube.of(problem, bounds, self.gain, float(reference_thrust))
        self.planned = tube_tightened(problem, self.tube)
        self.corridor = corridor(problem)  # the untightened plan, a warm start for the tightened one
        self.law = (WaypointFeedback if problem.approach_cone is not None else MinEnergyFeedback)(problem)
        self.counts = dict.fromkeys(PLANS, 0)
        self.plan_seconds: list[float] = []
        self.plans: list[tuple[np.ndarray, np.ndarray] | None] = []  # per row; None: the law flies it

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs)
        single = obs.ndim == 1
        batch = np.atleast_2d(obs).astype(np.float64)
        if batch.shape[-1] != DOCKING_OBS_DIM:
            raise ValueError(f"observations of width {batch.shape[-1]} are not docking observations")
        if len(batch) != len(self.plans):
            self.plans = [None] * len(batch)
            self._fresh = np.ones(len(batch), dtype=bool)
            self._commanded = np.zeros((len(batch), 3))
        horizon = self.problem.horizon
        steps_to_go = np.rint(batch[:, -1] * horizon).astype(np.int64)
        new = (steps_to_go == horizon) | self._fresh  # a new episode (or a row met mid-way)
        if self.navigation is not None:  # the filter's estimate replaces the measured [r, v]
            if not new.all():  # a batch of another size is all new (above)
                estimate = self.navigation.step(self._commanded, batch)
                batch[:, :6] = np.where(new[:, None], batch[:, :6], estimate)
            self.navigation.start(new, batch)  # a new episode starts at its measurement
        thrust = np.zeros((len(batch), 3))
        for row in range(len(batch)):
            if new[row]:
                self.plans[row], self._fresh[row] = self._plan(batch[row]), False
            if self.plans[row] is None:  # the law flies this episode
                thrust[row] = self.law.thrust(batch[row : row + 1])[0]
                continue
            states, controls = self.plans[row]
            k = min(horizon - steps_to_go[row], len(controls) - 1)
            thrust[row] = controls[k] + self.gain @ (batch[row, :6] - states[k])
        if self.navigation is not None:  # command what makes the estimated thruster deliver ``thrust``
            thrust = np.linalg.solve(self.navigation.thrust_gain(), thrust[..., None])[..., 0]
        actions = np.clip(thrust / self.problem.u_max, -1.0, 1.0)
        self._commanded = actions * self.problem.u_max  # what the filter predicts with next step
        return actions[0] if single else actions

    def _plan(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        started = time.perf_counter()
        try:
            way, plan = self._search(obs[:6], obs[6:9])
        finally:
            self.plan_seconds.append(time.perf_counter() - started)
        self.counts[way] += 1
        return plan

    def _search(self, x0: np.ndarray, goal: np.ndarray):
        """(how, (states, controls)) by the first way of :data:`PLANS` that answers."""
        try:
            return "cold", experts.solve_docking(x0, goal, self.planned)
        except experts.Infeasible:
            pass
        box = np.asarray(self.problem.velocity_box, dtype=np.float64)
        boxed = np.concatenate([x0[:3], np.clip(x0[3:], -box, box)])
        untightened = None  # the first corridor plan found: a warm start, and the last plan before the law
        for way, start in (("warm", x0), ("boxed", boxed)):
            try:
                plan = experts.solve_docking(start, goal, self.corridor)
                untightened = untightened or plan
                return way, experts.solve_docking(start, goal, self.planned, warm_start=plan[1])
            except experts.Infeasible:
                continue
        warm = None if untightened is None else untightened[1]
        try:
            return "soft", experts.soft_docking(x0, goal, self.planned, warm_start=warm)[:2]
        except experts.Infeasible:
            pass
        return ("law", None) if untightened is None else ("corridor", untightened)
