"""Screened initial conditions for both problems (paper Sec. 4.2-4.3).

Both samplers draw candidates in fixed-size blocks from ``rng`` and keep them in draw order,
so the result is a deterministic function of the generator state and ``n`` samples are the
first ``n`` of any larger draw from the same state (nested training sets).

Rendezvous: uniform in the position and velocity boxes, kept only if the expert
(:func:`cwh_envs.experts.solve_rendezvous`) reaches the origin within ``reach_tolerance``.

Docking: the docking point ``g`` sits at ``goal_radius`` on a uniform bearing; the start lies at
a uniform distance in ``start_distance`` on a bearing uniform in the cone of half-angle
``start_cone_deg`` around ``-g`` (the far side), with velocity uniform in ``+-velocity_box``
(zero by default: released from a hold point). Over the 2400 s horizon (0.43 orbits) the drift
bends the minimum-energy path, so the keep-out binds in only ~14 % of such demonstrations. The
fast screen keeps a start only if the *unconstrained* minimum-energy trajectory (closed form,
linear in (x0, g), batched) comes within ``R + delta - pierce_depth`` of the centre (by default
R: it crosses the keep-out itself) and its thrust fits the box; ~11 % of candidates pass. What
this guarantees (see docs/experts-and-cbf.md):

* the keep-out binds in every demonstration the expert returns for the start: a feasible
  trajectory with no active half-space would be the unconstrained optimum, which pierces;
* the box-only problem is feasible (its optimum is the screened closed form).

It does not run the SCP, so it does not guarantee the expert converges; the dataset builders
run the full expert and keep only the demonstrations it solved (all of them so far).
"""

from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np

from cwh_envs.experts import linear_model, solve_rendezvous_many
from cwh_envs.problems import DockingProblem, RendezvousProblem

RENDEZVOUS_BLOCK = 64  # candidates per draw; only as many as needed are run through the expert
DOCKING_BLOCK = 512  # candidates per draw; the whole block is screened as one matrix product
# Acceptance is ~10 % (docking) and higher for rendezvous with the paper's constants; this many
# candidates in a row without one accepted means the problem's constants admit (almost) no start.
MAX_CANDIDATES_WITHOUT_ACCEPT = 16_384


class NoAdmissibleStart(ValueError):
    """The problem's constants (e.g. a short horizon or a small thrust box) admit no screened start."""


def sample_rendezvous_starts(rng: np.random.Generator, n: int, problem: RendezvousProblem) -> np.ndarray:
    """(n, 6) reachability-screened rendezvous starts [m, m/s]."""
    return screened_rendezvous(rng, n, problem)[0]


def sample_rendezvous_start(rng: np.random.Generator, problem: RendezvousProblem) -> np.ndarray:
    """One screened rendezvous start (6,)."""
    return sample_rendezvous_starts(rng, 1, problem)[0]


def screened_rendezvous(rng: np.random.Generator, n: int, problem: RendezvousProblem):
    """Screened starts (n, 6) with their expert states (n, H+1, 6) and controls (n, H, 3) [N].

    The screen *is* the expert solve, so the dataset builders reuse its trajectories.
    """
    _check_count(n)
    starts, states, controls = zip(*itertools.islice(iter_rendezvous(rng, problem), n), strict=True)
    return np.array(starts), np.array(states), np.array(controls)


def iter_rendezvous(rng: np.random.Generator, problem: RendezvousProblem):
    """Endless (start (6,), states (H+1, 6), controls (H, 3)) of reachable starts, in draw order."""
    misses = 0
    while True:
        candidates = rendezvous_candidates(rng, problem)
        # Solve in small slices so a request for a few starts does not pay for the whole block.
        for first in range(0, RENDEZVOUS_BLOCK, 8):
            states, controls, solved = solve_rendezvous_many(candidates[first : first + 8], problem)
            misses = 0 if solved.any() else _count_miss(misses, len(solved), problem)
            for i in np.flatnonzero(solved):
                yield candidates[first + i], states[i], controls[i]


def sample_docking_starts(
    rng: np.random.Generator, n: int, problem: DockingProblem
) -> tuple[np.ndarray, np.ndarray]:
    """Screened far-side docking starts (n, 6) [m, m/s] and docking points (n, 3) [m]."""
    _check_count(n)
    starts, goals = zip(*itertools.islice(iter_docking_starts(rng, problem), n), strict=True)
    return np.array(starts), np.array(goals)


def iter_docking_starts(rng: np.random.Generator, problem: DockingProblem):
    """Endless screened (start (6,), goal (3,)) pairs in draw order, one block screened at a time."""
    misses = 0
    while True:
        starts, goals = docking_candidates(rng, problem)
        keep = docking_screen(starts, goals, problem)
        misses = 0 if keep.any() else _count_miss(misses, len(keep), problem)
        yield from zip(starts[keep], goals[keep], strict=True)


def sample_docking_start(rng: np.random.Generator, problem: DockingProblem) -> tuple[np.ndarray, np.ndarray]:
    """One screened docking start (6,) and docking point (3,)."""
    starts, goals = sample_docking_starts(rng, 1, problem)
    return starts[0], goals[0]


