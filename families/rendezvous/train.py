"""Behaviour cloning of the minimum-energy CWH rendezvous expert (paper Sec. 4.2).

One file, CleanRL style: the editable configuration on top, the fixed machinery below.

    python train.py [--seed 0] [--run-id ID] [--runs-log runs.jsonl] [--out out] [--eval-split search]

A time-conditioned MLP maps [x, y, z, vx, vy, vz, tau] to thrust / u_max and is trained by MSE
on screened expert demonstrations (Eq. bc_loss). It is then flown in closed loop from held-out
starts at once through the env's own batched core (cwh_envs.rollout.fly); the primary metric is
the mean terminal distance to the target in metres (lower is better). By default the starts are
the 128 of the search split, the only ones a search may select on; ``--eval-split test`` scores
the record on the 1024 starts of the sealed test split, and the same policy on the search split
too (each split's metrics under ``splits``). The run ends with one line ``FINAL_METRIC: {json}``
that is also appended to the runs log. At four evenly spaced epochs it prints
``PROGRESS: {"step": epoch, METRIC: value}``, the metric on the first 16 search starts, so that
``autoresearch loop --early-stop`` can stop a hopeless run. Fuel is logged, never optimised:
``effort_ratio`` (sum of |u|^2 dt, the quantity the expert minimises) and ``delta_v_ratio`` over
the expert's own from the same starts.
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

from cwh_envs.datasets import Demonstrations, demonstrations, evaluation_set
from cwh_envs.problems import RendezvousProblem
from cwh_envs.rollout import Flight, control_effort
from cwh_envs.rollout import fly as fly_policy

# ===== Editable Configuration (the agent may change these values only) =====
N_DEMOS = 32  # expert trajectories in the training set (the first N of a fixed screened pool)
EPOCHS = 60  # passes over the training set
LEARNING_RATE = 0.001  # AdamW peak learning rate, annealed to 0 by a cosine schedule
BATCH_SIZE = 256  # state-action pairs per gradient step
WEIGHT_DECAY = 0.0  # AdamW decoupled weight decay
GRAD_CLIP = 1.0  # maximum global L2 norm of the gradient
HIDDEN_DIM = 128  # units in each hidden layer
N_LAYERS = 2  # hidden layers
ACTIVATION = "tanh"  # hidden nonlinearity: "tanh", "relu" or "gelu"
DROPOUT = 0.0  # dropout probability after each hidden layer (training only)
# ===== Fixed Configuration (immutable below this line) =====

TASK = "rendezvous"
METRIC = "mean_terminal_distance"
PROBLEM = RendezvousProblem()  # every constant: horizon, u_max, success thresholds, (A, B)
POOL_DEMOS = 1024  # the N_DEMOS upper bound: one fixed pool, so a warm cache covers every config
N_EVAL = 128  # held-out, reachability-screened evaluation starts: the search split
N_TEST = 1024  # the sealed test split, screened alike (--eval-split test)
N_PROGRESS = 16  # search starts behind each PROGRESS line: a cheap proxy of the metric
PROGRESS_POINTS = 4  # PROGRESS lines per run, at evenly spaced epochs (the last one included)
DATA_SEED = 0  # the pool does not move with --seed; the seed varies only initialisation and batching
TORCH_THREADS = 1  # fixed: reproducible on any host, and the audit runs two trainings on two cores
OBS_DIM, ACT_DIM = 7, 3
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
        """Observations (N, 7) as the env shows them -> actions (N, 3) as it takes them: thrust / u_max in [-1, 1]."""
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
    """Observations (M, 7) and expert thrust (M, 3) [N] of the first N_DEMOS pool trajectories, and
    the content keys of the sets they come from."""
    pool = demonstrations(TASK, POOL_DEMOS, seed=DATA_SEED, problem=PROBLEM)
    demos = pool.take(config["N_DEMOS"])
    return demos.observations, demos.actions, {"train_pool": pool.content_key}


def train(config: dict, obs: np.ndarray, actions: np.ndarray, device: torch.device, seed: int, report=None):
    """MSE behaviour cloning (Eq. bc_loss); returns the policy and the best epoch-mean loss.

    ``report(epoch, policy)`` is called, the policy in eval mode, at PROGRESS_POINTS evenly spaced epochs.
    """
    mean, std = obs.mean(axis=0), obs.std(axis=0)
    std = np.where(std > 1e-8, std, 1.0)  # a constant input column (e.g. N_DEMOS = 1) stays finite
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


def fly(policy: Policy, starts: np.ndarray) -> Flight:
    """Every start flown at once through the env's own batched core; no expert in the loop."""
    return fly_policy(PROBLEM, policy.act, starts)


def rendezvous_metrics(flight: Flight, expert_thrust: np.ndarray) -> dict:
    """The primary metric and its auxiliaries; effort is measured against the expert's thrust
    (N, H, 3) from the same starts (ratios of the sums over the starts)."""
    distance, speed = flight.terminal_distance, flight.terminal_speed
    energy, delta_v = control_effort(flight.thrust, PROBLEM)
    expert_energy, expert_delta_v = control_effort(expert_thrust, PROBLEM)
    return {
        METRIC: float(distance.mean()),
        "success_rate": float(flight.is_success.mean()),
        "median_terminal_distance": float(np.median(distance)),
        "max_terminal_distance": float(distance.max()),
        "mean_terminal_speed": float(speed.mean()),
        "effort_ratio": float(energy.sum() / expert_energy.sum()),
        "delta_v_ratio": float(delta_v.sum() / expert_delta_v.sum()),
        "mean_delta_v": float(delta_v.mean()),
    }


def evaluate(policy: Policy, held_out: Demonstrations) -> dict:
    """The metrics of ``policy`` on an evaluation split (cwh_envs.datasets.evaluation_set)."""
    return rendezvous_metrics(fly(policy, held_out.starts), held_out.trajectory_thrust())


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

    obs, actions, datasets = load_training_set(config)
    search = evaluation_set(TASK, N_EVAL, problem=PROBLEM, split="search")
    datasets["search_split"] = search.content_key
    first = search.take(N_PROGRESS)

    def report(epoch: int, policy: Policy) -> None:
        value = evaluate(policy, first)[METRIC]
        print("PROGRESS: " + json.dumps({"step": epoch, METRIC: value}, allow_nan=False), flush=True)

    started = time.perf_counter()
    policy, best_loss = train(config, obs, actions, device, args.seed, report)
    train_seconds = time.perf_counter() - started
    started = time.perf_counter()
    splits = {"search": evaluate(policy, search)}
    if args.eval_split == "test":
        test = evaluation_set(TASK, N_TEST, problem=PROBLEM, split="test")
        datasets["test_split"] = test.content_key
        splits["test"] = evaluate(policy, test)
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
