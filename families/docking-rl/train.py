"""Reinforcement learning (SB3 PPO) on the keep-out docking problem, optionally residual on the closed-form law.

One file, CleanRL style: the editable configuration on top, the fixed machinery below.

    python train.py [--seed 0] [--run-id ID] [--runs-log runs.jsonl] [--out out] [--eval-split search]

The reinforcement-learning sibling of families/docking: the same problem, the same score on the same
splits, reached by trial and error on the env's reward instead of by imitating the expert. PPO
(Stable-Baselines3) trains on N_ENVS rows of the docking env (cwh_envs.sb3.NativeVecEnv over the
native vector env, its problem exactly PROBLEM, each reset drawn from a fixed pool of START_POOL
screened starts), under VecNormalize, with the two-step predictive CBF filter in the loop when
RUNTIME_CBF_FILTER is on (and then in the evaluation too: the policy is flown as it was trained).
POLICY_FORM = "residual" makes the agent's action a correction of at most RESIDUAL_SCALE x u_max
per axis added to the closed-form shrinking-horizon minimum-energy law (cwh_envs.sb3.ResidualVecEnv,
cwh_envs.controllers.MinEnergyFeedback); the action layer starts at zero, so a residual run starts
flying the law. The reward is the env's own, its weights in the editable block; the score never
reads it.

Training runs to TOTAL_TIMESTEPS env steps, or to the first env step or gradient step past the time
budget (AUTORESEARCH_TIME_BUDGET, seconds of training), whichever comes first. The policy is then flown
deterministically (the mean action, VecNormalize's statistics frozen) from the held-out starts at once
through the env's own batched core (cwh_envs.rollout.fly) and scored exactly as families/docking
scores a run: score = mean terminal distance + 10 x mean keep-out violation rate (lower is better);
strict-feasible when success >= 0.80, the violation rate is exactly 0 and the minimum clearance
>= 0; the fuel against the expert's from the same starts (``effort_ratio``, ``delta_v_ratio``), and
the Monte Carlo auxiliary under DISPERSIONS at 1 and STRESS_SCALE sigma (``dispersed``,
``dispersed_3sigma``, ``dispersed_violating_share``), never in the score. By default the starts are
the 512 of the search split (N_EVAL); ``--eval-split test`` scores the record on the 1024 starts of
the sealed test split, and the same policy on the search split too (each split's metrics under
``splits``). At four evenly spaced points of the run it prints ``PROGRESS: {"step": percent,
METRIC: value}``, the metric on the first 16 search starts; the run ends with one line
``FINAL_METRIC: {json}`` that is also appended to the runs log. The agent is saved to ``--out``:
SB3's ``model.zip``, VecNormalize's statistics ``vecnormalize.pkl`` and ``run.json`` (the task, the
configuration, the problem and the record).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import pickle
import random
import sys
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch
from filelock import FileLock
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecMonitor, VecNormalize
from torch import nn

from cwh_envs.controllers import MinEnergyFeedback
from cwh_envs.datasets import Demonstrations, evaluation_set
from cwh_envs.problems import DockingProblem
from cwh_envs.rollout import Flight, control_effort
from cwh_envs.rollout import fly as fly_policy
from cwh_envs.sb3 import NativeVecEnv, ResidualVecEnv, residual_policy

# ===== Editable Configuration (the agent may change these values only) =====
TOTAL_TIMESTEPS = 1000000  # env steps to train for, in whole rollouts (a time budget may end the run first)
LEARNING_RATE = 0.0003  # Adam learning rate of the policy and value networks
LR_ANNEAL = False  # True: the rate decays linearly to 0 by the end of the run (steps or time budget)
N_ENVS = 8  # parallel training envs
N_STEPS = 512  # steps per env per rollout: each update learns from N_ENVS x N_STEPS transitions
BATCH_SIZE = 128  # transitions per minibatch
N_EPOCHS = 10  # passes over each rollout
GAMMA = 0.996  # discount factor (1 / (1 - GAMMA) = 250 steps, about the 240-step horizon)
GAE_LAMBDA = 0.95  # generalised advantage estimation's bias-variance trade-off
CLIP_RANGE = 0.2  # PPO's clip on the probability ratio
ENT_COEF = 0.0  # entropy bonus weight
VF_COEF = 0.5  # value-loss weight
MAX_GRAD_NORM = 0.5  # maximum global L2 norm of the gradient
USE_SDE = True  # generalised state-dependent exploration (gSDE) instead of independent Gaussian noise
SDE_SAMPLE_FREQ = 4  # gSDE: steps between exploration-matrix draws (-1: once per rollout)
LOG_STD_INIT = -2.0  # initial log standard deviation of the exploration noise
HIDDEN_DIM = 256  # units in each hidden layer (policy and value networks alike, not shared)
N_LAYERS = 2  # hidden layers
ACTIVATION = "relu"  # hidden nonlinearity: "tanh", "relu" or "gelu"
NORMALIZE_REWARD = True  # VecNormalize scales the reward by its running discounted-return std
PROGRESS_WEIGHT = 0.1  # reward per metre closed on the docking point
EFFORT_WEIGHT = 0.01  # penalty per step on ||action||^2 (thrust / u_max)
TERMINAL_WEIGHT = 0.1  # final penalty on d_H / 1 m + v_H / 0.05 m/s
SUCCESS_BONUS = 10.0  # final reward for a success (within 1 m, below 0.05 m/s, no violation)
KOZ_WEIGHT = 1.0  # penalty for every step that ends inside the keep-out sphere
RUNTIME_CBF_FILTER = True  # train and fly through the two-step predictive CBF safety filter
POLICY_FORM = "direct"  # "direct": the network is the policy; "residual": a correction to the closed-form law
RESIDUAL_SCALE = 0.2  # residual form: the correction's bound per axis, a fraction of u_max
# ===== Fixed Configuration (immutable below this line) =====

TASK = "docking"
METRIC = "score"
PROBLEM = DockingProblem()  # the docking family's problem: horizon, u_max, keep-out, margin, thresholds
ENV_ID = "cwh_envs:CWHDockKOZ-v1"
VIOLATION_WEIGHT = 10.0  # Eq. rpo_score: one sustained violation outweighs the accuracy budget
START_POOL = 65536  # screened starts the training envs reset from (cached; disjoint from both splits)
N_EVAL = 512  # the search split, the docking family's (its first 512 starts)
N_TEST = 1024  # the sealed test split, the docking family's (--eval-split test)
N_PROGRESS = 16  # search starts behind each PROGRESS line: a cheap proxy of the metric
# The Monte Carlo auxiliary's fixed dispersion set (standard deviations; cwh_envs.dispersions):
# 2 % thrust magnitude, 1 degree misalignment, 2 % mass, 0.05 m and 0.5 mm/s navigation noise.
DISPERSIONS = dict(thrust_scale=0.02, misalignment_deg=1.0, mass=0.02, nav_position=0.05, nav_velocity=5e-4)
DISPERSION_SEED = 0  # episode i of a split draws its dispersions from seed DISPERSION_SEED + i
STRESS_SCALE = 3.0  # the stress set beside the auxiliary: DISPERSIONS at 3 sigma
PROGRESS_POINTS = 4  # PROGRESS lines per run, at evenly spaced shares of it (the last one included)
TORCH_THREADS = 1  # fixed: reproducible on any host, and the audit runs two trainings on two cores
TIME_BUDGET_VARIABLE = "AUTORESEARCH_TIME_BUDGET"  # seconds of training the loop grants a run (unset: none)
RUNAWAY_DISTANCE = 120.0  # m: a start ending farther from its target than the farthest start began ran away
SUCCESS_GATE = 0.80  # strict feasibility: success rate floor (with zero violations, clearance >= 0)
ORTHO_INIT = False  # rl-baselines3-zoo's setting with gSDE: PyTorch's default initialisation
CONFIG_NAMES = (
    "TOTAL_TIMESTEPS",
    "LEARNING_RATE",
    "LR_ANNEAL",
    "N_ENVS",
    "N_STEPS",
    "BATCH_SIZE",
    "N_EPOCHS",
    "GAMMA",
    "GAE_LAMBDA",
    "CLIP_RANGE",
    "ENT_COEF",
    "VF_COEF",
    "MAX_GRAD_NORM",
    "USE_SDE",
    "SDE_SAMPLE_FREQ",
    "LOG_STD_INIT",
    "HIDDEN_DIM",
    "N_LAYERS",
    "ACTIVATION",
    "NORMALIZE_REWARD",
    "PROGRESS_WEIGHT",
    "EFFORT_WEIGHT",
    "TERMINAL_WEIGHT",
    "SUCCESS_BONUS",
    "KOZ_WEIGHT",
    "RUNTIME_CBF_FILTER",
    "POLICY_FORM",
    "RESIDUAL_SCALE",
)
ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "gelu": nn.GELU}
POLICY_FORMS = ("direct", "residual")
REWARD_WEIGHTS = {  # editable name -> the env's keyword
    "PROGRESS_WEIGHT": "progress_weight",
    "EFFORT_WEIGHT": "effort_weight",
    "TERMINAL_WEIGHT": "terminal_weight",
    "SUCCESS_BONUS": "success_bonus",
    "KOZ_WEIGHT": "koz_weight",
}
MAX_RESIDUAL_SCALE = 2.0  # a correction of 2 u_max can undo any action of the law (cwh_envs.sb3)


def _number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def check_config(config: dict) -> None:
    """Refuse values the machinery cannot run (the search space in family.json is the finer bound)."""
    problems = []
    for name in ("TOTAL_TIMESTEPS", "N_ENVS", "N_STEPS", "N_EPOCHS", "HIDDEN_DIM", "N_LAYERS"):
        if not (_int(config[name]) and config[name] >= 1):
            problems.append(f"{name} must be a positive int")
    if not (_int(config["BATCH_SIZE"]) and config["BATCH_SIZE"] >= 2):  # advantages are normalised per batch
        problems.append("BATCH_SIZE must be an int >= 2")
    for name in ("LEARNING_RATE", "CLIP_RANGE", "MAX_GRAD_NORM"):
        if not (_number(config[name]) and config[name] > 0):
            problems.append(f"{name} must be a positive finite number")
    for name in ("ENT_COEF", "VF_COEF", *REWARD_WEIGHTS):
        if not (_number(config[name]) and config[name] >= 0):
            problems.append(f"{name} must be a non-negative finite number")
    if not (_number(config["GAMMA"]) and 0 < config["GAMMA"] < 1):
        problems.append("GAMMA must lie in (0, 1)")
    if not (_number(config["GAE_LAMBDA"]) and 0 <= config["GAE_LAMBDA"] <= 1):
        problems.append("GAE_LAMBDA must lie in [0, 1]")
    if not _number(config["LOG_STD_INIT"]):
        problems.append("LOG_STD_INIT must be a finite number")
    if not (_int(config["SDE_SAMPLE_FREQ"]) and config["SDE_SAMPLE_FREQ"] >= -1):
        problems.append("SDE_SAMPLE_FREQ must be an int >= -1")
    for name in ("LR_ANNEAL", "USE_SDE", "NORMALIZE_REWARD", "RUNTIME_CBF_FILTER"):
        if not isinstance(config[name], bool):
            problems.append(f"{name} must be True or False")
    if config["ACTIVATION"] not in ACTIVATIONS:
        problems.append(f"ACTIVATION must be one of {sorted(ACTIVATIONS)}")
    if config["POLICY_FORM"] not in POLICY_FORMS:
        problems.append(f"POLICY_FORM must be one of {list(POLICY_FORMS)}")
    scale = config["RESIDUAL_SCALE"]
    if not (_number(scale) and 0 < scale <= MAX_RESIDUAL_SCALE):
        problems.append(f"RESIDUAL_SCALE must lie in (0, {MAX_RESIDUAL_SCALE:g}]")
    if problems:
        raise SystemExit(f"train.py: invalid configuration: {'; '.join(problems)}")


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)  # noqa: NPY002 -- for any library code that draws from the legacy global RNG
    torch.manual_seed(seed)
    torch.set_num_threads(TORCH_THREADS)
    torch.use_deterministic_algorithms(True)


class Budget:
    """The run's training-time budget (TIME_BUDGET_VARIABLE, seconds): training stops at the first env
    step or gradient step past it, and the run is scored as it stands (``budget_exhausted`` in the
    record)."""

    def __init__(self, seconds: float | None):
        self.seconds, self.started, self.exhausted = seconds, None, False

    @classmethod
    def from_environment(cls) -> Budget:
        text = os.environ.get(TIME_BUDGET_VARIABLE)
        if text is None:
            return cls(None)
        try:
            seconds = float(text)
        except ValueError:
            seconds = math.nan
        if not (math.isfinite(seconds) and seconds > 0):
            raise SystemExit(
                f"train.py: {TIME_BUDGET_VARIABLE} must be a positive number of seconds, got {text!r}"
            )
        return cls(seconds)

    def start(self) -> None:
        """The clock runs from here: training time only (data and evaluation are the loop's allowance)."""
        self.started = time.perf_counter()

    def share(self) -> float:
        """The share of the budget spent so far (0 without a budget, or before the clock starts)."""
        if self.seconds is None or self.started is None:
            return 0.0
        return (time.perf_counter() - self.started) / self.seconds

    def spent(self) -> bool:
        """Whether the time is up; the first time it is, the run was cut."""
        if self.share() >= 1.0:
            self.exhausted = True
        return self.exhausted


class LearningRate:
    """SB3's learning-rate schedule: LEARNING_RATE, or with LR_ANNEAL decayed linearly to 0 by the end
    of the run, whichever of its two ends comes first: TOTAL_TIMESTEPS (SB3's ``progress_remaining``)
    or the time budget. A run the budget cuts is then scored annealed, not mid-schedule."""

    def __init__(self, config: dict, budget: Budget):
        self.rate, self.anneal, self.budget = config["LEARNING_RATE"], config["LR_ANNEAL"], budget

    def __call__(self, progress_remaining: float) -> float:
        if not self.anneal:
            return self.rate
        return self.rate * max(0.0, min(progress_remaining, 1.0 - self.budget.share()))


def safety_filter(config: dict) -> dict:
    """The recipe's filter as keywords of the env and of fly: the two-step predictive CBF filter with
    the keep-out margin PROBLEM.margin, or none."""
    return {"cbf_margin": PROBLEM.margin} if config["RUNTIME_CBF_FILTER"] else {}


def base_law() -> MinEnergyFeedback:
    """The residual form's base: the closed-form shrinking-horizon minimum-energy law toward the
    observed goal, which ignores the keep-out (the correction and the filter keep the chaser out)."""
    return MinEnergyFeedback(PROBLEM)


def training_envs(config: dict, seed: int) -> VecNormalize:
    """N_ENVS rows of the docking env on PROBLEM, reset from the START_POOL screened starts (row i
    seeded seed + i), with the config's reward weights and filter; monitored, the residual wrapper in
    the residual form, and VecNormalize on top (so that the law sees observations in metres)."""
    weights = {keyword: float(config[name]) for name, keyword in REWARD_WEIGHTS.items()}
    envs = VecMonitor(
        NativeVecEnv(
            ENV_ID,
            config["N_ENVS"],
            seed=seed,
            info_keys=("is_success",),  # all SB3 reads: converting every info key costs more than a step
            start_pool=START_POOL,
            **PROBLEM.as_dict(),
            **weights,
            **safety_filter(config),
        )
    )
    if config["POLICY_FORM"] == "residual":
        envs = ResidualVecEnv(envs, base_law(), config["RESIDUAL_SCALE"])
    return VecNormalize(envs, gamma=config["GAMMA"], norm_obs=True, norm_reward=config["NORMALIZE_REWARD"])


def build_model(config: dict, envs: VecNormalize, seed: int, learning_rate: Callable) -> PPO:
    """A fresh PPO agent on ``envs``. In the residual form the action layer (the policy's mean) starts
    at zero, so that the agent starts flying the law (Silver et al. 2018's residual practice)."""
    model = PPO(
        "MlpPolicy",
        envs,
        learning_rate=learning_rate,
        n_steps=config["N_STEPS"],
        batch_size=config["BATCH_SIZE"],
        n_epochs=config["N_EPOCHS"],
        gamma=config["GAMMA"],
        gae_lambda=config["GAE_LAMBDA"],
        clip_range=config["CLIP_RANGE"],
        ent_coef=config["ENT_COEF"],
        vf_coef=config["VF_COEF"],
        max_grad_norm=config["MAX_GRAD_NORM"],
        use_sde=config["USE_SDE"],
        sde_sample_freq=config["SDE_SAMPLE_FREQ"],
        policy_kwargs=dict(
            log_std_init=float(config["LOG_STD_INIT"]),
            ortho_init=ORTHO_INIT,
            activation_fn=ACTIVATIONS[config["ACTIVATION"]],
            net_arch=[config["HIDDEN_DIM"]] * config["N_LAYERS"],
        ),
        seed=seed,
        device="cpu",  # small MLPs: the GPU would only add transfers
        verbose=0,
    )
    if config["POLICY_FORM"] == "residual":
        with torch.no_grad():
            model.policy.action_net.weight.zero_()
            model.policy.action_net.bias.zero_()
    return model


def flown_policy(config: dict, model: PPO, normalizer: VecNormalize) -> Callable[[np.ndarray], np.ndarray]:
    """The agent as it is flown: observations (N, 10) as the env shows them -> env actions (N, 3),
    the mean action on VecNormalize's current statistics (read, never updated), the law added back in
    the residual form (cwh_envs.sb3.residual_policy, ResidualVecEnv's composition)."""

    def network(obs: np.ndarray) -> np.ndarray:
        action, _ = model.predict(normalizer.normalize_obs(obs), deterministic=True)
        return np.clip(action.astype(np.float64), -1.0, 1.0)  # what the env does to an action

    if config["POLICY_FORM"] == "residual":
        return residual_policy(base_law(), network, config["RESIDUAL_SCALE"])
    return network


def load_policy(path: str | os.PathLike) -> tuple[SimpleNamespace, dict]:
    """A saved agent (an --out directory) and its run.json; the agent's ``act`` (observations -> env
    actions, as the BC families' policies have it) flies it as trained (:func:`flown_policy`).
    VecNormalize's statistics are unpickled without an env: flying only normalises observations."""
    path = Path(path)
    run = json.loads((path / "run.json").read_text(encoding="utf-8"))
    with open(path / "vecnormalize.pkl", "rb") as saved:
        normalizer = pickle.load(saved)  # our own file, written by main() below
    normalizer.training = False
    model = PPO.load(path / "model.zip", device="cpu")
    return SimpleNamespace(act=flown_policy(run["config"], model, normalizer)), run


def fly(act: Callable, starts: np.ndarray, goals: np.ndarray, safety: dict, dispersions=None) -> Flight:
    """Every start flown at once through the env's own batched core; every action passes the filter
    ``safety`` names first (:func:`safety_filter`); with ``dispersions`` start i flies under the draw
    of seed DISPERSION_SEED + i, the filter on the navigation estimate."""
    return fly_policy(
        PROBLEM, act, starts, goals, dispersions=dispersions, dispersion_seed=DISPERSION_SEED, **safety
    )


def docking_metrics(flight: Flight, expert_thrust: np.ndarray) -> dict:
    """Eq. rpo_score and the strict gate from the env's per-start outcomes (a violation is a step
    ending strictly inside the keep-out, over steps 1..H); effort is measured against the expert's
    thrust (N, H, 3) from the same starts (ratios of the sums over the starts)."""
    terminal_distance, violation = flight.terminal_distance, flight.violation_rate
    mean_violation = float(violation.mean())
    min_clearance = float(flight.min_clearance.min())
    success_rate = float(flight.is_success.mean())
    energy, delta_v = control_effort(flight.thrust, PROBLEM)
    expert_energy, expert_delta_v = control_effort(expert_thrust, PROBLEM)
    metrics = {
        METRIC: float(terminal_distance.mean()) + VIOLATION_WEIGHT * mean_violation,
        "mean_terminal_distance": float(terminal_distance.mean()),
        "success_rate": success_rate,
        "violation_rate": mean_violation,
        "min_clearance": min_clearance,
        "strict_feasible": bool(
            success_rate >= SUCCESS_GATE and mean_violation == 0.0 and min_clearance >= 0.0
        ),
        # The same gate, graded (each <= 0 when met): a key-free searcher learns how far a run misses.
        "constraints": {
            "success_shortfall": SUCCESS_GATE - success_rate,
            "violation_rate": mean_violation,
            "clearance_deficit": -min_clearance,
        },
        "violating_starts": int((violation > 0).sum()),
        "median_terminal_distance": float(np.median(terminal_distance)),
        "max_terminal_distance": float(terminal_distance.max()),
        "runaway_share": float((terminal_distance > RUNAWAY_DISTANCE).mean()),
        "mean_terminal_speed": float(flight.terminal_speed.mean()),
        "effort_ratio": float(energy.sum() / expert_energy.sum()),
        "delta_v_ratio": float(delta_v.sum() / expert_delta_v.sum()),
        "mean_delta_v": float(delta_v.mean()),
    }
    if flight.cbf_active is not None:
        metrics["cbf_active_rate"] = float(flight.cbf_active.mean())
        metrics["cbf_infeasible_steps"] = int(flight.cbf_infeasible.sum())
    return metrics


def dispersed_metrics(flight: Flight, dispersions: dict) -> dict:
    """The Monte Carlo auxiliary: how the policy fares under ``dispersions`` (never in the score):
    per constraint (this problem's one, the keep-out), the starts breaking it and the deepest
    violation (m)."""
    violation = flight.violation_rate
    # Broken as the score counts it (a step ending strictly inside the sphere), how deep from the depth.
    rates, depths = {"keep_out": flight.violation_rate}, {"keep_out": flight.keep_out_depth}
    return {
        "dispersions": dispersions,
        "success_rate": float(flight.is_success.mean()),
        "violation_rate": float(violation.mean()),
        "violating_starts": int((violation > 0).sum()),
        "breaking_starts": {name: int((rate > 0).sum()) for name, rate in rates.items()},
        "deepest": {name: float(depth.max()) for name, depth in depths.items()},
        "mean_terminal_distance": float(flight.terminal_distance.mean()),
    }


def evaluate(act: Callable, held_out: Demonstrations, safety: dict, dispersed: bool = True) -> dict:
    """The metrics of the policy ``act`` on an evaluation split (cwh_envs.datasets.evaluation_set),
    flown through the filter ``safety`` names, with the Monte Carlo auxiliary (1 sigma, and the
    STRESS_SCALE stress set) unless ``dispersed`` is False."""
    flight = fly(act, held_out.starts, held_out.goals, safety)
    metrics = docking_metrics(flight, held_out.trajectory_thrust())
    if dispersed:
        stress = {name: STRESS_SCALE * value for name, value in DISPERSIONS.items()}
        for key, spreads in (("dispersed", DISPERSIONS), ("dispersed_3sigma", stress)):
            flown = fly(act, held_out.starts, held_out.goals, safety, spreads)
            metrics[key] = dispersed_metrics(flown, spreads)
        # What the robust protocol limits (family.json): the 1-sigma share of starts breaking anything.
        metrics["dispersed_violating_share"] = metrics["dispersed"]["violating_starts"] / len(held_out.starts)
    return metrics


class BudgetSpent(Exception):
    """Raised before the first gradient step past the time budget: learning ends inside that update."""


class Supervisor(BaseCallback):
    """Ends learning at the first env step or gradient step past the time budget (an update the clock
    runs out in keeps the steps it took), counts the rollouts collected in full, and at rollout ends
    calls ``report(percent)`` when the run has passed another 1 / PROGRESS_POINTS of itself (its env
    steps of TOTAL_TIMESTEPS or its share of the budget, whichever is further); the last point is
    the caller's, after learning."""

    def __init__(self, budget: Budget, total_timesteps: int, report: Callable[[int], None]):
        super().__init__()
        self.budget, self.total_timesteps, self.report = budget, total_timesteps, report
        self.rollouts, self.next_point = 0, 1

    def _on_training_start(self) -> None:
        # PPO's update has no callback: an optimiser hook stops a long one (many epochs, big rollouts).
        self.model.policy.optimizer.register_step_pre_hook(self._before_gradient_step)

    def _before_gradient_step(self, optimizer, args, kwargs) -> None:
        if self.budget.spent():
            raise BudgetSpent

    def _on_step(self) -> bool:
        return not self.budget.spent()

    def _on_rollout_end(self) -> None:
        self.rollouts += 1
        done = max(self.num_timesteps / self.total_timesteps, self.budget.share())
        point = min(PROGRESS_POINTS - 1, math.floor(done * PROGRESS_POINTS))
        if point >= self.next_point:
            self.report(round(100 * point / PROGRESS_POINTS))
            self.next_point = point + 1


def learn(model: PPO, config: dict, budget: Budget, report: Callable[[int], None]) -> Supervisor:
    """Train ``model`` for TOTAL_TIMESTEPS env steps or until ``budget`` is spent, its clock started
    here; the supervisor that watched it holds the counts."""
    supervisor = Supervisor(budget, config["TOTAL_TIMESTEPS"], report)
    budget.start()
    with contextlib.suppress(BudgetSpent):
        model.learn(config["TOTAL_TIMESTEPS"], callback=supervisor)
    return supervisor


def append_record(path: Path, record: dict) -> None:
    """One write of the whole line under a lock, flushed and fsynced: concurrent runs interleave safely."""
    path.parent.mkdir(parents=True, exist_ok=True)
    line = json.dumps(record, allow_nan=False) + "\n"
    with FileLock(f"{path}.lock"), open(path, "a", encoding="utf-8") as log:
        log.write(line)
        log.flush()
        os.fsync(log.fileno())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--run-id", default=None, help="defaults to a fresh random id")
    parser.add_argument("--runs-log", type=Path, default=Path(__file__).with_name("runs.jsonl"))
    parser.add_argument("--out", type=Path, default=Path("out"), help="directory for the saved agent")
    parser.add_argument(
        "--eval-split",
        choices=("search", "test"),
        default="search",
        help="the split the record is scored on; test also scores the search split (both under splits)",
    )
    args = parser.parse_args()
    config = {name: globals()[name] for name in CONFIG_NAMES}
    check_config(config)
    budget = Budget.from_environment()
    run_id = args.run_id or uuid.uuid4().hex[:12]
    seed_everything(args.seed)
    safety = safety_filter(config)

    search = evaluation_set(TASK, N_EVAL, problem=PROBLEM, split="search")
    datasets = {"search_split": search.content_key}
    split_ids = {"search": search.starts_key}  # the starts scored on (cwh_envs.splits): autoresearch compares
    first = search.take(N_PROGRESS)
    envs = training_envs(config, args.seed)
    model = build_model(config, envs, args.seed, LearningRate(config, budget))
    act = flown_policy(config, model, envs)

    def report(step: int) -> None:
        value = evaluate(act, first, safety, dispersed=False)[METRIC]
        print("PROGRESS: " + json.dumps({"step": step, METRIC: value}, allow_nan=False), flush=True)

    supervisor = learn(model, config, budget, report)
    train_seconds = time.perf_counter() - budget.started
    report(100)
    started = time.perf_counter()
    splits = {"search": evaluate(act, search, safety)}
    if args.eval_split == "test":
        test = evaluation_set(TASK, N_TEST, problem=PROBLEM, split="test")
        datasets["test_split"] = test.content_key
        split_ids["test"] = test.starts_key
        splits["test"] = evaluate(act, test, safety)
    eval_seconds = time.perf_counter() - started

    record = {
        "run_id": run_id,
        **splits[args.eval_split],  # the primary metric on top: the split the run is scored on
        "splits": splits,
        "eval_split": args.eval_split,
        "train_seconds": round(train_seconds, 3),
        "eval_seconds": round(eval_seconds, 3),
        "env_steps": int(model.num_timesteps),
        "rollouts": supervisor.rollouts,
        "n_params": sum(p.numel() for p in model.policy.parameters()),
        **({"time_budget": budget.seconds, "budget_exhausted": budget.exhausted} if budget.seconds else {}),
        "seed": args.seed,
        "datasets": datasets,
        "split_ids": split_ids,
        "config": config,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    model.save(args.out / "model.zip")
    envs.save(str(args.out / "vecnormalize.pkl"))
    run = {"task": TASK, "config": config, "problem": PROBLEM.as_dict(), "record": record}
    (args.out / "run.json").write_text(json.dumps(run, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    envs.close()
    append_record(args.runs_log, record)
    print("FINAL_METRIC: " + json.dumps(record, allow_nan=False), flush=True)


if __name__ == "__main__":
    sys.exit(main())
