"""Stable-Baselines3 on the native vector envs: :class:`NativeVecEnv`, an SB3 ``VecEnv``.

    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from cwh_envs.sb3 import NativeVecEnv

    envs = NativeVecEnv("CWHDockKOZ-v1", 64, seed=0, cbf_margin=0.5, start_pool=65536)
    model = PPO("MlpPolicy", VecNormalize(VecMonitor(envs)), seed=0).learn(100_000)

It steps one native vector env (``gym.make_vec(..., vectorization_mode="vector_entry_point")``,
:mod:`cwh_envs.vector`) built in Gymnasium's same-step autoreset mode, which is what SB3 expects:
the step that ends an episode returns the next episode's first observation, ``dones[i]`` is true,
``infos[i]["terminal_observation"]`` holds the final observation and ``infos[i]`` the
end-of-episode info, and the reset info goes to ``reset_infos[i]``. ``infos[i]`` is exactly the
single env's info dict as ``DummyVecEnv`` returns it (``distance``, ``speed``, ``reward_terms``,
``cost`` and the filter's ``cbf_*`` for docking, ``terminal_distance``, ``is_success``, ... at the
end, ``TimeLimit.truncated``), rewards are float32 as there, and with ``start_pool`` the rows
follow ``make_vec_env``'s seeding (env ``i`` seeded ``seed + i``), so the same seeds and actions
give the same trajectories as ``make_vec_env(env_id, n_envs, seed=seed, env_kwargs=...)``
(tests/test_sb3_adapter.py). Without a pool the rows draw fresh starts in one batch from the
env's ``np_random``: the same distribution, other starts.

**Residual RL** (Johannink et al. 2019, Silver et al. 2018): :class:`ResidualVecEnv` flies the agent's
action ``a`` as ``clip(base(obs) + scale * a, -1, 1)``, a bounded correction on a base controller (the
closed-form law, say) that sees the raw observation the agent acted on; the filter (``cbf_margin``)
then acts on that sum, as it would on any action. :func:`residual_policy` is the same composition
for flying a trained correction (``cwh_envs.rollout.fly``).

    envs = ResidualVecEnv(VecMonitor(NativeVecEnv("CWHDockKOZ-v1", 64, seed=0)), MinEnergyFeedback(problem), 0.2)
    model = PPO("MlpPolicy", VecNormalize(envs), seed=0).learn(1_000_000)

**Fine-tuning a cloned policy**: :class:`FixedStatistics` holds VecNormalize's observation statistics
where they were set (the clone's), so that the policy keeps seeing the inputs it was fitted on while
reward statistics keep updating: ``normalizer.obs_rms = FixedStatistics.of(mean, var, count)``.

Importing this module imports stable_baselines3; ``import cwh_envs`` does not.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode

try:
    from stable_baselines3.common.running_mean_std import RunningMeanStd
    from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
except ModuleNotFoundError as err:
    raise ModuleNotFoundError(
        "cwh_envs.sb3 needs stable-baselines3, which is not installed: pip install 'cwh-autoresearch[sb3]'",
        name=err.name,
    ) from err

# Per-row attributes of the single envs, served from the native env's batch.
_ROW_ATTRIBUTES = {"state": "states", "goal": "goals"}
_SET_BY_ADAPTER = ("autoreset_mode", "vectorization_mode", "num_envs")


class NativeVecEnv(VecEnv):
    """An SB3 ``VecEnv`` of ``num_envs`` rows of one native vector env of ``env_id``.

    ``env_kwargs`` go to the env (every problem field, the reward weights, ``start_pool``, and
    ``cbf_margin`` for docking: the CBF filter on the batch). ``seed`` seeds the next reset, as
    ``make_vec_env`` does. ``info_keys`` keeps only those keys of the env's infos (SB3's own,
    ``terminal_observation`` and ``TimeLimit.truncated``, always stay): converting every key to
    per-row dicts costs several times the native step itself at 1024 rows, and SB3's algorithms
    read only ``is_success`` (``info_keys=("is_success",)``). ``get_attr`` serves the native env's
    attributes to every row (``state`` and ``goal`` per row); ``set_attr`` and ``env_method`` act
    on the one native env, so they take every row or none; nothing renders (render a single env).
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        seed: int | None = None,
        info_keys: Iterable[str] | None = None,
        **env_kwargs: Any,
    ) -> None:
        taken = sorted(set(env_kwargs) & set(_SET_BY_ADAPTER))
        if taken:
            raise TypeError(f"NativeVecEnv sets {taken} itself")
        if isinstance(info_keys, str):
            raise TypeError("info_keys must be an iterable of info key names, not one string")
        self.info_keys = None if info_keys is None else frozenset(info_keys)
        self.env = gym.make_vec(
            env_id,
            num_envs=num_envs,
            vectorization_mode="vector_entry_point",
            autoreset_mode=AutoresetMode.SAME_STEP,
            **env_kwargs,
        )
        super().__init__(self.env.num_envs, self.env.single_observation_space, self.env.single_action_space)
        self._actions: np.ndarray | None = None
        if seed is not None:
            self.seed(seed)

    def reset(self) -> np.ndarray:
        seeds = self._seeds
        if any(s is not None for s in seeds) and seeds != [seeds[0] + i for i in range(self.num_envs)]:
            raise ValueError(f"NativeVecEnv seeds row i with seed + i (VecEnv.seed); got seeds {seeds}")
        obs, info = self.env.reset(seed=seeds[0], options=_stack_options(self._options))
        self.reset_infos = _rows(info, self.num_envs, self.info_keys)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        if self._actions is None:
            raise RuntimeError("step_wait() without step_async()")
        obs, reward, terminated, truncated, info = self.env.step(self._actions)
        self._actions = None
        dones = terminated | truncated
        infos = _rows(info, self.num_envs, self.info_keys)
        if dones.any():
            final = _rows(info["final_info"], self.num_envs, self.info_keys)
            for i in np.flatnonzero(dones).tolist():
                self.reset_infos[i] = infos[i]  # the new episode's reset info
                infos[i] = final[i]
                infos[i]["terminal_observation"] = info["final_obs"][i]
        for row, cut, ended in zip(infos, truncated.tolist(), terminated.tolist(), strict=True):
            row["TimeLimit.truncated"] = cut and not ended
        return obs, reward.astype(np.float32), dones, infos

    def close(self) -> None:
        self.env.close()

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        rows = self._rows(indices)
        if attr_name in _ROW_ATTRIBUTES and hasattr(self.env.unwrapped, _ROW_ATTRIBUTES[attr_name]):
            batch = getattr(self.env.unwrapped, _ROW_ATTRIBUTES[attr_name])
            return [batch[i] for i in rows]
        value = getattr(self.env.unwrapped, attr_name)
        return [value for _ in rows]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        self._every_row(indices, "set_attr")
        setattr(self.env.unwrapped, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        """Calls the method once on the native env; its result stands for every row."""
        self._every_row(indices, "env_method")
        result = getattr(self.env.unwrapped, method_name)(*method_args, **method_kwargs)
        return [result] * self.num_envs

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices=None) -> list[bool]:
        return [False] * len(self._rows(indices))  # a native vector env holds no gym.Wrapper

    def get_images(self) -> list[None]:
        return [None] * self.num_envs  # render_mode is None: SB3's render() warns and returns None

    def _rows(self, indices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        rows = [int(indices)] if isinstance(indices, int | np.integer) else [int(i) for i in indices]
        if any(not 0 <= i < self.num_envs for i in rows):
            raise IndexError(f"env indices {rows} out of range for {self.num_envs} envs")
        return rows

    def _every_row(self, indices, what: str) -> None:
        if indices is not None and sorted(self._rows(indices)) != list(range(self.num_envs)):
            raise ValueError(f"{what}: one native env holds every row, so indices must be None (all rows)")


def check_residual_scale(scale) -> float:
    """The correction's bound per axis, a fraction of u_max in (0, 2] (2: it can undo any base action)."""
    if not (isinstance(scale, int | float) and not isinstance(scale, bool) and 0 < scale <= 2):
        raise ValueError(f"scale must be a number in (0, 2] (a fraction of u_max), got {scale!r}")
    return float(scale)


def residual_policy(base: Callable, correction: Callable, scale: float) -> Callable:
    """The policy on observations that flies ``clip(base(obs) + scale * correction(obs), -1, 1)``."""
    scale = check_residual_scale(scale)

    def act(obs: np.ndarray) -> np.ndarray:
        return np.clip(base(obs) + scale * np.clip(correction(obs), -1.0, 1.0), -1.0, 1.0)

    return act


class ResidualVecEnv(VecEnvWrapper):
    """The agent learns a correction on ``base`` (a policy on observations returning normalised
    actions): its action ``a`` (clipped to [-1, 1]) is flown as ``clip(base(obs) + scale * a, -1, 1)``,
    ``obs`` the raw observation the agent acted on (module docstring). Put it below ``VecNormalize``,
    so that the base sees observations in metres."""

    def __init__(self, venv: VecEnv, base: Callable, scale: float) -> None:
        super().__init__(venv)
        self.base, self.scale = base, check_residual_scale(scale)
        self._obs: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        self._obs = self.venv.reset()
        return self._obs

    def step_async(self, actions: np.ndarray) -> None:
        if self._obs is None:
            raise RuntimeError("step_async() before reset(): the base needs the observation")
        correction = np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0)
        flown = np.clip(self.base(self._obs) + self.scale * correction, -1.0, 1.0)
        self.venv.step_async(flown)

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        self._obs = obs  # after an episode's end, the next episode's first observation (SB3's autoreset)
        return obs, rewards, dones, infos


