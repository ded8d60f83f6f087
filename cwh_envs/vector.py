"""Native batched vector envs: ``gym.make_vec(id, num_envs=N)`` steps N episodes as numpy arrays.

They run the same :mod:`cwh_envs.core` as the single envs, so a row behaves exactly like a single
env given the same start and actions. Infos follow the vector convention, one array per key with a
boolean ``_key`` mask of the rows that have it, exactly as ``SyncVectorEnv`` of the single envs
would build them (a key no row has is absent).

Autoreset, either of Gymnasium's two modes (``autoreset_mode=``), each as ``SyncVectorEnv`` does it:

* ``AutoresetMode.NEXT_STEP`` (the default): the step that ends an episode returns its final
  observation with ``terminated=True``; the next call ignores that row's action and returns the new
  episode's first observation with reward 0, ``terminated=truncated=False`` and the reset info.
* ``AutoresetMode.SAME_STEP``: the step that ends an episode also starts the next one and returns
  its first observation (with the final reward and ``terminated=True``) and the reset info; the
  final observation is in ``info["final_obs"]`` and the end-of-episode info in
  ``info["final_info"]``. Stable-Baselines3 expects this (:mod:`cwh_envs.sb3`).

Starts: by default fresh screened draws (:mod:`cwh_envs.sampling`), all rows in one batch from the
env's ``np_random``. With ``start_pool=P`` each row draws instead from a fixed pool of ``P``
screened starts (:func:`cwh_envs.datasets.start_pool`) with its own generator, seeded ``seed + i``
by ``reset(seed=seed)`` as ``SyncVectorEnv`` seeds its sub-envs (from the env's ``np_random`` when
no seed is given), so row ``i`` is then exactly ``gym.make(id, start_pool=P)`` reset with
``seed + i``, through every autoreset. A pooled reset is an index draw (a few microseconds a row);
a fresh one screens candidates, which for rendezvous means solving the expert.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from cwh_envs.actions import check_actions
from cwh_envs.core import (
    DockingCore,
    RendezvousCore,
    action_space,
    check_goals,
    check_margin,
    check_states,
    filter_actions,
    observation_space,
    parse_kwargs,
)
from cwh_envs.datasets import StartPool, check_pool_size, start_pool
from cwh_envs.sampling import sample_docking_starts, sample_rendezvous_starts

AUTORESET_MODES = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)


class _CWHVectorEnv(VectorEnv):
    metadata: ClassVar[dict[str, Any]] = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}
    core_cls: ClassVar[type[RendezvousCore]]
    reset_options: ClassVar[tuple[str, ...]]
    task: ClassVar[str]

    def __init__(
        self,
        num_envs: int = 1,
        render_mode: str | None = None,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        start_pool: int | None = None,
        **kwargs: Any,
    ) -> None:
        if not (isinstance(num_envs, int | np.integer) and num_envs >= 1):
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        if render_mode is not None:
            raise ValueError("the native vector env does not render; use the single env's render_mode")
        self.metadata = {**self.metadata, "autoreset_mode": _autoreset_mode(autoreset_mode)}
        self.start_pool = None if start_pool is None else check_pool_size(start_pool)
        self.num_envs = int(num_envs)
        self.render_mode = None
        self.problem, self.reward_weights = parse_kwargs(
            self.core_cls.problem_cls, self.core_cls.reward_cls, kwargs
        )
        self._core = self.core_cls(self.problem, self.reward_weights, self.num_envs)
        self.single_action_space = action_space()
        self.single_observation_space = observation_space(
            self.problem, with_goal=issubclass(self.core_cls, DockingCore)
        )
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._state_keys = tuple(self._core.state_info())  # info given at reset as well as every step
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._row_rngs: list[np.random.Generator] | None = None  # with a start pool: one per row
        self._started = False

    @property
    def states(self) -> np.ndarray:
        """Current states (N, 6), SI units (a copy)."""
        return self._core.states.copy()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset every row; ``options`` may give ``initial_state`` (N, 6) (and ``goal`` (N, 3) for docking)."""
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = sorted(set(options) - set(self.reset_options))
        if unknown:
            raise ValueError(f"unknown reset option(s) {unknown}; valid ones are {list(self.reset_options)}")
        if self.start_pool is not None and (seed is not None or self._row_rngs is None):
            # SyncVectorEnv's seeding: sub-env i is reset with seed + i.
            seeds = (
                [seed + i for i in range(self.num_envs)]
                if seed is not None
                else [int(s) for s in self.np_random.integers(2**63 - 1, size=self.num_envs)]
            )
            self._row_rngs = [seeding.np_random(s)[0] for s in seeds]
        self._core.start(slice(None), *self._initial(np.arange(self.num_envs), options))
        self._autoreset[:] = False
        self._started = True
        return self._core.observe(), _batch(self._core.state_info())

    def step(self, actions: Any):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        actions = check_actions(actions, (self.num_envs, 3))
        actions, extra = self._filter(actions)
        reward, terminated, info, final = self._core.step(actions)
        if self.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP:
            out = self._restart_ended(terminated, info, extra, final)
        else:
            out = self._restart_flagged(reward, terminated, info, extra, final)
        return self._core.observe(), reward, terminated, np.zeros(self.num_envs, dtype=bool), out

    def _restart_flagged(self, reward, terminated, info, extra, final) -> dict[str, Any]:
        """NEXT_STEP: rows that ended on the previous call start over now, ignoring this step."""
        resets = self._autoreset
        if resets.any():
            rows = np.flatnonzero(resets)
            self._core.start(rows, *self._initial(rows, {}))
            reward[rows] = 0.0
            terminated[rows] = False
            info.update(self._core.state_info())  # the rows that reset report their new state
        out = _batch({key: info.pop(key) for key in self._state_keys})
        _add_masked(out, {**info, **extra}, ~resets)
        _add_masked(out, final, terminated)
        self._autoreset = terminated.copy()
        return out

    def _restart_ended(self, terminated, info, extra, final) -> dict[str, Any]:
        """SAME_STEP: rows that ended now start over now; their step info moves to ``final_info``."""
        state = {key: info.pop(key) for key in self._state_keys}
        if not terminated.any():
            out = _batch(state)
            _add_masked(out, {**info, **extra}, np.ones(self.num_envs, dtype=bool))
            return out
        rows = np.flatnonzero(terminated)
        final_info: dict[str, Any] = {}
        _add_masked(final_info, {**state, **info, **extra, **final}, terminated)
        final_obs = np.full(self.num_envs, None, dtype=object)
        for row, obs in zip(rows, self._core.observe()[rows], strict=True):
            final_obs[row] = obs
        self._core.start(rows, *self._initial(rows, {}))
        out = _batch(self._core.state_info())  # the rows that reset report their new state
        _add_masked(out, {**info, **extra}, ~terminated)
        out["final_obs"], out["_final_obs"] = final_obs, terminated.copy()
        out["final_info"], out["_final_info"] = final_info, terminated.copy()
        return out

    def _pool_draws(self, rows: np.ndarray) -> tuple[StartPool, np.ndarray]:
        """The pool and one index per row, each from that row's generator (a single env's draw)."""
        pool = start_pool(self.task, self.start_pool, self.problem)
        return pool, np.array([self._row_rngs[row].integers(len(pool)) for row in rows], dtype=np.int64)

    def _filter(self, actions: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        return actions, {}

    def _initial(self, rows: np.ndarray, options: dict[str, Any]) -> tuple[np.ndarray, ...]:
        raise NotImplementedError


class CWHRendezvousVectorEnv(_CWHVectorEnv):
    """``CWHRendezvous-v0`` with ``num_envs`` rows: same arguments, observations (N, 7), actions (N, 3)."""

    core_cls: ClassVar[type] = RendezvousCore
    reset_options: ClassVar[tuple[str, ...]] = ("initial_state",)
    task: ClassVar[str] = "rendezvous"

    def _initial(self, rows: np.ndarray, options: dict[str, Any]) -> tuple[np.ndarray]:
        if "initial_state" in options:
            return (check_states(options["initial_state"], len(rows)),)
        if self.start_pool is not None:
            pool, drawn = self._pool_draws(rows)
            return (pool.starts[drawn],)
        starts = sample_rendezvous_starts(self.np_random, len(rows), self.problem)
        return (np.asarray(starts, dtype=np.float64),)


class CWHDockKOZVectorEnv(_CWHVectorEnv):
    """``CWHDockKOZ-v1`` with ``num_envs`` rows: observations (N, 10), actions (N, 3).

    ``cbf_margin`` (metres, default ``None`` = off) applies the predictive CBF of
    :func:`cwh_envs.cbf.safe_actions` to the whole batch before stepping, the same pure function
    :class:`cwh_envs.wrappers.CBFSafetyFilter` applies to one env, and adds ``cbf_active``,
    ``cbf_infeasible`` and ``cbf_correction_norm`` to the step info.
    """

    core_cls: ClassVar[type] = DockingCore
    reset_options: ClassVar[tuple[str, ...]] = ("initial_state", "goal")
    task: ClassVar[str] = "docking"

    def __init__(
        self,
        num_envs: int = 1,
        render_mode: str | None = None,
        cbf_margin: float | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(num_envs, render_mode, **kwargs)
        self.cbf_margin = None if cbf_margin is None else check_margin(cbf_margin)

    @property
    def goals(self) -> np.ndarray:
        """Docking points (N, 3), m (a copy)."""
        return self._core.goals.copy()

    def _filter(self, actions: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        if self.cbf_margin is None:
            return actions, {}
        safe, result = filter_actions(
            actions, self._core.states, self.problem, self.cbf_margin, self._core.goals
        )
        info = {
            "cbf_active": np.asarray(result.active, dtype=bool),
            "cbf_infeasible": np.asarray(result.infeasible, dtype=bool),
            "cbf_correction_norm": np.asarray(result.correction_norm, dtype=np.float64),
        }
        if hasattr(result, "dropped"):  # several barriers: (N, 3) in cwh_envs.cbf_multi.BARRIERS order
            info["cbf_dropped"] = np.asarray(result.dropped, dtype=bool)
        return safe, info

    def _initial(self, rows: np.ndarray, options: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        num = len(rows)
        state = check_states(options["initial_state"], num) if "initial_state" in options else None
        goal = check_goals(options["goal"], self.problem, num) if "goal" in options else None
        if state is None or goal is None:
            if self.start_pool is None:
                sampled_states, sampled_goals = sample_docking_starts(self.np_random, num, self.problem)
            else:
                pool, drawn = self._pool_draws(rows)
                sampled_states, sampled_goals = pool.starts[drawn], pool.goals[drawn]
            state = np.asarray(sampled_states, dtype=np.float64) if state is None else state
            goal = np.asarray(sampled_goals, dtype=np.float64) if goal is None else goal
        return state, goal


def _batch(info: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Arrays every row has (fresh from the core on each call), with all-true masks."""
    out: dict[str, np.ndarray] = {}
    for key, value in info.items():
        out[key], out[f"_{key}"] = value, np.ones(value.shape[0], dtype=bool)
    return out


def _add_masked(out: dict[str, Any], info: dict[str, Any], mask: np.ndarray) -> None:
    """Add keys present in the rows of ``mask`` only (zero elsewhere); skip keys no row has."""
    if not mask.any():
        return
    for key, value in info.items():
        if isinstance(value, dict):
            out[key] = {}
            _add_masked(out[key], value, mask)
        else:
            rows = mask.reshape(-1, *(1,) * (value.ndim - 1))  # a per-row vector, e.g. cbf_dropped (N, 3)
            out[key] = np.where(rows, value, np.zeros((), dtype=value.dtype))
        out[f"_{key}"] = mask.copy()


def _autoreset_mode(value: Any) -> AutoresetMode:
    try:
        mode = AutoresetMode(value)
    except ValueError:
        mode = None
    if mode not in AUTORESET_MODES:
        raise ValueError(
            f"autoreset_mode must be AutoresetMode.NEXT_STEP or SAME_STEP (or their values "
            f"{[m.value for m in AUTORESET_MODES]}), got {value!r}"
        )
    return mode