def docking_screen(starts: np.ndarray, goals: np.ndarray, problem: DockingProblem) -> np.ndarray:
    """(N,) bool: the unconstrained minimum-energy path pierces ``R + delta - pierce_depth`` and fits the box."""
    keep = unconstrained_min_distance(starts, goals, problem) <= _pierce_radius(problem)
    keep[keep] = unconstrained_peak_thrust(starts[keep], goals[keep], problem) <= problem.u_max
    return keep


def unconstrained_min_distance(starts: np.ndarray, goals: np.ndarray, problem: DockingProblem) -> np.ndarray:
    """(N,) closest approach [m] to the centre of the unconstrained minimum-energy trajectories."""
    position_map, _ = _docking_maps(problem)
    positions = _apply(position_map, starts, goals).reshape(len(starts), -1, 3)
    return np.sqrt(np.einsum("nki,nki->nk", positions, positions).min(axis=1))


def unconstrained_peak_thrust(starts: np.ndarray, goals: np.ndarray, problem: DockingProblem) -> np.ndarray:
    """(N,) largest per-axis thrust [N] of the unconstrained minimum-energy solutions."""
    _, control_map = _docking_maps(problem)
    return np.abs(_apply(control_map, starts, goals)).max(axis=1, initial=0.0)


def _apply(linear_map: np.ndarray, starts: np.ndarray, goals: np.ndarray) -> np.ndarray:
    # einsum rather than @: a threaded BLAS product stalls for tens of ms whenever the cores are
    # busy (vector envs next to training); this loop has no threads and costs ~2 ms per block.
    return np.einsum("nk,km->nm", np.concatenate([starts, goals], axis=1), linear_map)


@lru_cache(maxsize=8)
def _docking_maps(problem: DockingProblem) -> tuple[np.ndarray, np.ndarray]:
    """Linear maps from [x0, g] (9,) to the unconstrained path's positions ((H+1)*3,) and controls (3H,)."""
    model = linear_model(problem)
    # U* = G^+ ([g, 0] - A^H x0), so both U* and the positions are linear in (x0, g).
    control_map = np.concatenate(
        [-model.terminal_pinv @ model.powers[-1], model.terminal_pinv[:, :3]], axis=1
    )
    position_map = model.position_response @ control_map
    position_map[:, :, :6] += model.powers[:, :3, :]
    return position_map.reshape(-1, 9).T.copy(), control_map.T.copy()


def rendezvous_candidates(rng: np.random.Generator, problem: RendezvousProblem) -> np.ndarray:
    """One block (RENDEZVOUS_BLOCK, 6) of unscreened rendezvous candidates; the screened starts are a subset."""
    half_widths = np.concatenate([problem.position_box, problem.velocity_box])
    return rng.uniform(-half_widths, half_widths, size=(RENDEZVOUS_BLOCK, 6))


def docking_candidates(rng: np.random.Generator, problem: DockingProblem) -> tuple[np.ndarray, np.ndarray]:
    """One block of unscreened far-side candidates: starts (DOCKING_BLOCK, 6), goals (DOCKING_BLOCK, 3)."""
    size = DOCKING_BLOCK
    goal_dirs = _unit(rng.normal(size=(size, 3)))
    start_dirs = _cone_directions(rng, -goal_dirs, np.radians(problem.start_cone_deg))
    distances = rng.uniform(*problem.start_distance, size=size)
    velocities = rng.uniform(-1.0, 1.0, size=(size, 3)) * np.asarray(problem.velocity_box)
    starts = np.concatenate([start_dirs * distances[:, None], velocities], axis=1)
    return starts, goal_dirs * problem.goal_radius


def _cone_directions(rng: np.random.Generator, axes: np.ndarray, half_angle: float) -> np.ndarray:
    """Unit vectors uniform (by solid angle) in the cones of ``half_angle`` around unit ``axes`` (N, 3)."""
    cos_theta = rng.uniform(np.cos(half_angle), 1.0, size=len(axes))
    phi = rng.uniform(0.0, 2.0 * np.pi, size=len(axes))
    helper = np.where(np.abs(axes[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = _unit(np.cross(axes, helper))
    e2 = np.cross(axes, e1)
    sin_theta = np.sqrt(1.0 - cos_theta**2)
    lateral = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
    return cos_theta[:, None] * axes + sin_theta[:, None] * lateral


def _pierce_radius(problem: DockingProblem) -> float:
    return problem.koz_radius + problem.margin - problem.pierce_depth


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def _count_miss(misses: int, rejected: int, problem) -> int:
    misses += rejected
    if misses >= MAX_CANDIDATES_WITHOUT_ACCEPT:
        raise NoAdmissibleStart(
            f"no start passed the screen in {misses} candidates in a row: {problem} admits (almost) no "
            "reachable start; pass reset(options={'initial_state': ...}) or relax horizon/u_max"
        )
    return misses


def _check_count(n: int) -> None:
    if not (isinstance(n, int | np.integer) and n >= 1):
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
