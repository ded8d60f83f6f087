"""Behaviour cloning of the constrained docking expert: keep-out, speed limit and approach cone.

One file, CleanRL style: the editable configuration on top, the fixed machinery below. The
docking family's recipe on a harder problem (cwh_envs.constraints): the chaser must also keep
``||v|| <= 0.01 m/s + 2n ||r - g||`` and, within 15 m of the docking point, stay inside a
30-degree cone about the docking axis. A PD law with the multi-constraint CBF filter breaks the
cone on every start (docs/envs.md); the expert is the constrained SCP.

    python train.py [--seed 0] [--run-id ID] [--runs-log runs.jsonl] [--out out] [--eval-split search]

A time-conditioned MLP maps [r, v, g, tau] to thrust / u_max and is trained by MSE on screened
constrained-expert demonstrations, optionally augmented with recovery demonstrations from
perturbed states (the constrained expert re-solved from there), then flown in closed loop from held-out starts through the
env's own batched core (cwh_envs.rollout.fly), through the multi-constraint CBF filter
(cwh_envs.cbf_multi) when RUNTIME_CBF_FILTER is on. The primary metric is score = mean terminal
distance + 10 x (mean keep-out + speed + cone violation rates), lower is better; a run is
strict-feasible when success >= 0.80 (success asks every constraint met), every violation rate
is exactly 0 and the minimum keep-out clearance is >= 0. By default the starts are the 128 of the
search split; ``--eval-split test`` scores the record on the 1024 of the sealed test split, and
the search split too (each split's metrics under ``splits``): the docking family's sizes. The run ends
with one line ``FINAL_METRIC: {json}`` that is also appended to the runs log; PROGRESS lines as in
the docking family, on the first 16 search starts. Fuel is logged, never optimised: ``effort_ratio`` and ``delta_v_ratio`` against the
constrained expert from the same starts. ``dispersed`` is the Monte Carlo auxiliary: success and
violation rates of the same policy on the evaluation starts under DISPERSIONS; it never enters
the score.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import torch
from filelock import FileLock
from torch import nn

from cwh_envs.datasets import Demonstrations, demonstrations, evaluation_set, recovery_demonstrations
from cwh_envs.problems import DockingProblem
from cwh_envs.rollout import Flight, control_effort
from cwh_envs.rollout import fly as fly_policy

# ===== Editable Configuration (the agent may change these values only) =====
N_DEMOS = 64  # expert trajectories in the training set (the first N of a fixed screened pool)
EPOCHS = 60  # passes over the training set
LEARNING_RATE = 0.001  # AdamW peak learning rate, annealed to 0 by a cosine schedule
BATCH_SIZE = 256  # state-action pairs per gradient step
WEIGHT_DECAY = 0.0  # AdamW decoupled weight decay
GRAD_CLIP = 1.0  # maximum global L2 norm of the gradient
HIDDEN_DIM = 128  # units in each hidden layer
N_LAYERS = 2  # hidden layers
ACTIVATION = "tanh"  # hidden nonlinearity: "tanh", "relu" or "gelu"
DROPOUT = 0.0  # dropout probability after each hidden layer (training only)
RUNTIME_CBF_FILTER = True  # fly through the multi-constraint predictive CBF safety filter
RECOVERY_AUGMENT_FRAC = 0.0  # recovery trajectories added, as a fraction of N_DEMOS
# ===== Fixed Configuration (immutable below this line) =====

TASK = "docking"
METRIC = "score"
# Every constant: horizon, u_max, keep-out, margin, thresholds, (A, B), and the two path
# constraints (the constants of benchmarks/bench_constrained_docking.py, chosen there by measurement).
PROBLEM = DockingProblem(speed_limit=(0.01, 2 * DockingProblem().n), approach_cone=(30.0, 15.0))
VIOLATION_WEIGHT = 10.0  # Eq. rpo_score: one sustained violation outweighs the accuracy budget
POOL_DEMOS = 256  # the N_DEMOS upper bound: one fixed pool, so a warm cache covers every config
MAX_RECOVERY_FRAC = 0.5  # the RECOVERY_AUGMENT_FRAC upper bound
POOL_RECOVERY = round(MAX_RECOVERY_FRAC * POOL_DEMOS)  # recovery trajectories: also one fixed pool
N_EVAL = 128  # held-out, screened far-side evaluation starts: the search split
N_TEST = 1024  # the sealed test split, screened alike (--eval-split test)
N_PROGRESS = 16  # search starts behind each PROGRESS line: a cheap proxy of the metric
# The Monte Carlo auxiliary's fixed dispersion set (standard deviations; cwh_envs.dispersions):
# 2 % thrust magnitude, 1 degree misalignment, 2 % mass, 0.05 m and 0.5 mm/s navigation noise.
DISPERSIONS = dict(thrust_scale=0.02, misalignment_deg=1.0, mass=0.02, nav_position=0.05, nav_velocity=5e-4)
DISPERSION_SEED = 0  # episode i of a split draws its dispersions from seed DISPERSION_SEED + i
PROGRESS_POINTS = 4  # PROGRESS lines per run, at evenly spaced epochs (the last one included)
DATA_SEED = 0  # the pools do not move with --seed; the seed varies only initialisation and batching
TORCH_THREADS = 1  # fixed: reproducible on any host, and the audit runs two trainings on two cores
SUCCESS_GATE = 0.80  # strict feasibility: success rate floor (with zero violations, clearance >= 0)
OBS_DIM, ACT_DIM = 10, 3
CONFIG_NAMES = (
    "N_DEMOS",
    "EPOCHS",
    "LEARNING_RATE",
    "BATCH_SIZE",
    "WEIGHT_DECAY",
    "GRAD_CLIP",
    "HIDDEN_DIM",
    "N_LAYERS",
    "ACTIVATION",
    "DROPOUT",
    "RUNTIME_CBF_FILTER",
    "RECOVERY_AUGMENT_FRAC",
)
ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "gelu": nn.GELU}


class Policy(nn.Module):
    """MLP on standardised observations; outputs thrust / u_max. ``act`` returns the env action (thrust / u_max, clipped)."""

    def __init__(self, config: dict, obs_mean: torch.Tensor, obs_std: torch.Tensor, u_max: float):
        super().__init__()
        layers, width = [], OBS_DIM
        for _ in range(config["N_LAYERS"]):
            layers += [
                nn.Linear(width, config["HIDDEN_DIM"]),
                ACTIVATIONS[config["ACTIVATION"]](),
                nn.Dropout(config["DROPOUT"]),
            ]
            width = config["HIDDEN_DIM"]
        self.net = nn.Sequential(*layers, nn.Linear(width, ACT_DIM))
        self.register_buffer("obs_mean", obs_mean.float())
        self.register_buffer("obs_std", obs_std.float())
        self.u_max = u_max

    def forward(self, standardised_obs: torch.Tensor) -> torch.Tensor:
        return self.net(standardised_obs)

    @torch.no_grad()
    def act(self, obs: np.ndarray) -> np.ndarray:
        """Observations (N, 10) as the env shows them -> actions (N, 3) as it takes them: thrust / u_max in [-1, 1]."""
        x = torch.as_tensor(obs, dtype=torch.float32, device=self.obs_mean.device)
        return np.clip(self((x - self.obs_mean) / self.obs_std).double().cpu().numpy(), -1.0, 1.0)


def build_policy(config: dict, obs_mean=None, obs_std=None) -> Policy:
    """A fresh policy for ``config``; identity standardisation unless statistics are given."""
    mean = torch.zeros(OBS_DIM) if obs_mean is None else torch.as_tensor(obs_mean)
    std = torch.ones(OBS_DIM) if obs_std is None else torch.as_tensor(obs_std)
    return Policy(config, mean, std, PROBLEM.u_max)


def load_policy(path: str | os.PathLike) -> tuple[Policy, dict]:
    """A saved policy (an --out directory or its policy.pt), in eval mode, and the saved dict."""
    path = Path(path)
    saved = torch.load(path / "policy.pt" if path.is_dir() else path, map_location="cpu", weights_only=True)
    policy = build_policy(saved["config"], saved["obs_mean"], saved["obs_std"])
    policy.load_state_dict(saved["state_dict"])
    return policy.eval(), saved


def check_config(config: dict) -> None:
    """Refuse values the machinery cannot run (the search space in family.json is the finer bound)."""
    problems = []
    if not (isinstance(config["N_DEMOS"], int) and 1 <= config["N_DEMOS"] <= POOL_DEMOS):
        problems.append(f"N_DEMOS must be an int in [1, {POOL_DEMOS}]")
    for name in ("EPOCHS", "BATCH_SIZE", "HIDDEN_DIM", "N_LAYERS"):
        if not (isinstance(config[name], int) and not isinstance(config[name], bool) and config[name] >= 1):
            problems.append(f"{name} must be a positive int")
    for name in ("LEARNING_RATE", "GRAD_CLIP"):
        if not (isinstance(config[name], int | float) and math.isfinite(config[name]) and config[name] > 0):
            problems.append(f"{name} must be a positive finite number")
    if not (isinstance(config["WEIGHT_DECAY"], int | float) and 0 <= config["WEIGHT_DECAY"] < math.inf):
        problems.append("WEIGHT_DECAY must be a non-negative finite number")
    if not (isinstance(config["DROPOUT"], int | float) and 0 <= config["DROPOUT"] < 1):
        problems.append("DROPOUT must lie in [0, 1)")
    if config["ACTIVATION"] not in ACTIVATIONS:
        problems.append(f"ACTIVATION must be one of {sorted(ACTIVATIONS)}")
    if not isinstance(config["RUNTIME_CBF_FILTER"], bool):
        problems.append("RUNTIME_CBF_FILTER must be True or False")
    frac = config["RECOVERY_AUGMENT_FRAC"]
    if not (isinstance(frac, int | float) and 0 <= frac <= MAX_RECOVERY_FRAC):
        problems.append(f"RECOVERY_AUGMENT_FRAC must lie in [0, {MAX_RECOVERY_FRAC}]")
    if problems:
        raise SystemExit(f"train.py: invalid configuration: {'; '.join(problems)}")


def seed_everything(seed: int) -> torch.device:
    random.seed(seed)
    np.random.seed(seed)  # noqa: NPY002 -- for any library code that draws from the legacy global RNG
    torch.manual_seed(seed)
    torch.set_num_threads(TORCH_THREADS)
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")  # needed by deterministic cuBLAS
    torch.use_deterministic_algorithms(True)
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def load_training_set(config: dict) -> tuple[np.ndarray, np.ndarray, dict]:
    """Observations (M, 10) and expert thrust (M, 3) [N]: N_DEMOS demos plus the recovery share,
    and the content keys of the sets they come from."""
    pool = demonstrations(TASK, POOL_DEMOS, seed=DATA_SEED, problem=PROBLEM)
    demos = pool.take(config["N_DEMOS"])
    obs, actions, keys = [demos.observations], [demos.actions], {"train_pool": pool.content_key}
    n_recovery = round(config["RECOVERY_AUGMENT_FRAC"] * config["N_DEMOS"])
    if n_recovery > 0:
        recovery_pool = recovery_demonstrations(TASK, POOL_RECOVERY, seed=DATA_SEED, problem=PROBLEM)
        recovery = recovery_pool.take(n_recovery)
        obs.append(recovery.observations)
        actions.append(recovery.actions)
        keys["recovery_pool"] = recovery_pool.content_key
    return np.concatenate(obs), np.concatenate(actions), keys


def train(config: dict, obs: np.ndarray, actions: np.ndarray, device: torch.device, seed: int, report=None):
    """MSE behaviour cloning (Eq. bc_loss); returns the policy and the best epoch-mean loss.

    ``report(epoch, policy)`` is called, the policy in eval mode, at PROGRESS_POINTS evenly spaced epochs.
    """
    mean, std = obs.mean(axis=0), obs.std(axis=0)
    std = np.where(std > 1e-8, std, 1.0)  # a constant input column stays finite
    policy = build_policy(config, mean, std).to(device)
    x = torch.as_tensor((obs - mean) / std, dtype=torch.float32, device=device)
    y = torch.as_tensor(actions / PROBLEM.u_max, dtype=torch.float32, device=device)
    optimizer = torch.optim.AdamW(
        policy.parameters(), lr=config["LEARNING_RATE"], weight_decay=config["WEIGHT_DECAY"]
    )
    steps_per_epoch = math.ceil(len(x) / config["BATCH_SIZE"])
    total_steps = config["EPOCHS"] * steps_per_epoch
    # Cosine from the peak rate to 0 over the whole run: one fixed schedule, no warm-up.
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda s: 0.5 * (1.0 + math.cos(math.pi * s / total_steps))
    )
    generator = torch.Generator(device="cpu").manual_seed(seed)
    best_loss = math.inf
    progress_epochs = {
        math.ceil(config["EPOCHS"] * k / PROGRESS_POINTS) for k in range(1, PROGRESS_POINTS + 1)
    }
    policy.train()
    for epoch in range(config["EPOCHS"]):
        order = torch.randperm(len(x), generator=generator).to(device)
        epoch_loss = torch.zeros((), device=device)
        for start in range(0, len(x), config["BATCH_SIZE"]):
            batch = order[start : start + config["BATCH_SIZE"]]
            loss = (policy(x[batch]) - y[batch]).square().sum(dim=1).mean()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            nn.utils.clip_grad_norm_(policy.parameters(), config["GRAD_CLIP"])
            optimizer.step()
            schedule.step()
            epoch_loss += loss.detach() * len(batch)
        epoch_loss = epoch_loss.item() / len(x)
        if not math.isfinite(epoch_loss):
            raise SystemExit(f"train.py: training diverged: loss is {epoch_loss} at epoch {epoch + 1}")
        best_loss = min(best_loss, epoch_loss)
        if report is not None and (epoch + 1) in progress_epochs:
            report(epoch + 1, policy.eval())  # eval mode and no RNG draw: training is not altered
            policy.train()
    return policy.eval(), best_loss


def fly(policy: Policy, starts: np.ndarray, goals: np.ndarray, cbf: bool, dispersions=None) -> Flight:
    """Every start flown at once through the env's own batched core; no expert in the loop. With
    ``cbf`` every action passes the multi-constraint CBF filter (keep-out margin PROBLEM.margin)
    first; with ``dispersions`` start i flies under the draw of seed DISPERSION_SEED + i."""
    return fly_policy(
        PROBLEM,
        policy.act,
        starts,
        goals,
        cbf_margin=PROBLEM.margin if cbf else None,
        dispersions=dispersions,
        dispersion_seed=DISPERSION_SEED,
    )


def violation_rates(flight: Flight) -> np.ndarray:
    """Per start, the share of steps 1..H breaking each constraint, summed: keep-out + speed + cone."""
    return flight.violation_rate + flight.speed_violation_rate + flight.cone_violation_rate


def docking_metrics(flight: Flight, expert_thrust: np.ndarray) -> dict:
    """The score and the strict gate from the env's per-start outcomes, every constraint counted as
    the env counts it; effort against the expert's thrust (N, H, 3) from the same starts."""
    terminal_distance, violation = flight.terminal_distance, violation_rates(flight)
    mean_violation = float(violation.mean())
    rates = {
        "keep_out": float(flight.violation_rate.mean()),
        "speed": float(flight.speed_violation_rate.mean()),
        "cone": float(flight.cone_violation_rate.mean()),
    }
    min_clearance = float(flight.min_clearance.min())
    success_rate = float(flight.is_success.mean())
    energy, delta_v = control_effort(flight.thrust, PROBLEM)
    expert_energy, expert_delta_v = control_effort(expert_thrust, PROBLEM)
    metrics = {
        METRIC: float(terminal_distance.mean()) + VIOLATION_WEIGHT * mean_violation,
        "mean_terminal_distance": float(terminal_distance.mean()),
        "success_rate": success_rate,
        "violation_rate": mean_violation,
        "violation_rates": rates,
        "min_clearance": min_clearance,
        "strict_feasible": bool(
            success_rate >= SUCCESS_GATE and mean_violation == 0.0 and min_clearance >= 0.0
        ),
        # The same gate, graded (each <= 0 when met): a key-free searcher learns how far a run misses.
        "constraints": {
            "success_shortfall": SUCCESS_GATE - success_rate,
            "keep_out_violation_rate": rates["keep_out"],
            "speed_violation_rate": rates["speed"],
            "cone_violation_rate": rates["cone"],
            "clearance_deficit": -min_clearance,
        },
        "violating_starts": int((violation > 0).sum()),
        "median_terminal_distance": float(np.median(terminal_distance)),
        "max_terminal_distance": float(terminal_distance.max()),
        "mean_terminal_speed": float(flight.terminal_speed.mean()),
        "effort_ratio": float(energy.sum() / expert_energy.sum()),
        "delta_v_ratio": float(delta_v.sum() / expert_delta_v.sum()),
        "mean_delta_v": float(delta_v.mean()),
    }
    if flight.cbf_active is not None:
        metrics["cbf_active_rate"] = float(flight.cbf_active.mean())
        metrics["cbf_infeasible_steps"] = int(flight.cbf_infeasible.sum())
    return metrics


