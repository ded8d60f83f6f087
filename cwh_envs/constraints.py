"""The docking env's optional path constraints beyond the keep-out, as batched functions of the
state and the docking point; the env, the expert, the CBF filter and the families all read them here.

- **Speed limit** ``(v0, v1)``: ``||v|| <= v0 + v1 ||r - g||`` (m/s, 1/s), the distance-dependent
  relative-speed limit of ACT3's safe-autonomy docking: slow near the port, faster far out.
- **Approach cone** ``(half_angle_deg, radius)``: within ``radius`` (m) of the docking point the
  chaser stays inside the cone with apex at ``g``, axis ``a = g / ||g||`` (outward from the chief
  through the port) and that half angle: ``a^T (r - g) >= cos(half_angle) ||r - g||``, the
  line-of-sight corridor of a real final approach. A second-order cone, convex in ``r``.
"""

from __future__ import annotations

import numpy as np

# A constraint counts as violated only beyond this slack: the expert meets it to solver accuracy.
SPEED_TOLERANCE = 1e-7  # m/s
CONE_TOLERANCE = 1e-7  # m, on a^T (r - g) - cos(theta) ||r - g||
APEX = 1e-6  # m: closer to the port than this, a point counts as at the cone's apex


def check_speed_limit(value) -> tuple[float, float] | None:
    if value is None:
        return None
    v0, v1 = _pair("speed_limit", value)
    if not (v0 > 0 and v1 >= 0):
        raise ValueError(f"speed_limit (v0, v1) needs v0 > 0 m/s and v1 >= 0 1/s, got {value!r}")
    return v0, v1


def check_approach_cone(value) -> tuple[float, float] | None:
    if value is None:
        return None
    half_angle, radius = _pair("approach_cone", value)
    if not (0 < half_angle < 90 and radius > 0):
        raise ValueError(
            f"approach_cone (half_angle_deg, radius) needs 0 < half_angle < 90 and radius > 0 m, got {value!r}"
        )
    return half_angle, radius


def _pair(name: str, value) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair of numbers or None, got {value!r}") from None
    if not (np.isfinite(a) and np.isfinite(b)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return a, b


def path_constrained(problem) -> bool:
    """Whether a docking problem has a speed limit or an approach cone beyond the keep-out."""
    return problem.speed_limit is not None or problem.approach_cone is not None


def speed_margin(states: np.ndarray, goals: np.ndarray, speed_limit: tuple[float, float]) -> np.ndarray:
    """``v0 + v1 ||r - g|| - ||v||`` (N,), m/s: negative where the speed limit is broken."""
    v0, v1 = speed_limit
    return v0 + v1 * np.linalg.norm(states[:, :3] - goals, axis=1) - np.linalg.norm(states[:, 3:], axis=1)


def cone_axis(goals: np.ndarray) -> np.ndarray:
    """The unit docking axis ``g / ||g||`` (N, 3). A docking point lies outside the keep-out; the
    zero rows of a vector env not yet reset get +x."""
    norm = np.linalg.norm(goals, axis=1, keepdims=True)
    return np.where(norm > 0, goals / np.where(norm > 0, norm, 1.0), np.array([1.0, 0.0, 0.0]))


def cone_terms(
    states: np.ndarray, goals: np.ndarray, approach_cone: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(in the cone's region, its slack ``a^T (r - g) - cos(theta) ||r - g||`` in m, the angle of
    ``r - g`` from the axis in degrees), each (N,). Within APEX of the port the point is at the
    apex: its angle is 0 and its slack at least 0 (a chaser 2e-7 m off the port, as a controller
    re-planning from float32 observations ends, is docked, not outside the cone)."""
    half_angle, radius = approach_cone
    offset = states[:, :3] - goals
    distance = np.linalg.norm(offset, axis=1)
    along = np.einsum("ij,ij->i", cone_axis(goals), offset)
    slack = along - np.cos(np.radians(half_angle)) * distance
    slack = np.where(distance <= APEX, np.maximum(slack, 0.0), slack)
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = np.where(distance > APEX, along / distance, 1.0)
    angle = np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))
    return distance <= radius, slack, angle
