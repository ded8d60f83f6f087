"""Reference controllers: hand-written laws on the envs' observations, nothing learned.

Shared by the examples, the benchmarks and the tests. Both read the layout of
:mod:`cwh_envs.observations` (r = obs[..., 0:3], v = obs[..., 3:6], docking's goal g = obs[..., 6:9])
and return normalised actions in [-1, 1]^3 (thrust / u_max), batched over leading dimensions.
"""

from __future__ import annotations

import numpy as np

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
