"""The batched numpy core behind both the single and the vector envs.

One :class:`RendezvousCore` / :class:`DockingCore` holds ``N`` episodes as arrays and owns the
step, the reward and the info. The single env is the ``N = 1`` case, so the two can only differ
in packaging (Python scalars versus arrays with ``_key`` masks).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from cwh_envs import dynamics
from cwh_envs.actions import check_actions, real_array
from cwh_envs.cbf import safe_actions
from cwh_envs.cbf_multi import safe_actions_multi
from cwh_envs.constraints import (
    CONE_TOLERANCE,
    SPEED_TOLERANCE,
    cone_depth,
    cone_terms,
    path_constrained,
    speed_margin,
)
from cwh_envs.dispersions import EpisodeDispersions
from cwh_envs.observations import docking_observation, rendezvous_observation
from cwh_envs.problems import DockingProblem, RendezvousProblem
from cwh_envs.robust_cbf import robust_safe_actions

# Admissible user-given states (reset options): far beyond the sampled starts, yet small enough
# that the observation bounds below stay finite. CWH linearisation is meaningless past this anyway.
MAX_POSITION = 1.0e4  # m per axis, initial state and docking goal
MAX_SPEED = 10.0  # m/s per axis, initial state


@dataclass(frozen=True)
class RendezvousReward:
    """Reward weights (each a keyword argument of the env); see the env docstring for the formula."""

    progress_weight: float = 0.1  # per metre of distance closed toward the target
    effort_weight: float = 0.01  # per unit of squared normalised thrust ||a||^2 (at most 3)
    terminal_weight: float = 1.0  # times d_H / success_distance + v_H / success_speed, at k = H
    success_bonus: float = 10.0  # added at k = H when the episode is a success

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if not (isinstance(value, int | float | np.number) and np.isfinite(value) and value >= 0):
                raise ValueError(f"{field.name} must be a non-negative finite number, got {value!r}")


@dataclass(frozen=True)
class DockingReward(RendezvousReward):
    # The 1 m success radius makes d_H / success_distance 25 times larger than rendezvous's 25 m.
    terminal_weight: float = 0.1
    koz_weight: float = 1.0  # per step that ends inside the keep-out sphere
    speed_weight: float = 1.0  # per step that ends above the speed limit (when the problem has one)
    cone_weight: float = 1.0  # per step that ends outside the approach cone (when the problem has one)


def parse_kwargs(problem_cls: type, reward_cls: type, kwargs: dict[str, Any]) -> tuple[Any, Any]:
    """Split env keyword arguments into the problem dataclass and the reward weights."""
    problem_names = {f.name for f in dataclasses.fields(problem_cls)}
    reward_names = {f.name for f in dataclasses.fields(reward_cls)}
    unknown = sorted(set(kwargs) - problem_names - reward_names)
    if unknown:
        raise TypeError(
            f"unexpected keyword argument(s) {unknown}; valid ones are the {problem_cls.__name__} fields "
            f"{sorted(problem_names)} and the reward weights {sorted(reward_names)}"
        )
    problem = problem_cls(**{k: v for k, v in kwargs.items() if k in problem_names})
    reward = reward_cls(**{k: v for k, v in kwargs.items() if k in reward_names})
    return problem, reward


def action_space() -> spaces.Box:
    """Thrust as a fraction of ``u_max`` per axis."""
    return spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)


def state_envelope(problem) -> np.ndarray:
    """Per-component bound on |x_k| for k <= H, any admissible start and any admissible thrust.

    A rigorous elementwise bound, |x_k| <= |A^k| |x_0| + sum_{j<k} |A^j B| u_max, so an
    observation can never leave the observation space whatever the policy does.
    """
    a, b = problem.matrices()
    start = np.r_[np.full(3, MAX_POSITION), np.full(3, MAX_SPEED)]
    thrust = np.full(3, problem.u_max)
    power, forced, envelope = np.eye(6), np.zeros(6), start.copy()
    for _ in range(problem.horizon):
        forced = forced + np.abs(power @ b) @ thrust
        power = a @ power
        envelope = np.maximum(envelope, np.abs(power) @ start + forced)
    return envelope


def observation_space(problem, with_goal: bool) -> spaces.Box:
    """[r, v, (g,) tau] with finite bounds from :func:`state_envelope` (rounded up, float32-safe)."""
    state = state_envelope(problem) * 1.01 + 1.0
    goal = np.full(3, MAX_POSITION) if with_goal else np.empty(0)
    high = np.r_[state, goal, 1.0].astype(np.float32)
    low = -high
    low[-1] = 0.0
    return spaces.Box(low, high, dtype=np.float32)


def check_states(states: Any, batch: int | None = None) -> np.ndarray:
    """Validate user-given initial states, shape (6,) or, for a batch, (batch, 6)."""
    name = "initial_state"
    x = _finite_array(states, name, (6,) if batch is None else (batch, 6))
    x2 = x.reshape(-1, 6)
    if np.any(np.abs(x2[:, :3]) > MAX_POSITION) or np.any(np.abs(x2[:, 3:]) > MAX_SPEED):
        raise ValueError(
            f"{name} must have |position| <= {MAX_POSITION:g} m and |velocity| <= {MAX_SPEED:g} m/s per axis"
        )
    return x


def check_goals(goals: Any, problem: DockingProblem, batch: int | None = None) -> np.ndarray:
    """Validate docking goals, shape (3,) or (batch, 3), outside the keep-out sphere plus the margin."""
    g = _finite_array(goals, "goal", (3,) if batch is None else (batch, 3))
    g2 = g.reshape(-1, 3)
    standoff = problem.koz_radius + problem.margin
    if np.any(np.linalg.norm(g2, axis=1) <= standoff):
        raise ValueError(
            f"goal must lie strictly outside the keep-out radius plus margin ({problem.koz_radius:g} + "
            f"{problem.margin:g} m) from the origin"
        )
    if np.any(np.abs(g2) > MAX_POSITION):
        raise ValueError(f"goal must have |position| <= {MAX_POSITION:g} m per axis")
    return g


def filter_actions(
    actions: np.ndarray,
    states: np.ndarray,
    problem: DockingProblem,
    margin: float,
    goals: np.ndarray,
    bounds=None,
    navigation_sigma=None,
    stop_line: bool = False,
):
    """Apply the predictive CBF to normalised actions; returns (safe normalised actions, result).

    The keep-out alone (the paper's problem) goes through :func:`cwh_envs.cbf.safe_actions`; with a
    speed limit or an approach cone every barrier goes into one QP,
    :func:`cwh_envs.cbf_multi.safe_actions_multi`, whose result also says what it ``dropped``.
    With ``bounds`` (:class:`cwh_envs.robust_cbf.ErrorBounds`) the robust filter,
    :func:`cwh_envs.robust_cbf.robust_safe_actions`, answers instead (its result adds ``margin_scale``),
    its navigation margins per row from ``navigation_sigma`` (N, 2) where given, with its stop line
    where ``stop_line``.
    """
    if bounds is not None:
        result = robust_safe_actions(
            actions * problem.u_max, states, goals, problem, bounds, margin, navigation_sigma, stop_line
        )
        return np.clip(np.asarray(result.u) / problem.u_max, -1.0, 1.0), result
    a, b = problem.matrices()
    common = dict(koz_radius=problem.koz_radius, margin=margin, u_max=problem.u_max)
    if not path_constrained(problem):
        result = safe_actions(actions * problem.u_max, states, a, b, **common)
    else:
        result = safe_actions_multi(
            actions * problem.u_max,
            states,
            goals,
            a,
            b,
            speed_limit=problem.speed_limit,
            approach_cone=problem.approach_cone,
            **common,
        )
    # Float rounding of u / u_max may land a hair outside the box the env clips to.
    return np.clip(np.asarray(result.u) / problem.u_max, -1.0, 1.0), result


def check_margin(margin: Any) -> float:
    numeric = isinstance(margin, int | float | np.number) and not isinstance(margin, bool | np.bool_)
    if not (numeric and np.isfinite(margin) and margin >= 0):
        raise ValueError(f"CBF margin must be a non-negative finite number of metres, got {margin!r}")
    return float(margin)


def _finite_array(value: Any, name: str, shape: tuple[int, ...]) -> np.ndarray:
    x = real_array(value, name, shape)
    if x.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} must be finite")
    return x


class RendezvousCore:
    """N rendezvous episodes stepped together: states (N, 6) in SI units, target at the origin."""

    problem_cls: ClassVar[type] = RendezvousProblem
    reward_cls: ClassVar[type] = RendezvousReward

    def __init__(self, problem: RendezvousProblem, reward: RendezvousReward, num_envs: int) -> None:
        self.problem, self.reward, self.num_envs = problem, reward, num_envs
        self.a, self.b = problem.matrices()
        self.states = np.zeros((num_envs, 6))
        self.goals = np.zeros((num_envs, 3))  # the target; the docking point in DockingCore
        self.steps = np.zeros(num_envs, dtype=np.int64)

    def start(self, rows: Any, states: np.ndarray, goals: np.ndarray | None = None) -> None:
        """Begin new episodes in ``rows`` (an index, mask or slice) from the given states."""
        self.states[rows] = states
        if goals is not None:
            self.goals[rows] = goals
        self.steps[rows] = 0

    def observe(self) -> np.ndarray:
        return rendezvous_observation(self.states, self.steps, self.problem.horizon)

    def state_info(self) -> dict[str, np.ndarray]:
        """Info that depends on the current state only (given at reset and at every step)."""
        return {
            "distance": np.linalg.norm(self.states[:, :3] - self.goals, axis=1),
            "speed": np.linalg.norm(self.states[:, 3:], axis=1),
        }

    def step(self, actions: np.ndarray):
        """Advance every row by one step with normalised actions already in the box.

        Returns (reward, terminated, step_info, final_info); final_info is meaningful only in
        the terminated rows and step_info["reward_terms"] sums to the reward.
        """
        previous = np.linalg.norm(self.states[:, :3] - self.goals, axis=1)
        self.states = dynamics.step(self.states, actions * self.problem.u_max, self.a, self.b)
        self.steps += 1
        terminated = self.steps >= self.problem.horizon
        info = self.state_info()
        extra = self._accumulate(info)
        final = self._final_info(info)
        w = self.reward
        terminal = w.success_bonus * final["is_success"] - w.terminal_weight * (
            info["distance"] / self.problem.success_distance + info["speed"] / self.problem.success_speed
        )
        terms = {
            "progress": w.progress_weight * (previous - info["distance"]),
            "effort": -w.effort_weight * np.einsum("ij,ij->i", actions, actions),
            "terminal": np.where(terminated, terminal, 0.0),
            **self._extra_terms(info, extra),
        }
        reward = sum(terms.values())
        return reward, terminated, {**info, **extra, "reward_terms": terms}, final

    def _accumulate(self, info: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Update per-episode accumulators; returns step-only info (not given at reset)."""
        return {}

    def _extra_terms(
        self, info: dict[str, np.ndarray], extra: dict[str, np.ndarray]
    ) -> dict[str, np.ndarray]:
        """Reward terms beyond the shared ones, from the step's info and _accumulate's costs."""
        return {}

    def _final_info(self, info: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {
            "terminal_distance": info["distance"],
            "terminal_speed": info["speed"],
            "is_success": (info["distance"] < self.problem.success_distance)
            & (info["speed"] < self.problem.success_speed),
        }


class DockingCore(RendezvousCore):
    """N docking episodes: the target is a per-episode goal; a keep-out sphere sits at the origin."""

    problem_cls: ClassVar[type] = DockingProblem
    reward_cls: ClassVar[type] = DockingReward

    def __init__(self, problem: DockingProblem, reward: DockingReward, num_envs: int) -> None:
        super().__init__(problem, reward, num_envs)
        self.violations = np.zeros(num_envs, dtype=np.int64)
        self.min_clearance = np.full(num_envs, np.inf)
        # The optional constraints (cwh_envs.constraints): steps broken and least margin, per episode.
        self.extra = [
            name for name, on in (("speed", problem.speed_limit), ("cone", problem.approach_cone)) if on
        ]
        self.broken = {name: np.zeros(num_envs, dtype=np.int64) for name in self.extra}
        self.least = {name: np.full(num_envs, np.inf) for name in self.extra}
        # The cone's deepest violation over x_1 .. x_H, m; the keep-out's and the speed limit's follow
        # from min_clearance and least["speed"] (cwh_envs.constraints.violation_depths).
        self.cone_depth = np.zeros(num_envs)

    def start(self, rows: Any, states: np.ndarray, goals: np.ndarray | None = None) -> None:
        super().start(rows, states, goals)
        self.violations[rows] = 0
        self.min_clearance[rows] = np.inf
        for name in self.extra:
            self.broken[name][rows] = 0
            self.least[name][rows] = np.inf
        self.cone_depth[rows] = 0.0

    def observe(self) -> np.ndarray:
        return docking_observation(self.states, self.goals, self.steps, self.problem.horizon)

    def state_info(self) -> dict[str, np.ndarray]:
        info = super().state_info()
        info["clearance"] = np.linalg.norm(self.states[:, :3], axis=1) - self.problem.koz_radius
        info["in_koz"] = info["clearance"] < 0.0
        if self.problem.speed_limit is not None:
            info["speed_margin"] = speed_margin(self.states, self.goals, self.problem.speed_limit)
        if self.problem.approach_cone is not None:
            region, _, angle = cone_terms(
                self.states, self.goals, self.problem.approach_cone, self.problem.capture_radius
            )
            info["in_cone_region"], info["cone_angle"] = region, angle
        return info

    def _broken(self, info: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Per optional constraint: whether this step broke it, and its margin (inf where it does not apply)."""
        out = {}
        if "speed" in self.extra:
            out["speed"] = (info["speed_margin"] < -SPEED_TOLERANCE, info["speed_margin"])
        if "cone" in self.extra:
            region, slack, angle = cone_terms(
                self.states, self.goals, self.problem.approach_cone, self.problem.capture_radius
            )
            margin = np.where(region, self.problem.approach_cone[0] - angle, np.inf)
            out["cone"] = (region & (slack < -CONE_TOLERANCE), margin)
        return out

    def _accumulate(self, info: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        self.violations += info["in_koz"]
        np.minimum(self.min_clearance, info["clearance"], out=self.min_clearance)
        if "cone" in self.extra:
            depth = cone_depth(
                self.states, self.goals, self.problem.approach_cone, self.problem.capture_radius
            )
            np.maximum(self.cone_depth, depth, out=self.cone_depth)
        costs = {"cost_keep_out": info["in_koz"].astype(np.float64)}
        for name, (broken, margin) in self._broken(info).items():
            self.broken[name] += broken
            np.minimum(self.least[name], margin, out=self.least[name])
            costs[f"cost_{name}"] = broken.astype(np.float64)
        if not self.extra:  # the paper's problem: one constraint, one cost
            return {"cost": costs["cost_keep_out"]}
        return {"cost": sum(costs.values()), **costs}  # Safety-Gymnasium: the total and each part

    def _extra_terms(
        self, info: dict[str, np.ndarray], extra: dict[str, np.ndarray]
    ) -> dict[str, np.ndarray]:
        terms = {"keep_out": np.where(info["in_koz"], -self.reward.koz_weight, 0.0)}
        weights = {"speed": self.reward.speed_weight, "cone": self.reward.cone_weight}
        for name in self.extra:  # the step's costs, as _accumulate found them
            terms[name] = np.where(extra[f"cost_{name}"] > 0, -weights[name], 0.0)
        return terms

    def _final_info(self, info: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        final = super()._final_info(info)
        final["is_success"] &= self.violations == 0
        final["violation_rate"] = self.violations / self.problem.horizon
        final["min_clearance"] = self.min_clearance.copy()
        final["keep_out_depth"] = np.maximum(-self.min_clearance, 0.0)
        for name in self.extra:
            final["is_success"] &= self.broken[name] == 0
            final[f"{name}_violation_rate"] = self.broken[name] / self.problem.horizon
            final[f"min_{name}_margin"] = self.least[name].copy()
        if "speed" in self.extra:
            final["speed_depth"] = np.maximum(-self.least["speed"], 0.0)
        if "cone" in self.extra:
            final["cone_depth"] = self.cone_depth.copy()
        return final


class CWHEnv(gym.Env):
    """A core with N = 1 behind the ``gymnasium.Env`` API; info values are Python scalars."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 10}
    core_cls: ClassVar[type[RendezvousCore]]
    reset_options: ClassVar[tuple[str, ...]]

    def __init__(
        self, render_mode: str | None = None, dispersions: dict | None = None, **kwargs: Any
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}"
            )
        self.render_mode = render_mode
        self.problem, self.reward_weights = parse_kwargs(
            self.core_cls.problem_cls, self.core_cls.reward_cls, kwargs
        )
        self._core = self.core_cls(self.problem, self.reward_weights, 1)
        self.action_space = action_space()
        self.observation_space = observation_space(
            self.problem, with_goal=issubclass(self.core_cls, DockingCore)
        )
        self._needs_reset = True
        self._trajectory: list[np.ndarray] = []
        self._dispersed = None
        if dispersions is not None:
            if not isinstance(dispersions, dict):
                raise ValueError(
                    f"dispersions must be a dict of standard deviations or None, got {dispersions!r}"
                )
            self._dispersed = EpisodeDispersions(dispersions, self.problem.horizon)

    @property
    def state(self) -> np.ndarray:
        """The current state [x, y, z, vx, vy, vz] in metres and metres per second (a copy)."""
        return self._core.states[0].copy()

    @property
    def navigation_state(self) -> np.ndarray:
        """The state as navigation estimates it (6,): the true state plus this step's noise under the
        ``dispersions`` option, else the state itself. A CBF filter on top acts on it."""
        if self._dispersed is None or self._dispersed.draw is None:
            return self.state
        return self._dispersed.estimate(self.state, int(self._core.steps[0]))

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = sorted(set(options) - set(self.reset_options))
        if unknown:
            raise ValueError(f"unknown reset option(s) {unknown}; valid ones are {list(self.reset_options)}")
        state, goal = self._initial(options)
        self._core.start(0, state, goal)
        self._needs_reset = False
        self._trajectory = [state.copy()]
        info = _scalars(self._core.state_info())
        if self._dispersed is None:
            return self._core.observe()[0], info
        info["dispersion"] = self._dispersed.reset(seed)
        return self._dispersed.observe(self._core.observe()[0], 0), info

    def step(self, action: Any):
        if self._needs_reset:
            raise RuntimeError("call reset() before step(): the episode has not started or has ended")
        action = check_actions(action, (3,))
        if self._dispersed is not None:  # the plant's errors act before the box clip, as a thruster's would
            action = np.clip(self._dispersed.plant(action), -1.0, 1.0)
        reward, terminated, info, final = self._core.step(action[None])
        info = _scalars(info)
        done = bool(terminated[0])
        if done:
            info.update(_scalars(final))
            self._needs_reset = True
        if self.render_mode is not None:
            self._trajectory.append(self.state)
        obs = self._core.observe()[0]
        if self._dispersed is not None:
            obs = self._dispersed.observe(obs, int(self._core.steps[0]))
        return obs, float(reward[0]), done, False, info

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' to the env")
            return None
        from cwh_envs.render import render_frame  # matplotlib is needed only to render

        goal = self._core.goals[0].copy() if issubclass(self.core_cls, DockingCore) else None
        return render_frame(np.array(self._trajectory), self.problem, goal=goal)

    def _initial(self, options: dict[str, Any]) -> tuple[np.ndarray, np.ndarray | None]:
        raise NotImplementedError


def _scalars(info: dict[str, Any]) -> dict[str, Any]:
    """Row 0 of a batched info dict as Python scalars (fresh objects on every call)."""
    return {k: _scalars(v) if isinstance(v, dict) else v[0].item() for k, v in info.items()}