class FixedStatistics(RunningMeanStd):
    """Observation statistics that VecNormalize does not move: ``update`` is a no-op (module docstring).
    VecNormalize updates its ``obs_rms`` on every training step; a cloned actor fitted on inputs
    normalised by fixed statistics would otherwise see its inputs drift under it."""

    @classmethod
    def of(cls, mean: np.ndarray, var: np.ndarray, count: float) -> FixedStatistics:
        stats = cls(shape=np.shape(mean))
        stats.mean, stats.var, stats.count = np.asarray(mean, np.float64), np.asarray(var, np.float64), count
        return stats

    def update(self, arr: np.ndarray) -> None:  # the statistics stay where they were set
        return None


def _rows(info: dict[str, Any], n: int, keys: frozenset[str] | None = None) -> list[dict[str, Any]]:
    """A vector env's info (arrays with ``_key`` masks) as n single-env info dicts of Python scalars,
    with only ``keys`` (top level) when given."""
    rows: list[dict[str, Any]] = [{} for _ in range(n)]
    for key, value in info.items():
        if (
            key.startswith("_")
            or key in ("final_obs", "final_info")
            or (keys is not None and key not in keys)
        ):
            continue
        mask = info[f"_{key}"]
        values = _rows(value, n) if isinstance(value, dict) else value.tolist()
        if mask.all():  # every step but the last: the fastest loop (measured)
            for row, item in zip(rows, values, strict=True):
                row[key] = item
        else:
            for i in np.flatnonzero(mask).tolist():
                rows[i][key] = values[i]
    return rows


def _stack_options(options: Iterable[dict[str, Any]]) -> dict[str, np.ndarray] | None:
    """SB3's per-env reset options as the native env's batch options (every row resets together)."""
    options = list(options)
    keys = {frozenset(o) for o in options}
    if keys == {frozenset()}:
        return None
    if len(keys) != 1:
        raise ValueError(
            "NativeVecEnv resets every row together: give every env the same option keys "
            "(set_options(dict) or a list of dicts with the same keys)"
        )
    return {key: np.stack([np.asarray(o[key]) for o in options]) for key in options[0]}
