"""CWHDockKOZ-v1: docking just outside a spherical keep-out zone (paper Sec. 4.3)."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from cwh_envs.core import CWHEnv, DockingCore, check_goals, check_states
from cwh_envs.datasets import check_pool_size, start_pool
from cwh_envs.sampling import sample_docking_start


class CWHDockKOZEnv(CWHEnv):
    r"""Dock at a point 3 m outside a 5 m keep-out sphere, starting on its far side, in ``H = 240`` steps.

    ## Description

    The same CWH dynamics as ``CWHRendezvous-v0`` (``x' = A x + B u`` with
    ``(A, B) = problem.matrices()``), a stronger thrust box ``|u_i| <= 2 N``, and a hard keep-out
    sphere of radius ``R = 5 m`` around the chief at the origin. The docking point ``g`` sits at
    8 m on a per-episode random bearing and the chaser starts 40-110 m out, biased opposite ``g``,
    so the straight line to ``g`` crosses the sphere: the agent must detour. Wrap the env in
    :class:`cwh_envs.wrappers.CBFSafetyFilter` to apply the paper's run-time CBF filter.

    ## Action Space

    ``Box(-1, 1, (3,), float32)``: thrust as a fraction of ``u_max`` (2 N) per axis; actions outside
    the box are clipped to it (NaN raises ``ValueError``).

    ## Observation Space

    ``Box(float32, (10,))`` (:func:`cwh_envs.observations.docking_observation`):

    | Num | Observation                      | Unit |
    |-----|----------------------------------|------|
    | 0-2 | position ``r``                   | m    |
    | 3-5 | velocity ``v``                   | m/s  |
    | 6-8 | docking point ``g``              | m    |
    | 9   | time-to-go ``tau = (H - k) / H`` | -    |

    Finite bounds as in ``CWHRendezvous-v0`` (exact reachable envelope of admissible starts);
    ``|g_i| <= 1e4 m``.

    ## Rewards

    The rendezvous reward measured to ``g`` instead of the origin, plus a keep-out penalty; the
    parts are in ``info["reward_terms"]`` and sum to the reward (``d = ||r - g||``):

    | Term       | Value                                                                                      |
    |------------|--------------------------------------------------------------------------------------------|
    | progress   | ``progress_weight * (d_k - d_{k+1})`` (0.1 per metre)                                      |
    | effort     | ``-effort_weight * ||a_k||^2`` (0.01)                                                      |
    | keep_out   | ``-koz_weight * cost_{k+1}``: -1.0 for every step that ends inside the sphere              |
    | terminal   | at ``k + 1 = H`` only: ``success_bonus * is_success - terminal_weight * (d_H / success_distance + v_H / success_speed)`` (10.0, 0.1) |

    ## Starting State

    ``cwh_envs.sampling.sample_docking_start(self.np_random, problem)`` draws ``(x0, g)``: ``g`` at
    ``goal_radius`` on a uniform bearing, ``x0`` 40-110 m out in a 60-degree cone around ``-g``, at
    rest by default, kept only if the unconstrained minimum-energy transfer pierces the keep-out
    (so it binds) and fits the thrust box. ``reset(options={"initial_state": x0, "goal": g})`` sets
    either or both; a missing one comes from the same draw.

    ``start_pool=P`` draws ``(x0, g)`` instead from a fixed pool of ``P`` such screened pairs
    (:func:`cwh_envs.datasets.start_pool`, built once and cached), uniformly with replacement by
    ``self.np_random.integers(P)``: the empirical distribution of ``P`` screened draws rather than
    fresh ones, at the cost of an index draw instead of a screen.

    ## Episode End

    ``terminated=True`` at ``k = H``, ``truncated`` always ``False`` (see ``CWHRendezvous-v0``: the
    time-to-go is observed, so the horizon is a terminal state). Entering the keep-out does not
    end the episode: it costs, and the paper's metric counts the fraction of such steps.

    ## Information

    | Key                  | When              | Meaning                                                         |
    |----------------------|-------------------|-----------------------------------------------------------------|
    | ``distance``         | reset, every step | ``||r - g||``, m                                                |
    | ``speed``            | reset, every step | ``||v||``, m/s                                                  |
    | ``clearance``        | reset, every step | ``||r|| - R``, m (negative inside the sphere)                   |
    | ``in_koz``           | reset, every step | ``clearance < 0``                                               |
    | ``cost``             | every step        | 1.0 if the step ended inside the sphere, else 0.0 (Safety-Gymnasium's convention) |
    | ``reward_terms``     | every step        | dict of floats summing to the reward                            |
    | ``terminal_distance``| at ``k = H``      | final ``||r - g||``, m                                          |
    | ``terminal_speed``   | at ``k = H``      | final speed, m/s                                                |
    | ``violation_rate``   | at ``k = H``      | fraction of the ``H`` steps that ended inside the sphere        |
    | ``min_clearance``    | at ``k = H``      | least clearance over the states ``x_1 .. x_H``, m               |
    | ``is_success``       | at ``k = H``      | distance < ``success_distance``, speed < ``success_speed`` and no violation |

    With :class:`~cwh_envs.wrappers.CBFSafetyFilter` every step also has ``cbf_active``,
    ``cbf_infeasible`` and ``cbf_correction_norm``.

    ## Path constraints (optional)

    ``speed_limit=(v0, v1)`` caps the relative speed by the distance to the docking point,
    ``||v|| <= v0 + v1 ||r - g||`` (ACT3's docking limit); ``approach_cone=(half_angle_deg, radius)``
    keeps the chaser, within ``radius`` of ``g``, inside the cone with apex ``g`` about the outward
    docking axis ``g / ||g||`` (:mod:`cwh_envs.constraints`). Both default to ``None``, the paper's
    problem, whose info is as above. With either on, a step broken costs ``speed_weight`` /
    ``cone_weight`` (1.0) in ``reward_terms`` (``speed``, ``cone``), success also needs no step
    broken, and the info gains:

    | Key                      | When              | Meaning                                                   |
    |--------------------------|-------------------|-----------------------------------------------------------|
    | ``speed_margin``         | reset, every step | ``v0 + v1 ||r - g|| - ||v||``, m/s (negative: over the limit) |
    | ``in_cone_region``       | reset, every step | ``||r - g|| <= radius``                                   |
    | ``cone_angle``           | reset, every step | angle of ``r - g`` from the docking axis, deg (0 at ``g``) |
    | ``cost_keep_out``        | every step        | 1.0 if the step ended inside the sphere                   |
    | ``cost_speed``           | every step        | 1.0 if the step ended over the speed limit                |
    | ``cost_cone``            | every step        | 1.0 if the step ended in the region, outside the cone     |
    | ``cost``                 | every step        | the sum of the costs (Safety-Gymnasium's total)           |
    | ``speed_violation_rate`` | at ``k = H``      | fraction of the ``H`` steps over the speed limit          |
    | ``min_speed_margin``     | at ``k = H``      | least ``speed_margin`` over ``x_1 .. x_H``, m/s           |
    | ``cone_violation_rate``  | at ``k = H``      | fraction of the ``H`` steps in the region outside the cone |
    | ``min_cone_margin``      | at ``k = H``      | least ``half_angle - cone_angle`` over the steps in the region, deg (inf if none) |

    ## Arguments

    Every :class:`cwh_envs.problems.DockingProblem` field (``n, dt, mass, discretization, horizon,
    u_max, koz_radius, goal_radius, margin, start_distance, success_distance, success_speed`` and
    the sampler's ``start_cone_deg, velocity_box, pierce_depth``, the optional ``speed_limit,
    approach_cone``), the reward weights ``progress_weight=0.1, effort_weight=0.01, terminal_weight=0.1,
    success_bonus=10.0, koz_weight=1.0, speed_weight=1.0, cone_weight=1.0``, ``start_pool`` (``None``: fresh draws, the default; or a
    pool size) and ``render_mode`` (``None`` or ``"rgb_array"``).
    ``self.problem``, ``self.state`` (the (6,) SI state) and ``self.goal`` are public.
    """

    core_cls: ClassVar[type] = DockingCore
    reset_options: ClassVar[tuple[str, ...]] = ("initial_state", "goal")

    def __init__(self, render_mode: str | None = None, start_pool: int | None = None, **kwargs: Any) -> None:
        pool_size = None if start_pool is None else check_pool_size(start_pool)
        super().__init__(render_mode, **kwargs)
        self.start_pool = pool_size

    @property
    def goal(self) -> np.ndarray:
        """The docking point of the current episode, m (a copy)."""
        return self._core.goals[0].copy()

    def _initial(self, options: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        state = check_states(options["initial_state"]) if "initial_state" in options else None
        goal = check_goals(options["goal"], self.problem) if "goal" in options else None
        if state is None or goal is None:
            if self.start_pool is None:
                sampled_state, sampled_goal = sample_docking_start(self.np_random, self.problem)
            else:  # the same draw as a row of the vector env (cwh_envs.vector)
                pool = start_pool("docking", self.start_pool, self.problem)
                drawn = self.np_random.integers(len(pool))
                sampled_state, sampled_goal = pool.starts[drawn], pool.goals[drawn]
            state = np.asarray(sampled_state, dtype=np.float64) if state is None else state
            goal = np.asarray(sampled_goal, dtype=np.float64) if goal is None else goal
        return state, goal
