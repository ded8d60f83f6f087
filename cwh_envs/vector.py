"""Native batched vector envs: ``gym.make_vec(id, num_envs=N)`` steps N episodes as numpy arrays.

They run the same :mod:`cwh_envs.core` as the single envs, so a row behaves exactly like a single
env given the same start and actions. Autoreset is Gymnasium's default next-step mode: the step
that ends an episode returns its final observation with ``terminated=True``; the next call
ignores that row's action and returns the new episode's first observation with reward 0,
``terminated=truncated=False`` and the reset info. Infos follow the vector convention, one array
per key with a boolean ``_key`` mask of the rows that have it, exactly as ``SyncVectorEnv`` of the
single envs would build them (a key no row has is absent).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from cwh_envs.core import (
    DockingCore,
    RendezvousCore,
    action_space,
    check_actions,
    check_goals,
    check_margin,
    check_states,
    filter_actions,
    observation_space,
    parse_kwargs,
)
from cwh_envs.sampling import sample_docking_starts, sample_rendezvous_starts


class _CWHVectorEnv(VectorEnv):
    metadata: ClassVar[dict[str, Any]] = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}
    core_cls: ClassVar[type[RendezvousCore]]
    reset_options: ClassVar[tuple[str, ...]]

    def __init__(self, num_envs: int = 1, render_mode: str | None = None, **kwargs: Any) -> None:
        if not (isinstance(num_envs, int | np.integer) and num_envs >= 1):
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        if render_mode is not None:
            raise ValueError("the native vector env does not render; use the single env's render_mode")
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
        self._core.start(slice(None), *self._initial(self.num_envs, options))
        self._autoreset[:] = False
        self._started = True
        return self._core.observe(), _batch(self._core.state_info())

    def step(self, actions: Any):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        actions = check_actions(actions, (self.num_envs, 3))
        actions, extra = self._filter(actions)
        reward, terminated, info, final = self._core.step(actions)
        resets = self._autoreset
        if resets.any():
            rows = np.flatnonzero(resets)
            self._core.start(rows, *self._initial(rows.size, {}))
            reward[rows] = 0.0
            terminated[rows] = False
            info.update(self._core.state_info())  # the rows that reset report their new state
        out = _batch({key: info.pop(key) for key in self._state_keys})
        _add_masked(out, {**info, **extra}, ~resets)
        _add_masked(out, final, terminated)
        self._autoreset = terminated.copy()
        return self._core.observe(), reward, terminated, np.zeros(self.num_envs, dtype=bool), out

    def _filter(self, actions: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        return actions, {}

    def _initial(self, num: int, options: dict[str, Any]) -> tuple[np.ndarray, ...]:
        raise NotImplementedError


class CWHRendezvousVectorEnv(_CWHVectorEnv):
    """``CWHRendezvous-v0`` with ``num_envs`` rows: same arguments, observations (N, 7), actions (N, 3)."""

    core_cls: ClassVar[type] = RendezvousCore
    reset_options: ClassVar[tuple[str, ...]] = ("initial_state",)

    def _initial(self, num: int, options: dict[str, Any]) -> tuple[np.ndarray]:
        if "initial_state" in options:
            return (check_states(options["initial_state"], num),)
        return (np.asarray(sample_rendezvous_starts(self.np_random, num, self.problem), dtype=np.float64),)


class CWHDockKOZVectorEnv(_CWHVectorEnv):
    """``CWHDockKOZ-v0`` with ``num_envs`` rows: observations (N, 10), actions (N, 3).

    ``cbf_margin`` (metres, default ``None`` = off) applies the predictive CBF of
    :func:`cwh_envs.cbf.safe_actions` to the whole batch before stepping, the same pure function
    :class:`cwh_envs.wrappers.CBFSafetyFilter` applies to one env, and adds ``cbf_active``,
    ``cbf_infeasible`` and ``cbf_correction_norm`` to the step info.
    """

    core_cls: ClassVar[type] = DockingCore
    reset_options: ClassVar[tuple[str, ...]] = ("initial_state", "goal")

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
        safe, result = filter_actions(actions, self._core.states, self.problem, self.cbf_margin)
        return safe, {
            "cbf_active": np.asarray(result.active, dtype=bool),
            "cbf_infeasible": np.asarray(result.infeasible, dtype=bool),
            "cbf_correction_norm": np.asarray(result.correction_norm, dtype=np.float64),
        }

    def _initial(self, num: int, options: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        state = check_states(options["initial_state"], num) if "initial_state" in options else None
        goal = check_goals(options["goal"], self.problem, num) if "goal" in options else None
        if state is None or goal is None:
            sampled_states, sampled_goals = sample_docking_starts(self.np_random, num, self.problem)
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
            out[key] = np.where(mask, value, np.zeros((), dtype=value.dtype))
        out[f"_{key}"] = mask.copy()
