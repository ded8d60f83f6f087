"""Reference controllers: hand-written laws on the envs' observations, nothing learned.

The PD law, a naive speed-capped approach, the closed-form shrinking-horizon minimum-energy law
(:class:`MinEnergyFeedback`) and the same law routed through waypoints (:class:`WaypointFeedback`);
the receding-horizon MPC is :mod:`cwh_envs.mpc`. Shared by the
examples, the benchmarks and the tests. All read the layout of
:mod:`cwh_envs.observations` (r = obs[..., 0:3], v = obs[..., 3:6], docking's goal g = obs[..., 6:9])
and return normalised actions in [-1, 1]^3 (thrust / u_max), batched over leading dimensions.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from cwh_envs.dynamics import cwh_matrices
from cwh_envs.observations import DOCKING_OBS_DIM


def pd_action(obs: np.ndarray, problem, omega: float = 0.01) -> np.ndarray:
    """Critically damped PD toward the target, a = -omega^2 e - 2 omega v, saturated to the box.

    The target is docking's observed goal, the origin for rendezvous. omega = 0.01 rad/s: a ~100 s
    time constant, well inside both horizons (800 s, 2400 s). It ignores the keep-out (it flies
    straight at the docking point), which is what the CBF filter is for.
    """
    obs = np.asarray(obs, dtype=np.float64)
    target = obs[..., 6:9] if obs.shape[-1] == DOCKING_OBS_DIM else 0.0
    error, velocity = obs[..., :3] - target, obs[..., 3:6]
    accel_max = problem.u_max / problem.mass
    return np.clip((-(omega**2) * error - 2 * omega * velocity) / accel_max, -1.0, 1.0)


def capped_speed_action(obs: np.ndarray, speed: float, problem) -> np.ndarray:
    """Docking: fly straight at the goal (through the keep-out) at up to ``speed`` m/s, slowing to
    0.02 s^-1 times the distance near it; a naive nominal policy for the CBF to correct."""
    r, v, g = obs[..., :3], obs[..., 3:6], obs[..., 6:9]
    error = g - r
    distance = np.linalg.norm(error, axis=-1, keepdims=True)
    desired = error / np.maximum(distance, 1e-9) * np.minimum(speed, 0.02 * distance)
    dv_max = problem.u_max / problem.mass * problem.dt  # velocity change of one full-thrust step
    return np.clip((desired - v) / dv_max, -1.0, 1.0).astype(np.float32)


# ------------------------------------------------------------------ shrinking-horizon min-energy law


@dataclass(frozen=True, eq=False)  # hashed by identity: instances are cached per problem
class MinEnergyGains:
    """The gain table of the shrinking-horizon minimum-energy law, indexed by the steps to go m.

    With m = H - k steps left, the unconstrained minimum-energy controls from x_k to the target state
    x* are ``U = G_m^+ (x* - A^m x_k)``, ``G_m = [A^{m-1} B, ..., A B, B]`` (the experts' condensed
    model over m steps). The law applies their first control, ``u_k = K_m x* - L_m x_k`` with
    ``K_m`` the first three rows of ``G_m^+`` and ``L_m = K_m A^m``: two 3 x 6 gains per step.
    ``target_gain`` and ``state_gain`` are (H + 1, 3, 6), row m for m = 1..H (row 0 is zero).

    At m = 1 under Euler no thrust moves the final position, and ``G_1^+`` gives the least-squares
    control (the velocity part of the gap); from m = 2 on G_m has full row rank and the control
    sequence reaches x* exactly.
    """

    horizon: int
    target_gain: np.ndarray
    state_gain: np.ndarray


def min_energy_gains(problem) -> MinEnergyGains:
    """The cached gain table of ``problem``'s dynamics and horizon (pseudo-inverses by SVD, as the
    experts' ``terminal_pinv``)."""
    return _min_energy_gains(problem.n, problem.dt, problem.mass, problem.discretization, problem.horizon)


def _powers_and_impulses(n: float, dt: float, mass: float, discretization: str, horizon: int):
    """``[A^0, ..., A^H]`` and ``[A^0 B, ..., A^{H-1} B]``: both laws' condensed model (the experts'
    LinearModel holds the same; importing it would load the solvers into every controller)."""
    a, b = cwh_matrices(n, dt, mass, discretization)
    powers = [np.eye(6)]
    for _ in range(horizon):
        powers.append(a @ powers[-1])
    return powers, [power @ b for power in powers[:-1]]


@lru_cache(maxsize=8)
def _min_energy_gains(n: float, dt: float, mass: float, discretization: str, horizon: int) -> MinEnergyGains:
    powers, impulse = _powers_and_impulses(n, dt, mass, discretization, horizon)
    target_gain = np.zeros((horizon + 1, 3, 6))
    state_gain = np.zeros((horizon + 1, 3, 6))
    for m in range(1, horizon + 1):
        first_rows = np.linalg.pinv(np.concatenate(impulse[m - 1 :: -1], axis=1))[:3]
        target_gain[m], state_gain[m] = first_rows, first_rows @ powers[m]
    for array in (target_gain, state_gain):
        array.setflags(write=False)
    return MinEnergyGains(horizon, target_gain, state_gain)