def dispersed_metrics(flight: Flight) -> dict:
    """The Monte Carlo auxiliary: how the policy fares under DISPERSIONS (never in the score)."""
    violation = violation_rates(flight)
    return {
        "dispersions": DISPERSIONS,
        "success_rate": float(flight.is_success.mean()),
        "violation_rate": float(violation.mean()),
        "violating_starts": int((violation > 0).sum()),
        "mean_terminal_distance": float(flight.terminal_distance.mean()),
    }


def evaluate(policy: Policy, held_out: Demonstrations, cbf: bool, dispersed: bool = True) -> dict:
    """The metrics of ``policy`` on an evaluation split (cwh_envs.datasets.evaluation_set), with the
    Monte Carlo auxiliary under ``dispersed`` unless it is False."""
    flight = fly(policy, held_out.starts, held_out.goals, cbf)
    metrics = docking_metrics(flight, held_out.trajectory_thrust())
    if dispersed:
        metrics["dispersed"] = dispersed_metrics(
            fly(policy, held_out.starts, held_out.goals, cbf, DISPERSIONS)
        )
    return metrics


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
    parser.add_argument("--out", type=Path, default=Path("out"), help="directory for policy.pt")
    parser.add_argument(
        "--eval-split",
        choices=("search", "test"),
        default="search",
        help="the split the record is scored on; test also scores the search split (both under splits)",
    )
    args = parser.parse_args()
    config = {name: globals()[name] for name in CONFIG_NAMES}
    check_config(config)
    run_id = args.run_id or uuid.uuid4().hex[:12]
    device = seed_everything(args.seed)
    cbf = config["RUNTIME_CBF_FILTER"]

    obs, actions, datasets = load_training_set(config)
    search = evaluation_set(TASK, N_EVAL, problem=PROBLEM, split="search")
    datasets["search_split"] = search.content_key
    first = search.take(N_PROGRESS)

    def report(epoch: int, policy: Policy) -> None:
        value = evaluate(policy, first, cbf, dispersed=False)[METRIC]
        print("PROGRESS: " + json.dumps({"step": epoch, METRIC: value}, allow_nan=False), flush=True)

    started = time.perf_counter()
    policy, best_loss = train(config, obs, actions, device, args.seed, report)
    train_seconds = time.perf_counter() - started
    started = time.perf_counter()
    splits = {"search": evaluate(policy, search, cbf)}
    if args.eval_split == "test":
        test = evaluation_set(TASK, N_TEST, problem=PROBLEM, split="test")
        datasets["test_split"] = test.content_key
        splits["test"] = evaluate(policy, test, cbf)
    eval_seconds = time.perf_counter() - started

    record = {
        "run_id": run_id,
        **splits[args.eval_split],  # the primary metric on top: the split the run is scored on
        "splits": splits,
        "eval_split": args.eval_split,
        "best_train_loss": best_loss,
        "train_seconds": round(train_seconds, 3),
        "eval_seconds": round(eval_seconds, 3),
        "n_params": sum(p.numel() for p in policy.parameters()),
        "n_train_pairs": len(obs),
        "seed": args.seed,
        "datasets": datasets,
        "config": config,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    torch.save(
        {
            "task": TASK,
            "config": config,
            "state_dict": {k: v.cpu() for k, v in policy.state_dict().items()},
            "obs_mean": policy.obs_mean.cpu(),
            "obs_std": policy.obs_std.cpu(),
            "problem": PROBLEM.as_dict(),
            "record": record,
        },
        args.out / "policy.pt",
    )
    append_record(args.runs_log, record)
    print("FINAL_METRIC: " + json.dumps(record, allow_nan=False), flush=True)


if __name__ == "__main__":
    sys.exit(main())
