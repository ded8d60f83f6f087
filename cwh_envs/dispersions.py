"""Monte Carlo dispersions of the plant and the navigation, per episode: the way GNC engineers judge
a guidance law off the nominal model. Off unless a dispersion is given, in three places that draw
alike: the :class:`Dispersions` wrapper, the envs' ``dispersions=`` option
(``gym.make("CWHDockKOZ-v1", dispersions={...})``) and ``cwh_envs.rollout.fly(dispersions=...)``.

Each episode draws, from a generator seeded by the episode's ``reset(seed=...)``:

| Dispersion                 | Argument (a standard deviation) | Effect each step                                   |
|----------------------------|----------------------------------|----------------------------------------------------|
| thrust magnitude error     | ``thrust_scale``, fraction       | the commanded thrust is scaled by ``1 + e``        |
| thrust misalignment        | ``misalignment_deg``, degrees    | and rotated about a random axis by that angle      |
| mass error                 | ``mass``, fraction               | the acceleration is divided by ``1 + e``           |
| navigation noise           | ``nav_position`` m, ``nav_velocity`` m/s | added to the observed ``r`` and ``v`` (fresh each step) |

An episode seeded ``s`` draws from ``numpy.random.default_rng([s, DISPERSION_STREAM])``, in this
order: the thrust scale, the mass scale, the misalignment angle, its axis (3), then the navigation
noise of all H + 1 observations (position (H + 1, 3), then velocity (H + 1, 3)). So the wrapper, the
env option and ``fly`` (start ``i`` seeded ``dispersion_seed + i``) fly the same dispersions.

**What sees what.** The policy, the CBF filter (:class:`cwh_envs.CBFSafetyFilter`, ``fly``'s
``cbf_margin``) and MPC act on the navigation estimate, the true state plus that step's noise, as
flight software's run-time assurance does; the env scores the true state. The estimate is
``navigation_state`` (float64) on the env and on this wrapper. The filter fed the true state instead
(``CBFSafetyFilter(..., sees="truth")``, ``fly(..., filter_sees="truth")``) is kept for comparison:
it flatters every dispersed row.

The plant errors are applied to the normalised action before the env clips it to its box: a
thrust error beyond full throttle saturates, as a real thruster would. The dispersions come from a
generator of their own, seeded by ``reset(seed=...)`` together with the env (nothing is drawn from
the env's stream), so a dispersed env draws the same starts as the nominal one, and the same
dispersions for the same seed.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np

from cwh_envs.actions import check_actions

DISPERSION_STREAM = 0xD15  # the second word of the dispersions' seed: a stream apart from the env's
FILTER_SEES = ("estimate", "truth")  # what a CBF filter under dispersions acts on (module docstring)
SPREADS = ("thrust_scale", "misalignment_deg", "mass", "nav_position", "nav_velocity")


def check_spreads(spreads: dict[str, Any]) -> dict[str, float]:
    """The five standard deviations (missing ones 0), validated; an unknown name is an error."""
    unknown = sorted(set(spreads) - set(SPREADS))
    if unknown:
        raise ValueError(f"unknown dispersion(s) {unknown}; valid ones are {list(SPREADS)}")
    out = {name: spreads.get(name, 0.0) for name in SPREADS}
    for name, value in out.items():
        if not (isinstance(value, int | float) and not isinstance(value, bool) and 0 <= value < np.inf):
            raise ValueError(f"{name} must be a finite standard deviation >= 0, got {value!r}")
    if out["mass"] >= 0.5 or out["thrust_scale"] >= 0.5:
        raise ValueError("thrust_scale and mass must stay below 0.5: a draw could reverse or stop the thrust")
    return {name: float(value) for name, value in out.items()}


class EpisodeDraw(NamedTuple):
    """One episode's dispersions: ``gain`` (3, 3) applied to each normalised action, ``nav`` (H + 1, 6)
    added to each observation's ``[r, v]``, and ``info`` (the draw, as ``info["dispersion"]``)."""

    gain: np.ndarray
    nav: np.ndarray
    info: dict[str, float]


