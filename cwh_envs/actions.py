"""Actions as the envs take them, checked: the one place a caller's action array is validated.

Its own module so that the env core (:mod:`cwh_envs.core`) and the dispersion model
(:mod:`cwh_envs.dispersions`), which both check actions, need not import each other.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def check_actions(actions: Any, shape: tuple[int, ...]) -> np.ndarray:
    """Normalised actions clipped to the box; NaN, a complex value or a wrong shape is a caller error."""
    a = real_array(actions, "action", shape)
    if a.shape != shape:
        raise ValueError(f"action must have shape {shape}, got {a.shape}")
    if np.isnan(a).any():
        raise ValueError("action contains NaN")
    return np.clip(a, -1.0, 1.0)


def real_array(value: Any, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a new float64 array. A complex value is refused: numpy would drop its imaginary
    part with no more than a warning."""
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError) as e:  # e.g. a ragged nesting
        raise ValueError(f"{name} must be a numeric array of shape {shape}") from e
    if raw.dtype.kind == "c" or (
        raw.dtype.kind == "O" and any(isinstance(v, complex | np.complexfloating) for v in raw.flat)
    ):
        raise ValueError(f"{name} must be real, got a complex value")
    try:
        return raw.astype(np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be a numeric array of shape {shape}") from e
