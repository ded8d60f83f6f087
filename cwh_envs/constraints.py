"""The docking env's optional path constraints beyond the keep-out, as batched functions of the
state and the docking point; the env, the expert, the CBF filter and the families all read them here.

- **Speed limit** ``(v0, v1)``: ``||v|| <= v0 + v1 ||r - g||`` (m/s, 1/s), the distance-dependent
  relative-speed limit of ACT3's safe-autonomy docking: slow near the port, faster far out.
- **Approach cone** ``(half_angle_deg, radius)``: within ``radius`` (m) of the docking point the
  chaser stays inside the cone with apex at ``g``, axis ``a = g / ||g||`` (outward from the chief
  through the port) and that half angle: ``a^T (r - g) >= cos(half_angle) ||r - g||``, the
  line-of-sight corridor of a real final approach. A second-order cone, convex in ``r``.
- **Capture envelope** ``capture_radius`` (m): the corridor's half-width at the port. As scored by
  the env, the cone's apex sits ``capture_radius / tan(half_angle)`` behind ``g`` on the axis, so a
  chaser that arrives within ``capture_radius`` of the axis at the port is inside the corridor; the
  zone is still the ball of ``radius`` about ``g``. A docking mechanism captures within such an
  envelope: the International Docking System Standard's initial-contact conditions allow 0.1 m of
  lateral misalignment (IDSS Interface Definition Document), hence the default CAPTURE_RADIUS. With
  ``capture_radius = 0`` the apex is the port itself (``CWHDockKOZ-v0``'s definition, under which a
  chaser 1 mm off the axis at the port is outside the cone). The experts and the nominal filter
  plan the corridor to the port (apex at ``g``): a tube ``capture_radius cos(half_angle)`` wide
  inside the scored one.

Each constraint also reports how deep a violation went (:func:`violation_depths`): metres inside the
keep-out, m/s over the speed limit, metres outside the cone (Euclidean distance to the corridor).
"""

from __future__ import annotations

import numpy as np

# A constraint counts as violated only beyond this slack: the expert meets it to solver accuracy.
SPEED_TOLERANCE = 1e-7  # m/s
CONE_TOLERANCE = 1e-7  # m, on a^T (r - g) - cos(theta) ||r - g||
APEX = 1e-6  # m: closer to the port than this, a point counts as at the cone's apex
CAPTURE_RADIUS = 0.1  # m: the corridor's half-width at the port (IDSS lateral misalignment; docstring)


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


def check_capture_radius(value, approach_cone: tuple[float, float] | None) -> float:
    """A capture radius in metres, finite and >= 0, inside the cone's zone when there is a cone."""
    numeric = isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)
    if not (numeric and np.isfinite(value) and value >= 0):
        raise ValueError(f"capture_radius must be a finite number of metres >= 0, got {value!r}")
    if approach_cone is not None and value >= approach_cone[1]:
        raise ValueError(
            f"capture_radius ({value:g} m) must be smaller than the approach cone's zone radius "
            f"({approach_cone[1]:g} m): the envelope at the port would swallow the whole corridor"
        )
    return float(value)


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


def cone_apex(
    goals: np.ndarray, approach_cone: tuple[float, float], capture_radius: float = 0.0
) -> np.ndarray:
    """The cone's apex (N, 3): ``capture_radius / tan(half_angle)`` behind the port on the axis."""
    setback = capture_radius / np.tan(np.radians(approach_cone[0]))
    return goals - setback * cone_axis(goals)


def cone_terms(
    states: np.ndarray,
    goals: np.ndarray,
    approach_cone: tuple[float, float],
    capture_radius: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(in the cone's region ``||r - g|| <= radius``, its slack ``a^T (r - p) - cos(theta) ||r - p||``
    in m, the angle of ``r - p`` from the axis in degrees), each (N,), with ``p`` the apex
    (:func:`cone_apex`; the port itself when ``capture_radius`` is 0). Within APEX of the apex the
    point is at the apex: its angle is 0 and its slack at least 0 (a chaser 2e-7 m off the port, as a
    controller re-planning from float32 observations ends, is docked, not outside the cone)."""
    half_angle, radius = approach_cone
    offset = states[:, :3] - cone_apex(goals, approach_cone, capture_radius)
    distance = np.linalg.norm(offset, axis=1)
    along = np.einsum("ij,ij->i", cone_axis(goals), offset)
    slack = along - np.cos(np.radians(half_angle)) * distance
    slack = np.where(distance <= APEX, np.maximum(slack, 0.0), slack)
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = np.where(distance > APEX, along / distance, 1.0)
    angle = np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))
    region = np.linalg.norm(states[:, :3] - goals, axis=1) <= radius
    return region, slack, angle


def cone_depth(
    states: np.ndarray,
    goals: np.ndarray,
    approach_cone: tuple[float, float],
    capture_radius: float = 0.0,
) -> np.ndarray:
    """How far outside the corridor each position lies (N,), m: its Euclidean distance to the cone
    (0 inside it, or outside the cone's region). For a point at distance ``l`` from the apex and
    ``phi`` degrees off the axis, ``l sin(phi - theta)`` while ``phi - theta < 90``, else ``l``."""
    half_angle = approach_cone[0]
    region, _, angle = cone_terms(states, goals, approach_cone, capture_radius)
    length = np.linalg.norm(states[:, :3] - cone_apex(goals, approach_cone, capture_radius), axis=1)
    beyond = np.radians(np.clip(angle - half_angle, 0.0, 90.0))
    return np.where(region, length * np.sin(beyond), 0.0)


def violation_depths(states, goals, problem) -> dict[str, np.ndarray]:
    """How deep each constraint of a docking problem is broken at each state (N,): ``keep_out``
    metres inside the sphere, ``speed`` m/s over the limit, ``cone`` metres outside the corridor
    (0 where met; only the constraints the problem has)."""
    out = {"keep_out": np.maximum(problem.koz_radius - np.linalg.norm(states[:, :3], axis=1), 0.0)}
    if problem.speed_limit is not None:
        out["speed"] = np.maximum(-speed_margin(states, goals, problem.speed_limit), 0.0)
    if problem.approach_cone is not None:
        out["cone"] = cone_depth(states, goals, problem.approach_cone, problem.capture_radius)
    return out
