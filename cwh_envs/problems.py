"""The two problems' constants, in one place (paper Sec. 4 and Table 1 defaults).

The envs, the experts, the dataset builders, the CBF filter and the families all build
their models from these dataclasses, so a changed constant changes every consumer at once.
Every field is also a keyword argument of the corresponding env (``gym.make(id, **kwargs)``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from cwh_envs.constraints import CAPTURE_RADIUS, check_approach_cone, check_capture_radius, check_speed_limit
from cwh_envs.dynamics import DISCRETIZATIONS, MASS, MEAN_MOTION, TIME_STEP, cwh_matrices

# The longest episode, in steps. 10**5 steps of the default 10 s are about 180 orbits, over 400
# times the paper's horizons (80, 240). The envs' constructors walk the horizon step by step
# (core.state_envelope: about 1 s at this bound), so an unbounded one (10**9) would hang them.
MAX_HORIZON = 100_000


@dataclass(frozen=True)
class _Orbit:
    n: float = MEAN_MOTION
    dt: float = TIME_STEP
    mass: float = MASS
    discretization: str = "euler"
    horizon: int = 80
    u_max: float = 0.25

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        return cwh_matrices(self.n, self.dt, self.mass, self.discretization)

    def replace(self, **changes):
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)

    def __post_init__(self) -> None:
        if self.discretization not in DISCRETIZATIONS:
            raise ValueError(f"discretization must be one of {DISCRETIZATIONS}, got {self.discretization!r}")
        if not (isinstance(self.horizon, int | np.integer) and 2 <= self.horizon <= MAX_HORIZON):
            raise ValueError(f"horizon must be an integer in [2, {MAX_HORIZON}], got {self.horizon!r}")
        for name in ("n", "dt", "mass", "u_max"):
            _positive(name, getattr(self, name))


@dataclass(frozen=True)
class RendezvousProblem(_Orbit):
    """Unconstrained rendezvous to the origin (paper Sec. 4.2)."""

    horizon: int = 80
    u_max: float = 0.25  # N per axis
    position_box: tuple[float, float, float] = (75.0, 75.0, 37.5)  # m, starts uniform in +-box
    velocity_box: tuple[float, float, float] = (0.08, 0.08, 0.04)  # m/s
    success_distance: float = 25.0  # m
    success_speed: float = 0.05  # m/s
    reach_tolerance: float = 1e-6  # m, expert terminal error accepted by the reachability screen

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("position_box", "velocity_box"):
            box = getattr(self, name)
            if len(box) != 3 or any(not (np.isfinite(v) and v >= 0) for v in box):
                raise ValueError(f"{name} must be three non-negative half-widths, got {box!r}")
        for name in ("success_distance", "success_speed", "reach_tolerance"):
            _positive(name, getattr(self, name))


@dataclass(frozen=True)
class DockingProblem(_Orbit):
    """Docking at a point outside a spherical keep-out zone at the origin (paper Sec. 4.3)."""

    horizon: int = 240
    u_max: float = 2.0  # N per axis
    koz_radius: float = 5.0  # m, hard keep-out sphere centred at the origin
    goal_radius: float = 8.0  # m, docking point distance from the centre
    margin: float = 0.5  # m, standoff delta used by the expert's half-spaces and the CBF filter
    start_distance: tuple[float, float] = (40.0, 110.0)  # m, far-side start range
    start_cone_deg: float = 60.0  # deg, start bearing uniform in this cone around -goal (far side)
    velocity_box: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m/s, start velocity uniform in +-box
    pierce_depth: float = 0.5  # m, the unconstrained path must dip this far inside R + delta
    success_distance: float = 1.0  # m, terminal distance to the docking point
    success_speed: float = 0.05  # m/s, terminal relative speed
    # Optional path constraints (cwh_envs.constraints); None, the default, is the paper's problem.
    speed_limit: tuple[float, float] | None = None  # (v0 m/s, v1 1/s): ||v|| <= v0 + v1 ||r - g||
    approach_cone: tuple[float, float] | None = None  # (half angle deg, radius m) about g / ||g|| at g
    # m: the corridor's half-width at the port, as the env scores the cone (CWHDockKOZ-v0 registers
    # 0, the apex on the port). Scoring only: the experts plan the corridor to the port.
    capture_radius: float = CAPTURE_RADIUS

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "speed_limit", check_speed_limit(self.speed_limit))
        object.__setattr__(self, "approach_cone", check_approach_cone(self.approach_cone))
        object.__setattr__(
            self, "capture_radius", check_capture_radius(self.capture_radius, self.approach_cone)
        )
        for name in ("koz_radius", "goal_radius", "success_distance", "success_speed"):
            _positive(name, getattr(self, name))
        if not (_real(self.margin) and self.margin >= 0):
            raise ValueError(f"margin must be a non-negative finite number, got {self.margin!r}")
        if self.goal_radius <= self.koz_radius + self.margin:
            raise ValueError(
                f"goal_radius ({self.goal_radius}) must lie outside the keep-out radius plus margin "
                f"({self.koz_radius} + {self.margin})"
            )
        low, high = self.start_distance
        if not (self.goal_radius < low <= high):
            raise ValueError(
                f"start_distance must satisfy goal_radius < low <= high, got {self.start_distance!r}"
            )
        if not (0.0 <= self.start_cone_deg < 90.0):
            raise ValueError(
                f"start_cone_deg must lie in [0, 90) to stay on the far side, got {self.start_cone_deg!r}"
            )
        if len(self.velocity_box) != 3 or any(not (np.isfinite(v) and v >= 0) for v in self.velocity_box):
            raise ValueError(
                f"velocity_box must be three non-negative half-widths, got {self.velocity_box!r}"
            )
        if not (0.0 <= self.pierce_depth < self.koz_radius + self.margin):
            raise ValueError(f"pierce_depth must lie in [0, koz_radius + margin), got {self.pierce_depth!r}")


# Fields that change how a flight is scored, never which starts are screened or what the expert
# plans: they stay out of a problem's identity in the shipped splits and the dataset caches.
SCORING_ONLY = frozenset({"capture_radius"})


def _real(value) -> bool:
    """A finite real number; a bool is not one (True would pass as 1)."""
    numeric = isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)
    return numeric and bool(np.isfinite(value))


def _positive(name: str, value: float) -> None:
    if not (_real(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
