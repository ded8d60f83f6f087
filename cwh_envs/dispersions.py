"""Monte Carlo dispersions of the plant and the navigation, per episode: the way GNC engineers judge
a guidance law off the nominal model. A wrapper, off unless a dispersion is given.

Each episode draws, from a generator seeded by the episode's ``reset(seed=...)``:

| Dispersion                 | Argument (a standard deviation) | Effect each step                                   |
|----------------------------|----------------------------------|----------------------------------------------------|
| thrust magnitude error     | ``thrust_scale``, fraction       | the commanded thrust is scaled by ``1 + e``        |
| thrust misalignment        | ``misalignment_deg``, degrees    | and rotated about a random axis by that angle      |
| mass error                 | ``mass``, fraction               | the acceleration is divided by ``1 + e``           |
| navigation noise           | ``nav_position`` m, ``nav_velocity`` m/s | added to the observed ``r`` and ``v`` (fresh each step) |

The plant errors are applied to the normalised action before the env clips it to its box: a
thrust error beyond full throttle saturates, as a real thruster would. The dispersions come from a
generator of their own, seeded by ``reset(seed=...)`` together with the env (nothing is drawn from
the env's stream), so a dispersed env draws the same starts as the nominal one, and the same
dispersions for the same seed.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from cwh_envs.core import check_actions

DISPERSION_STREAM = 0xD15  # the second word of the dispersions' seed: a stream apart from the env's


class Dispersions(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Per-episode plant dispersions and per-step navigation noise (module docstring).

    For either env. ``info["dispersion"]`` at reset holds the episode's draw: ``thrust_scale``,
    ``misalignment_deg``, ``mass_scale``.
    """

    def __init__(
        self,
        env: gym.Env,
        *,
        thrust_scale: float = 0.0,
        misalignment_deg: float = 0.0,
        mass: float = 0.0,
        nav_position: float = 0.0,
        nav_velocity: float = 0.0,
    ) -> None:
        spreads = {
            "thrust_scale": thrust_scale,
            "misalignment_deg": misalignment_deg,
            "mass": mass,
            "nav_position": nav_position,
            "nav_velocity": nav_velocity,
        }
        for name, value in spreads.items():
            if not (isinstance(value, int | float) and not isinstance(value, bool) and 0 <= value < np.inf):
                raise ValueError(f"{name} must be a finite standard deviation >= 0, got {value!r}")
        if mass >= 0.5 or thrust_scale >= 0.5:
            raise ValueError(
                "thrust_scale and mass must stay below 0.5: a draw could reverse or stop the thrust"
            )
        gym.utils.RecordConstructorArgs.__init__(self, **spreads)
        gym.Wrapper.__init__(self, env)
        self.spreads = spreads
        self._rng: np.random.Generator | None = None
        self._gain = np.eye(3)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        if seed is not None:  # seeded by the same seed as the env, on a stream of its own
            self._rng = np.random.default_rng([seed, DISPERSION_STREAM])
        elif self._rng is None:  # never seeded: neither is the env
            self._rng = np.random.default_rng()
        scale = 1.0 + self._rng.normal(0.0, self.spreads["thrust_scale"])
        mass_scale = 1.0 + self._rng.normal(0.0, self.spreads["mass"])
        angle = self._rng.normal(0.0, self.spreads["misalignment_deg"])
        axis = self._rng.normal(size=3)
        self._gain = scale / mass_scale * _rotation(axis / np.linalg.norm(axis), np.radians(angle))
        info["dispersion"] = {"thrust_scale": scale, "misalignment_deg": abs(angle), "mass_scale": mass_scale}
        return self._navigate(obs), info

    def step(self, action: Any):
        applied = self._gain @ check_actions(action, (3,))
        obs, reward, terminated, truncated, info = self.env.step(applied)
        return self._navigate(obs), reward, terminated, truncated, info

    def _navigate(self, obs: np.ndarray) -> np.ndarray:
        noisy = np.array(obs, copy=True)
        noisy[0:3] += self._rng.normal(0.0, self.spreads["nav_position"], 3)
        noisy[3:6] += self._rng.normal(0.0, self.spreads["nav_velocity"], 3)
        return noisy.astype(obs.dtype)


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' rotation by ``angle`` (radians) about the unit ``axis``."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * k @ k