def episode_rng(seed: int) -> np.random.Generator:
    return np.random.default_rng([seed, DISPERSION_STREAM])


def draw_episode(spreads: dict[str, float], rng: np.random.Generator, horizon: int) -> EpisodeDraw:
    scale = 1.0 + rng.normal(0.0, spreads["thrust_scale"])
    mass_scale = 1.0 + rng.normal(0.0, spreads["mass"])
    angle = rng.normal(0.0, spreads["misalignment_deg"])
    axis = rng.normal(size=3)
    nav = np.concatenate(
        [
            rng.normal(0.0, spreads["nav_position"], (horizon + 1, 3)),
            rng.normal(0.0, spreads["nav_velocity"], (horizon + 1, 3)),
        ],
        axis=1,
    )
    gain = scale / mass_scale * _rotation(axis / np.linalg.norm(axis), np.radians(angle))
    info = {"thrust_scale": scale, "misalignment_deg": abs(angle), "mass_scale": mass_scale}
    return EpisodeDraw(gain, nav, info)


def noisy(obs: np.ndarray, nav: np.ndarray) -> np.ndarray:
    """``obs`` (..., D) with ``nav`` (..., 6) added to its ``[r, v]`` columns, in obs's dtype."""
    out = np.array(obs, dtype=np.float64, copy=True)
    out[..., :6] += nav
    return out.astype(np.asarray(obs).dtype)


class EpisodeDispersions:
    """What an env or a wrapper keeps: the spreads and the current episode's draw."""

    def __init__(self, spreads: dict[str, Any], horizon: int) -> None:
        self.spreads = check_spreads(spreads)
        self.horizon = horizon
        self._rng: np.random.Generator | None = None
        self.draw: EpisodeDraw | None = None

    def reset(self, seed: int | None) -> dict[str, float]:
        """Draw the next episode: from ``seed``'s stream when seeded, else the stream goes on."""
        if seed is not None:
            self._rng = episode_rng(seed)
        elif self._rng is None:  # never seeded: neither is the env
            self._rng = np.random.default_rng()
        self.draw = draw_episode(self.spreads, self._rng, self.horizon)
        return dict(self.draw.info)

    def plant(self, action: np.ndarray) -> np.ndarray:
        return np.einsum("ij,j->i", self.draw.gain, action)  # as fly's batched einsum, to the bit

    def observe(self, obs: np.ndarray, step: int) -> np.ndarray:
        return noisy(obs, self.draw.nav[step])

    def estimate(self, state: np.ndarray, step: int) -> np.ndarray:
        """The navigation estimate (6,) of the true ``state`` at ``step``, float64: what is observed."""
        return np.asarray(state, dtype=np.float64) + self.draw.nav[step]


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
        self._episode = EpisodeDispersions(spreads, env.unwrapped.problem.horizon)
        gym.utils.RecordConstructorArgs.__init__(self, **spreads)
        gym.Wrapper.__init__(self, env)
        self.spreads = self._episode.spreads
        self._step = 0

    @property
    def navigation_state(self) -> np.ndarray:
        """The state as navigation estimates it this step (6,), m and m/s: what the observation shows,
        in float64. A CBF filter on top acts on it (module docstring)."""
        inner = self.env.get_wrapper_attr("navigation_state")
        return self._episode.estimate(inner, min(self._step, self._episode.horizon))

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        info["dispersion"] = self._episode.reset(seed)
        self._step = 0
        return self._episode.observe(obs, 0), info

    def step(self, action: Any):
        obs, reward, terminated, truncated, info = self.env.step(
            self._episode.plant(check_actions(action, (3,)))
        )
        self._step += 1
        return (
            self._episode.observe(obs, min(self._step, self._episode.horizon)),
            reward,
            terminated,
            truncated,
            info,
        )


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' rotation by ``angle`` (radians) about the unit ``axis``."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * k @ k