class MinEnergyFeedback:
    """The shrinking-horizon minimum-energy feedback law: the optimal-control expert's unconstrained
    solution re-planned from the observed state at every step, in closed form (:class:`MinEnergyGains`).

    ``law = MinEnergyFeedback(problem)``; ``law(obs)`` maps observations (7,) / (N, 7) for
    rendezvous or (10,) / (N, 10) for docking to normalised actions, saturated to [-1, 1]. The steps
    to go come from the observed ``tau`` (m = round(tau H)), the target from docking's observed goal
    (the origin for rendezvous). It ignores the thrust box until it clips, and every path
    constraint: on docking it flies through the keep-out unless a CBF filter is in the loop.
    Where it is not clipped it equals the expert's first control from the same state over the
    remaining horizon, and on the nominal model it then flies the expert's open-loop trajectory.
    """

    def __init__(self, problem) -> None:
        self.problem = problem
        self.gains = min_energy_gains(problem)

    def thrust(self, obs: np.ndarray) -> np.ndarray:
        """The law's thrust [N] before the box, (3,) or (N, 3)."""
        obs = np.asarray(obs, dtype=np.float64)
        horizon = self.gains.horizon
        steps_to_go = np.rint(obs[..., -1] * horizon).astype(np.int64)
        if np.any((steps_to_go < 1) | (steps_to_go > horizon)):
            raise ValueError(f"observed time-to-go must lie in [1/H, 1] with H = {horizon}")
        target = np.zeros((*obs.shape[:-1], 6))
        if obs.shape[-1] == DOCKING_OBS_DIM:
            target[..., :3] = obs[..., 6:9]
        return np.einsum("...ij,...j->...i", self.gains.target_gain[steps_to_go], target) - np.einsum(
            "...ij,...j->...i", self.gains.state_gain[steps_to_go], obs[..., :6]
        )

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.clip(self.thrust(obs) / self.problem.u_max, -1.0, 1.0)


# ------------------------------------------------------------------ the same law through waypoints


@dataclass(frozen=True)
class Waypoint:
    """Where the chaser is to pass at step ``step``: ``distance`` m from the docking point g, at
    ``angle_deg`` from the docking axis a = g / ||g||, on the chaser's side of the axis (the plane
    of a and the chaser's current offset from it)."""

    step: int
    distance: float
    angle_deg: float


# A route for the constrained docking problem (H = 240, port 8 m out, 5 m keep-out, 30-degree cone
# within 15 m): around the keep-out at 17-26 m from the port, onto the axis outside the cone's 15 m,
# then down the axis. Drawn by hand from the expert's median path on the constrained search split
# (it enters the 15 m zone at steps 133-168, median 149); results/docking-constrained/waypoint_law.py.
CONE_ROUTE = (
    Waypoint(80, 26.0, 110.0),
    Waypoint(110, 20.0, 75.0),
    Waypoint(135, 17.0, 38.0),
    Waypoint(150, 15.2, 12.0),
    Waypoint(165, 12.0, 0.0),
    Waypoint(180, 10.0, 0.0),
    Waypoint(200, 5.2, 0.0),
    Waypoint(220, 1.7, 0.0),
)


@dataclass(frozen=True, eq=False)  # hashed by identity: instances are cached per problem and route
class WaypointGains:
    """The gain table of :class:`WaypointFeedback`, indexed by the steps to go m (row 0 is zero).

    With m steps left (step k = H - m), the law's first control is ``target_gain[m] @ t -
    state_gain[m] @ x_k``, ``t`` stacking every waypoint's position and the target state (g, 0),
    (3 W + 6,); the columns of the waypoints already passed (step <= k) are zero.
    """

    horizon: int
    target_gain: np.ndarray  # (H + 1, 3, 3 W + 6)
    state_gain: np.ndarray  # (H + 1, 3, 6)


