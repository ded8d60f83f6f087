"""CWHRendezvous-v0: unconstrained rendezvous with the target at the LVLH origin (paper Sec. 4.2)."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from cwh_envs.core import CWHEnv, RendezvousCore, check_states
from cwh_envs.datasets import check_pool_size, start_pool
from cwh_envs.sampling import sample_rendezvous_start


class CWHRendezvousEnv(CWHEnv):
    r"""Close from a wide range of initial conditions to a target at the origin in ``H = 80`` steps.

    ## Description

    A chaser spacecraft moves relative to a target on a low-Earth orbit under the linear
    Clohessy-Wiltshire-Hill dynamics in the target's LVLH frame (x radial, y along-track,
    z cross-track). Each step holds a per-axis thrust for ``dt = 10 s`` and advances the state with
    the one discrete model of :mod:`cwh_envs.dynamics`, ``x' = A x + B u`` with
    ``(A, B) = problem.matrices()`` (forward Euler by default, ``discretization="exact"`` for the
    zero-order hold). The task is finite-horizon: be at the origin, slowly, at step ``H``.

    ## Action Space

    ``Box(-1, 1, (3,), float32)``: thrust as a fraction of ``u_max`` (0.25 N) per axis. Actions
    outside the box are clipped to it (NaN raises ``ValueError``).

    | Num | Action                  | Min | Max | Applied thrust   |
    |-----|-------------------------|-----|-----|------------------|
    | 0   | radial thrust ``u_x``   | -1  | 1   | ``a_0 * u_max`` N |
    | 1   | along-track ``u_y``     | -1  | 1   | ``a_1 * u_max`` N |
    | 2   | cross-track ``u_z``     | -1  | 1   | ``a_2 * u_max`` N |

    ## Observation Space

    ``Box(float32, (7,))``, the paper's time-augmented policy input
    (:func:`cwh_envs.observations.rendezvous_observation`):

    | Num | Observation                      | Unit |
    |-----|----------------------------------|------|
    | 0-2 | position ``x, y, z``             | m    |
    | 3-5 | velocity ``vx, vy, vz``          | m/s  |
    | 6   | time-to-go ``tau = (H - k) / H`` | -    |

    The bounds are finite: ``tau`` lies in [0, 1] and the state bounds are the exact worst case
    reachable within ``H`` steps from any admissible start (|position| <= 1e4 m, |velocity| <= 10 m/s
    per axis) under any admissible thrust, so no policy can leave the space.

    ## Rewards

    A dense reward whose parts are returned in ``info["reward_terms"]`` (they sum to the reward),
    with ``d`` the distance to the origin, ``v`` the speed, ``a`` the clipped action:

    | Term       | Value                                                                                      |
    |------------|--------------------------------------------------------------------------------------------|
    | progress   | ``progress_weight * (d_k - d_{k+1})``: the distance closed this step (0.1 per metre)       |
    | effort     | ``-effort_weight * ||a_k||^2`` (0.01, at most 0.03 per step)                                |
    | terminal   | at ``k + 1 = H`` only: ``success_bonus * is_success - terminal_weight * (d_H / success_distance + v_H / success_speed)`` |

    The progress terms telescope to ``progress_weight * (d_0 - d_H)``, so they only spread the
    terminal objective over the episode; the terminal term adds the speed that success requires.

    ## Starting State

    ``cwh_envs.sampling.sample_rendezvous_start(self.np_random, problem)``: uniform in the box
    (positions +-[75, 75, 37.5] m, velocities +-[0.08, 0.08, 0.04] m/s) and screened so that the
    optimal-control expert reaches the origin. ``reset(options={"initial_state": x0})`` starts from a
    given 6-vector instead.

    ``start_pool=P`` draws each start instead from a fixed pool of ``P`` such screened starts
    (:func:`cwh_envs.datasets.start_pool`, built once and cached), uniformly with replacement by
    ``self.np_random.integers(P)``: a reset then costs an index draw, not an expert solve, and the
    starts are the empirical distribution of ``P`` screened draws rather than fresh ones.

    ## Episode End

    The episode has a fixed length: ``terminated=True`` at ``k = H`` and ``truncated`` is always
    ``False``. The time-to-go is observed, so the end of the horizon is part of the task (a true
    terminal state, not a time limit): learners must not bootstrap past it, which is what
    Stable-Baselines3 and Gymnasium do for ``terminated``. There is no early termination.

    ## Information

    | Key                  | When                | Meaning                                                |
    |----------------------|---------------------|--------------------------------------------------------|
    | ``distance``         | reset, every step   | ``||r||`` to the origin, m                             |
    | ``speed``            | reset, every step   | ``||v||``, m/s                                         |
    | ``reward_terms``     | every step          | dict of floats summing to the reward                   |
    | ``terminal_distance``| at ``k = H``        | final distance, m (the paper's metric)                 |
    | ``terminal_speed``   | at ``k = H``        | final speed, m/s                                       |
    | ``is_success``       | at ``k = H``        | ``terminal_distance < success_distance and terminal_speed < success_speed`` |

    ## Arguments

    Every :class:`cwh_envs.problems.RendezvousProblem` field (``n, dt, mass, discretization,
    horizon, u_max, position_box, velocity_box, success_distance, success_speed,
    reach_tolerance``), the reward weights ``progress_weight=0.1, effort_weight=0.01,
    terminal_weight=1.0, success_bonus=10.0``, ``start_pool`` (``None``: fresh draws, the default; or
    a pool size) and ``render_mode`` (``None`` or ``"rgb_array"``: an image of the trajectory so far
    in three projections). Invalid values raise ``ValueError``, unknown names ``TypeError``::

        import gymnasium as gym
        env = gym.make("cwh_envs:CWHRendezvous-v0", discretization="exact")

    The ``cwh_envs:`` prefix makes Gymnasium import the package, which registers the envs
    (Gymnasium 1.x loads no plugin entry points); after ``import cwh_envs`` the bare id works.
    ``self.problem`` holds the constants and ``self.state`` the current SI state.
    """

    core_cls: ClassVar[type] = RendezvousCore
    reset_options: ClassVar[tuple[str, ...]] = ("initial_state",)

    def __init__(self, render_mode: str | None = None, start_pool: int | None = None, **kwargs: Any) -> None:
        pool_size = None if start_pool is None else check_pool_size(start_pool)
        super().__init__(render_mode, **kwargs)
        self.start_pool = pool_size

    def _initial(self, options: dict[str, Any]) -> tuple[np.ndarray, None]:
        if "initial_state" in options:
            return check_states(options["initial_state"]), None
        if self.start_pool is not None:  # the same draw as a row of the vector env (cwh_envs.vector)
            pool = start_pool("rendezvous", self.start_pool, self.problem)
            return np.array(pool.starts[self.np_random.integers(len(pool))]), None
        return np.asarray(sample_rendezvous_start(self.np_random, self.problem), dtype=np.float64), None
