"""Reference controllers: hand-written laws on the envs' observations, nothing learned.

The PD law, a naive speed-capped approach, and the closed-form shrinking-horizon minimum-energy law
(:class:`MinEnergyFeedback`); the receding-horizon MPC is :mod:`cwh_envs.mpc`. Shared by the
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


@lru_cache(maxsize=8)
def _min_energy_gains(n: float, dt: float, mass: float, discretization: str, horizon: int) -> MinEnergyGains:
    a, b = cwh_matrices(n, dt, mass, discretization)
    powers = [np.eye(6)]
    for _ in range(horizon):
        powers.append(a @ powers[-1])
    impulse = [power @ b for power in powers[:-1]]  # A^j B
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
