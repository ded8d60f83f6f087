"""Policy inputs, shared by the envs and the demonstration datasets so both see one layout.

Rendezvous: ``[x, y, z, vx, vy, vz, tau]``; docking: ``[r(3), v(3), g(3), tau]``, with the
time-to-go ``tau = (H - k) / H`` running from 1 at step 0 to 1/H at the last action step.
Positions are in metres, velocities in m/s, all in the LVLH frame.
"""

from __future__ import annotations

import numpy as np

RENDEZVOUS_OBS_DIM = 7
DOCKING_OBS_DIM = 10


def time_to_go(step, horizon: int) -> np.ndarray:
    """``tau = (H - k) / H`` for an int step or an (N,) array of steps."""
    if horizon < 1:
        raise ValueError(f"horizon must be >= 1, got {horizon!r}")
    return (horizon - np.asarray(step, dtype=np.float64)) / horizon


def rendezvous_observation(states, step, horizon: int, *, dtype=np.float32) -> np.ndarray:
    """States (6,) or (N, 6) and step int or (N,) ints -> observations (7,) or (N, 7)."""
    states = np.asarray(states, dtype=np.float64)
    _check_last_dim("states", states, 6)
    tau = np.broadcast_to(time_to_go(step, horizon), states.shape[:-1])
    return np.concatenate([states, tau[..., None]], axis=-1).astype(dtype, copy=False)


def docking_observation(states, goals, step, horizon: int, *, dtype=np.float32) -> np.ndarray:
    """States (6,)/(N, 6), goals (3,)/(N, 3) in metres, step int or (N,) -> (10,) or (N, 10)."""
    states = np.asarray(states, dtype=np.float64)
    goals = np.asarray(goals, dtype=np.float64)
    _check_last_dim("states", states, 6)
    _check_last_dim("goals", goals, 3)
    batch = np.broadcast_shapes(states.shape[:-1], goals.shape[:-1])
    tau = np.broadcast_to(time_to_go(step, horizon), batch)
    parts = [np.broadcast_to(states, (*batch, 6)), np.broadcast_to(goals, (*batch, 3)), tau[..., None]]
    return np.concatenate(parts, axis=-1).astype(dtype, copy=False)


def _check_last_dim(name: str, array: np.ndarray, size: int) -> None:
    if array.ndim not in (1, 2) or array.shape[-1] != size:
        raise ValueError(f"{name} must have shape ({size},) or (N, {size}), got {array.shape}")