class WaypointFeedback:
    """The minimum-energy law re-planned at every step through position waypoints: of all thrust
    sequences from the observed state that pass each remaining waypoint at its step (velocity free)
    and reach (g, 0) at H, the least-energy one, whose first control is applied (saturated to the box).

    A guidance engineer's answer to a path constraint the unconstrained law cannot see: the route
    goes in the waypoints, the law stays linear (per step, one gain on the state and one on the
    stacked targets: :class:`WaypointGains`), and a CBF filter in the loop keeps what the route
    misses (e.g. the speed limit). With no waypoints it is :class:`MinEnergyFeedback`. Docking
    observations only.
    """

    def __init__(self, problem, waypoints=CONE_ROUTE) -> None:
        self.problem = problem
        self.waypoints = _check_waypoints(waypoints, problem.horizon)
        self.gains = _waypoint_gains(
            problem.n,
            problem.dt,
            problem.mass,
            problem.discretization,
            problem.horizon,
            tuple(w.step for w in self.waypoints),
        )

    def waypoint_positions(self, obs: np.ndarray) -> np.ndarray:
        """Every waypoint's position (..., W, 3) [m] for the observed chaser and port: ``distance``
        from g along ``cos(angle) a + sin(angle) s``, s the unit offset of the chaser from the axis
        (on the axis, where s is undefined, the fixed perpendicular ``a x e_i``, e_i the unit vector
        of a's smallest component)."""
        obs = _docking_obs(obs)
        r, g = obs[..., :3], obs[..., 6:9]
        axis = g / np.linalg.norm(g, axis=-1, keepdims=True)
        offset = r - g
        side = offset - np.sum(offset * axis, axis=-1, keepdims=True) * axis
        norm = np.linalg.norm(side, axis=-1, keepdims=True)
        fallback = np.cross(axis, np.eye(3)[np.argmin(np.abs(axis), axis=-1)])
        fallback /= np.linalg.norm(fallback, axis=-1, keepdims=True)
        side = np.where(norm > AXIS_TOLERANCE, side / np.maximum(norm, AXIS_TOLERANCE), fallback)
        angle = np.radians([w.angle_deg for w in self.waypoints])
        distance = np.array([w.distance for w in self.waypoints])
        direction = np.cos(angle)[:, None] * axis[..., None, :] + np.sin(angle)[:, None] * side[..., None, :]
        return g[..., None, :] + distance[:, None] * direction

    def thrust(self, obs: np.ndarray) -> np.ndarray:
        """The law's thrust [N] before the box, (3,) or (N, 3)."""
        obs = _docking_obs(obs)
        horizon = self.gains.horizon
        steps_to_go = np.rint(obs[..., -1] * horizon).astype(np.int64)
        if np.any((steps_to_go < 1) | (steps_to_go > horizon)):
            raise ValueError(f"observed time-to-go must lie in [1/H, 1] with H = {horizon}")
        goal = obs[..., 6:9]
        positions = self.waypoint_positions(obs).reshape(*obs.shape[:-1], -1)
        targets = np.concatenate([positions, goal, np.zeros_like(goal)], axis=-1)
        return np.einsum("...ij,...j->...i", self.gains.target_gain[steps_to_go], targets) - np.einsum(
            "...ij,...j->...i", self.gains.state_gain[steps_to_go], obs[..., :6]
        )

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.clip(self.thrust(obs) / self.problem.u_max, -1.0, 1.0)


AXIS_TOLERANCE = 1e-9  # m: a chaser closer to the docking axis than this is on it


def _check_waypoints(waypoints, horizon: int) -> tuple[Waypoint, ...]:
    waypoints = tuple(waypoints)
    for w in waypoints:
        if not isinstance(w, Waypoint):
            raise ValueError(f"waypoints must be Waypoint(step, distance, angle_deg) values, got {w!r}")
        if not (isinstance(w.step, int | np.integer) and 0 < w.step < horizon):
            raise ValueError(f"a waypoint's step must be an integer in [1, {horizon - 1}], got {w.step!r}")
        if not (np.isfinite(w.distance) and w.distance >= 0 and np.isfinite(w.angle_deg)):
            raise ValueError(f"a waypoint needs a finite distance >= 0 m and a finite angle, got {w!r}")
    steps = [w.step for w in waypoints]
    if steps != sorted(set(steps)):
        raise ValueError(f"waypoint steps must be strictly increasing, got {steps}")
    return waypoints


def _docking_obs(obs) -> np.ndarray:
    obs = np.asarray(obs, dtype=np.float64)
    if obs.shape[-1] != DOCKING_OBS_DIM:
        raise ValueError(
            f"WaypointFeedback flies docking observations (..., {DOCKING_OBS_DIM}), got shape {obs.shape}"
        )
    return obs


@lru_cache(maxsize=8)
def _waypoint_gains(
    n: float, dt: float, mass: float, discretization: str, horizon: int, steps: tuple[int, ...]
) -> WaypointGains:
    """Per steps to go m (step k = H - m): the constraints stack each remaining waypoint's position
    rows and the final state's six over the controls u_k..u_{H-1}; the first three rows of their
    pseudo-inverse (SVD, least norm) give the first control's gains."""
    powers, impulse = _powers_and_impulses(n, dt, mass, discretization, horizon)
    target_gain = np.zeros((horizon + 1, 3, 3 * len(steps) + 6))
    state_gain = np.zeros((horizon + 1, 3, 6))
    for m in range(1, horizon + 1):
        k = horizon - m
        ahead = [(i, end) for i, end in enumerate(steps) if end > k]
        rows, free = [], []
        for end, keep in [(end, 3) for _, end in ahead] + [(horizon, 6)]:
            block = np.zeros((6, 3 * m))
            block[:, : 3 * (end - k)] = np.concatenate(impulse[end - k - 1 :: -1], axis=1)
            rows.append(block[:keep])
            free.append(powers[end - k][:keep])
        first_rows = np.linalg.pinv(np.concatenate(rows))[:3]
        columns = [c for i, _ in ahead for c in range(3 * i, 3 * i + 3)] + list(
            range(3 * len(steps), 3 * len(steps) + 6)
        )
        target_gain[m][:, columns] = first_rows
        state_gain[m] = first_rows @ np.concatenate(free)
    for array in (target_gain, state_gain):
        array.setflags(write=False)
    return WaypointGains(horizon, target_gain, state_gain)
