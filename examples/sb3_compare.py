"""Reinforcement learning (PPO, SAC) next to behaviour cloning, a PD law and the optimal-control expert.

What would a reader try instead of cloning the expert? Reinforcement learning on the env's dense
reward, or a classical feedback law. This script trains Stable-Baselines3's PPO and SAC on
CWHRendezvous-v0 and CWHDockKOZ-v1 (docking without and with the CBFSafetyFilter in the loop) and
scores every policy with the families' own code: the 128 held-out starts of the search split,
flown in closed loop as one batch by the family train.py's ``evaluate`` (the env's own batched core
and CBF, cwh_envs.rollout), then the family metric and the fuel used against the expert's from the
same starts (sum of |u|^2 dt, which the expert minimises, and delta-v). Beside them: the expert (solve_* from each start, flown open-loop through the same
code), a behaviour-cloned policy from a family run, and a hand-written PD law (nothing learned).

    .venv/bin/python examples/sb3_compare.py --smoke     # under a minute: plumbing only, not a result
    .venv/bin/python examples/sb3_compare.py             # the run in docs/examples.md (~15-20 min, 2 cores)
    .venv/bin/python examples/sb3_compare.py --vec-env dummy   # the same learning on DummyVecEnv, slower

SB3 trains on the native vector env through cwh_envs.sb3.NativeVecEnv (``--vec-env native``, the
default) or on make_vec_env's DummyVecEnv of single envs (``--vec-env dummy``). Both reset from the
same cached pool of screened starts (``--start-pool``) with the same per-env seeding, so for one
seed they learn exactly the same policy (the tests check it); only the wall-clock differs.
``--start-pool 0`` draws fresh starts instead, which the two paths draw differently.

Writes results.md (the table, also printed), results.json, metric_vs_wallclock.png and the SB3
models (models/) to --out.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import stable_baselines3
import torch
from matplotlib.figure import Figure
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecMonitor, VecNormalize
from torch import nn

from cwh_envs import CBFSafetyFilter
from cwh_envs.controllers import pd_action
from cwh_envs.datasets import evaluation_set
from cwh_envs.experts import solve_docking, solve_rendezvous
from cwh_envs.sb3 import NativeVecEnv

ROOT = Path(__file__).resolve().parents[1]


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=150_000, help="env steps per PPO run")
    parser.add_argument(
        "--sac-timesteps",
        type=int,
        default=15_000,
        help="env steps per SAC run: one gradient step per env step makes it ~30x PPO's cost per step on CPU",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--algos", nargs="+", default=["ppo", "sac"], choices=["ppo", "sac"])
    parser.add_argument("--problems", nargs="+", default=["rendezvous", "docking", "docking+cbf"])
    parser.add_argument(
        "--bc-policy",
        action="append",
        default=[],
        metavar="FAMILY=PATH",
        help="a family run's policy (its --out dir or policy.pt), e.g. docking=runs/x/out; "
        "a family without one gets a BC policy trained now by its train.py with the defaults",
    )
    parser.add_argument("--eval-points", type=int, default=8, help="evaluations along each SB3 run")
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="where the results go (default results/sb3_compare; with --smoke, runs/sb3_compare_smoke, "
        "so that a plumbing check never overwrites the committed results)",
    )
    parser.add_argument(
        "--tensorboard", default=None, metavar="DIR", help="TensorBoard log dir (if installed)"
    )
    parser.add_argument(
        "--vec-env",
        choices=["native", "dummy"],
        default="native",
        help="native: cwh_envs.sb3.NativeVecEnv over the native vector env; dummy: make_vec_env's DummyVecEnv",
    )
    parser.add_argument(
        "--start-pool",
        type=int,
        default=None,
        metavar="N",
        help=f"reset from a cached pool of N screened starts (default {START_POOL}, --smoke {SMOKE_POOL}); "
        "0: fresh draws",
    )
    parser.add_argument("--smoke", action="store_true", help="512 steps, shrunken rollouts: a plumbing check")
    args = parser.parse_args()
    if args.out is None:
        args.out = Path("runs/sb3_compare_smoke" if args.smoke else "results/sb3_compare")
    if args.smoke:
        args.timesteps = args.sac_timesteps = 512
    if args.start_pool is None:
        args.start_pool = SMOKE_POOL if args.smoke else START_POOL
    if args.start_pool < 0:
        parser.error("--start-pool must be >= 0")
    if args.tensorboard is not None and importlib.util.find_spec("tensorboard") is None:
        print("[tensorboard] not installed (pip install tensorboard): no TensorBoard logs")
        args.tensorboard = None
    unknown = set(args.problems) - set(PROBLEMS)
    if unknown:
        parser.error(f"unknown problems {sorted(unknown)}; choose from {list(PROBLEMS)}")
    families = sorted({problem["family"] for problem in PROBLEMS.values()})
    if any(item.partition("=")[0] not in families for item in args.bc_policy):
        parser.error(f"--bc-policy takes FAMILY=PATH with FAMILY one of {families}")
    return args


# Each problem: the family whose metric scores it, the env SB3 trains on, and whether the CBF filter
# sits between the policy and the dynamics (in training and in the evaluation alike). The constrained
# env takes the family's speed limit and approach cone (its PROBLEM) as keyword arguments, and its
# filter is the multi-constraint one.
PROBLEMS = {
    "rendezvous": dict(family="rendezvous", env_id="cwh_envs:CWHRendezvous-v0", cbf=False),
    "docking": dict(family="docking", env_id="cwh_envs:CWHDockKOZ-v1", cbf=False),
    "docking+cbf": dict(family="docking", env_id="cwh_envs:CWHDockKOZ-v1", cbf=True),
    "docking-constrained+cbf": dict(family="docking-constrained", env_id="cwh_envs:CWHDockKOZ-v1", cbf=True),
}

# Hyperparameters written the way rl-baselines3-zoo writes hyperparams/ppo.yml and sac.yml for
# continuous control (its PyBullet entries: VecNormalize, gSDE with a small log_std_init, two hidden
# layers), not tuned here. Changes from the zoo: gamma is set per task so that 1 / (1 - gamma) is
# about the horizon (80 and 240 steps), since the time-to-go is observed and the terminal reward
# decides success; SAC's learning_starts is 1k, not 10k, and its net SB3's default [256, 256], not
# [400, 300], because the SAC budgets that fit a 2-core CPU are ~10x smaller than the zoo's.
HYPERPARAMS = {
    "ppo": {
        "rendezvous": dict(
            n_envs=8,
            normalize=dict(norm_obs=True, norm_reward=True),
            n_steps=512,
            batch_size=128,
            gamma=0.99,
            gae_lambda=0.95,
            n_epochs=10,
            ent_coef=0.0,
            learning_rate=3e-4,
            clip_range=0.2,
            max_grad_norm=0.5,
            use_sde=True,
            sde_sample_freq=4,
            policy_kwargs=dict(log_std_init=-2, ortho_init=False, activation_fn=nn.ReLU, net_arch=[256, 256]),
        ),
        "docking": dict(
            n_envs=8,
            normalize=dict(norm_obs=True, norm_reward=True),
            n_steps=512,
            batch_size=128,
            gamma=0.996,
            gae_lambda=0.95,
            n_epochs=10,
            ent_coef=0.0,
            learning_rate=3e-4,
            clip_range=0.2,
            max_grad_norm=0.5,
            use_sde=True,
            sde_sample_freq=4,
            policy_kwargs=dict(log_std_init=-2, ortho_init=False, activation_fn=nn.ReLU, net_arch=[256, 256]),
        ),
    },
    "sac": {
        "rendezvous": dict(
            n_envs=1,
            normalize=dict(norm_obs=True, norm_reward=False),
            learning_rate=7.3e-4,
            buffer_size=300_000,
            batch_size=256,
            ent_coef="auto",
            gamma=0.99,
            tau=0.02,
            train_freq=8,
            gradient_steps=8,
            learning_starts=1_000,
            use_sde=True,
            policy_kwargs=dict(log_std_init=-3, net_arch=[256, 256]),
        ),
        "docking": dict(
            n_envs=1,
            normalize=dict(norm_obs=True, norm_reward=False),
            learning_rate=7.3e-4,
            buffer_size=300_000,
            batch_size=256,
            ent_coef="auto",
            gamma=0.996,
            tau=0.02,
            train_freq=8,
            gradient_steps=8,
            learning_starts=1_000,
            use_sde=True,
            policy_kwargs=dict(log_std_init=-3, net_arch=[256, 256]),
        ),
    },
}
HYPERPARAMS["ppo"]["docking-constrained"] = HYPERPARAMS["ppo"]["docking"]
HYPERPARAMS["sac"]["docking-constrained"] = HYPERPARAMS["sac"]["docking"]
# --smoke only proves the plumbing: rollouts and warm-up shrunk to fit 512 steps.
SMOKE = {
    "ppo": dict(n_envs=2, n_steps=64, batch_size=64, n_epochs=2),
    "sac": dict(learning_starts=128, gradient_steps=1),
}
ALGOS = {"ppo": PPO, "sac": SAC}
FLOOR = 1e-3  # the plot's lowest metric value
# The training envs reset from a fixed pool of screened starts, drawn once and cached on disk
# (cwh_envs.datasets.start_pool): 35x the ~1,900 episodes of a 150k-step rendezvous run, so few
# starts repeat; a smoke run builds a small one.
START_POOL, SMOKE_POOL = 65_536, 1_024


def load_family(name: str):
    """The family's train.py as a module (its main() is guarded), for fly/evaluate/metrics/load_policy."""
    spec = importlib.util.spec_from_file_location(f"{name}_train", ROOT / "families" / name / "train.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class EvalSet:
    """A family's evaluation split and its exact closed-loop evaluation, for any ``policy.act``: the
    search split's N_EVAL starts by default, the sealed test split's N_TEST with ``split="test"``.
    ``dispersed=False`` skips the docking families' Monte Carlo auxiliary (a learning curve needs only
    the nominal metric); ``count`` scores only the split's first ``count`` starts."""

    def __init__(
        self, family, cbf: bool, split: str = "search", dispersed: bool = True, count: int | None = None
    ):
        self.safety = filter_keywords(family, cbf)
        self.family, self.dispersed = family, dispersed
        count = count or {"search": family.N_EVAL, "test": family.N_TEST}[split]
        self.held_out = evaluation_set(family.TASK, count, problem=family.PROBLEM, split=split)
        self.starts, self.goals = self.held_out.starts, self.held_out.goals

    def __call__(self, policy) -> dict:
        if self.family.TASK == "rendezvous":
            return self.family.evaluate(policy, self.held_out)
        return self.family.evaluate(policy, self.held_out, self.safety, dispersed=self.dispersed)


class SB3Policy:
    """An SB3 model behind the families' ``act`` interface: observations (N, d) -> env actions (N, 3)."""

    def __init__(self, model):
        self.model = model

    def act(self, obs: np.ndarray) -> np.ndarray:
        normalizer = self.model.get_vec_normalize_env()
        if normalizer is not None:  # the statistics the policy was trained on, frozen
            obs = normalizer.normalize_obs(obs)
        action, _ = self.model.predict(obs, deterministic=True)
        return np.clip(action.astype(np.float64), -1.0, 1.0)  # what the env does to an action


class OpenLoopExpert:
    """Replays the expert's thrust (N, H, 3) [N] as env actions; the step is read back from the observed
    time-to-go."""

    def __init__(self, controls: np.ndarray, u_max: float):
        self.actions = controls / u_max
        self.horizon = controls.shape[1]

    def act(self, obs: np.ndarray) -> np.ndarray:
        step = np.rint((1.0 - obs[:, -1].astype(np.float64)) * self.horizon).astype(int)
        return self.actions[np.arange(len(obs)), step]


class PDController:
    """Nothing learned: cwh_envs.controllers.pd_action (vector_rollout.py's law), a saturated,
    critically damped PD law toward the target. It flies straight at the docking point; the
    keep-out is left to the CBF."""

    def __init__(self, problem, omega: float = 0.01):
        self.problem, self.omega = problem, omega

    def act(self, obs: np.ndarray) -> np.ndarray:
        return pd_action(obs, self.problem, self.omega)


class MetricCurve(BaseCallback):
    """Scores the policy every ``every`` env steps before ``stop``; the clock excludes the scoring."""

    def __init__(self, evaluate: EvalSet, every: int, stop: int, metric: str):
        super().__init__()
        self.evaluate, self.every, self.stop, self.metric = evaluate, every, stop, metric
        self.points: list[dict] = []

    def _on_training_start(self) -> None:
        self.started, self.scoring, self.next = time.perf_counter(), 0.0, self.every

    def score(self) -> dict:
        seconds = time.perf_counter() - self.started - self.scoring
        began = time.perf_counter()
        metrics = self.evaluate(SB3Policy(self.model))
        self.scoring += time.perf_counter() - began
        self.points.append({"timesteps": self.num_timesteps, "train_seconds": seconds, **metrics})
        self.logger.record(f"family/{self.metric}", metrics[self.metric])
        return metrics

    def _on_step(self) -> bool:
        # The final point is scored after learn() returns: PPO still updates after its last rollout.
        if self.next <= self.num_timesteps < self.stop:
            self.next += self.every
            self.score()
        return True


def train_sb3(algo: str, problem: dict, family, evaluate: EvalSet, args) -> dict:
    params = {**HYPERPARAMS[algo][problem["family"]], **(SMOKE[algo] if args.smoke else {})}
    n_envs, normalize = params.pop("n_envs"), params.pop("normalize")
    envs = VecNormalize(training_envs(problem, family, n_envs, args), gamma=params["gamma"], **normalize)
    model = ALGOS[algo]("MlpPolicy", envs, seed=args.seed, tensorboard_log=args.tensorboard, **params)
    timesteps = args.sac_timesteps if algo == "sac" else args.timesteps
    every = max(1, timesteps // args.eval_points)
    curve = MetricCurve(evaluate, every, timesteps, family.METRIC)
    model.learn(timesteps, callback=curve, tb_log_name=f"{algo}_{problem['name']}")
    metrics = curve.score()
    model.save(args.out / "models" / f"{algo}_{problem['name']}.zip")
    envs.save(str(args.out / "models" / f"{algo}_{problem['name']}_vecnormalize.pkl"))
    envs.close()
    return {
        "data": f"{model.num_timesteps} env steps",
        "train_seconds": curve.points[-1]["train_seconds"],
        "metrics": metrics,
        "curve": curve.points,
    }


def filter_keywords(family, cbf: bool) -> dict:
    """The CBF filter the training envs fly (the family's margin), as keywords of the native env and of
    the families' ``fly``: the evaluation flies the same filter."""
    return {"cbf_margin": family.PROBLEM.margin} if cbf else {}


def training_envs(problem: dict, family, n_envs: int, args, reward: dict | None = None):
    """The monitored SB3 VecEnv of ``n_envs`` training envs; with the CBF for docking+cbf (the
    family's margin, as CBFSafetyFilter's default); ``reward``, the env's reward weights where they
    are not its defaults (keyword arguments of the env, e.g. ``terminal_weight``)."""
    options = ({"start_pool": args.start_pool} if args.start_pool else {}) | (reward or {})
    limits = {
        k: getattr(family.PROBLEM, k)
        for k in ("speed_limit", "approach_cone")
        if getattr(family.PROBLEM, k, None)
    }
    if args.vec_env == "dummy":
        wrapper = CBFSafetyFilter if problem["cbf"] else None
        return make_vec_env(
            problem["env_id"],
            n_envs=n_envs,
            seed=args.seed,
            env_kwargs={**options, **limits},
            wrapper_class=wrapper,
        )
    cbf = filter_keywords(family, problem["cbf"])
    # SB3's algorithms read only is_success (and the terminal observation) from the infos.
    envs = NativeVecEnv(
        problem["env_id"], n_envs, seed=args.seed, info_keys=("is_success",), **options, **cbf, **limits
    )
    return VecMonitor(envs)


def expert(family, evaluate: EvalSet) -> dict:
    """Solve every held-out start and fly the thrust open-loop through the family's evaluation."""
    began = time.perf_counter()
    if family.TASK == "rendezvous":
        controls = [solve_rendezvous(x0, family.PROBLEM)[1] for x0 in evaluate.starts]
    else:
        controls = [
            solve_docking(x0, g, family.PROBLEM)[1]
            for x0, g in zip(evaluate.starts, evaluate.goals, strict=True)
        ]
    seconds = time.perf_counter() - began
    return {
        "data": "the model",
        "train_seconds": seconds,
        "metrics": evaluate(OpenLoopExpert(np.array(controls), family.PROBLEM.u_max)),
    }


def behaviour_cloning(name: str, family, given: dict, args) -> tuple:
    """(policy, saved dict, provenance): the given family run, else one trained now with the defaults."""
    path = given.get(name)
    if path is None:
        path = args.out / f"bc_{name}"
        print(f"[bc] no --bc-policy {name}=PATH: training families/{name}/train.py (defaults) into {path}")
        script = ROOT / "families" / name / "train.py"
        command = [sys.executable, str(script), "--seed", str(args.seed), "--out", str(path)]
        # The runs log goes beside the policy: the family's own runs.jsonl is for its campaigns.
        subprocess.run(
            [*command, "--runs-log", str(path / "runs.jsonl")],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        provenance = f"trained now by families/{name}/train.py (defaults, seed {args.seed})"
    else:
        provenance = f"loaded from {path}"
    policy, saved = family.load_policy(path)
    if saved["task"] != family.TASK:
        raise SystemExit(f"--bc-policy {name}: {path} holds a {saved['task']} policy")
    return policy, saved, provenance


def fmt(value) -> str:
    if value is None:
        return "-"
    return ("yes" if value else "no") if isinstance(value, bool) else f"{value:.4g}"


def markdown(rows: list[dict], notes: list[str]) -> str:
    lines = [
        "| problem | method | trained on | train wall-clock [s] | metric | value | success rate "
        "| violation rate | min clearance [m] | strict feasible | CBF edits | energy / expert | Δv / expert |",
        "|---|---|---|---:|---|---:|---:|---:|---:|---|---:|---:|---:|",
    ]
    for row in rows:
        m = row["metrics"]
        cells = [
            row["problem"],
            row["method"],
            row["data"],
            f"{row['train_seconds']:.1f}",
            row["metric"],
            fmt(m[row["metric"]]),
            f"{m['success_rate']:.1%}",
            f"{m['violation_rate']:.2%}" if "violation_rate" in m else "-",
            fmt(m.get("min_clearance")),
            fmt(m.get("strict_feasible")),
            f"{m['cbf_active_rate']:.1%}" if PROBLEMS[row["problem"]]["cbf"] else "-",
            f"{m['effort_ratio']:.3g}",
            f"{m['delta_v_ratio']:.3g}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n\n" + "\n".join(f"- {note}" for note in notes) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """Metric vs training wall-clock, one panel per problem, log-log; values below FLOOR drawn at it."""
    problems = list(dict.fromkeys(row["problem"] for row in rows))
    figure = Figure(figsize=(5 * len(problems), 4), layout="constrained")
    styles = {"PPO": "o-", "SAC": "s-", "BC": "D", "expert (open loop)": "*"}
    for ax, name in zip(np.atleast_1d(figure.subplots(1, len(problems))), problems, strict=True):
        for row in (r for r in rows if r["problem"] == name):
            points = row.get("curve") or [{"train_seconds": row["train_seconds"], **row["metrics"]}]
            x = [max(p["train_seconds"], 1e-2) for p in points]
            y = [max(p[row["metric"]], FLOOR) for p in points]  # the expert's ~1e-12 would flatten the rest
            label = f"{row['method']}: {row['metrics'][row['metric']]:.3g}"
            if row["method"] == "PD law":  # no training: a reference level, not a point
                ax.axhline(y[0], ls="--", color="tab:gray", label=label)
            else:
                ax.plot(x, y, styles[row["method"]], label=label, ms=8)
            ax.set_ylabel(row["metric"])
        ax.set(xscale="log", yscale="log", title=name, xlabel="training wall-clock [s]")
        ax.grid(True, which="both", lw=0.3)
        ax.legend(fontsize="small")
    figure.savefig(path, dpi=100)


def main() -> None:
    args = parse_args()
    torch.set_num_threads(1)  # as the families train: small MLPs, and wall-clocks comparable to BC's
    (args.out / "models").mkdir(parents=True, exist_ok=True)
    given = dict(item.split("=", 1) for item in args.bc_policy)
    families = {name: load_family(name) for name in sorted({PROBLEMS[p]["family"] for p in args.problems})}
    bc = {name: behaviour_cloning(name, family, given, args) for name, family in families.items()}

    rows = []
    for name in args.problems:
        problem = {"name": name, **PROBLEMS[name]}
        family = families[problem["family"]]
        evaluate = EvalSet(family, problem["cbf"])
        base = {"problem": name, "metric": family.METRIC}
        rows.append({**base, "method": "expert (open loop)", **expert(family, evaluate)})
        pd_metrics = evaluate(PDController(family.PROBLEM))
        rows.append(
            {**base, "method": "PD law", "data": "nothing", "train_seconds": 0.0, "metrics": pd_metrics}
        )
        policy, saved, _ = bc[problem["family"]]
        record = saved["record"]
        data = f"{record['n_train_pairs']} expert pairs"
        bc_row = {
            "method": "BC",
            "data": data,
            "train_seconds": record["train_seconds"],
            "metrics": evaluate(policy),
        }
        rows.append({**base, **bc_row})
        for algo in args.algos:
            print(f"[{algo}] {name}: training ...", flush=True)
            rows.append({**base, "method": algo.upper(), **train_sb3(algo, problem, family, evaluate, args)})
            print(f"[{algo}] {name}: {family.METRIC} = {rows[-1]['metrics'][family.METRIC]:.4g}", flush=True)

    notes = [
        f"BC {name}: {provenance}; config "
        + ", ".join(f"{k}={v}" for k, v in saved["config"].items())
        + f"; its own FINAL_METRIC {families[name].METRIC} = {saved['record'][families[name].METRIC]:.4g}."
        for name, (_, saved, provenance) in bc.items()
    ]
    vec_env = "cwh_envs.sb3.NativeVecEnv (native vector env)" if args.vec_env == "native" else "DummyVecEnv"
    starts = f"a pool of {args.start_pool} screened starts" if args.start_pool else "fresh screened draws"
    notes += [
        f"SB3 {stable_baselines3.__version__}, seed {args.seed}"
        + (" (--smoke: shrunken rollouts, not a result)" if args.smoke else "")
        + "; wall-clock = model.learn minus the metric evaluations along the way, torch on 1 thread.",
        f"SB3 trained on {vec_env}; training resets from {starts}.",
        "BC wall-clock = the family's train_seconds (gradient steps only; its expert demonstrations come "
        "from the dataset cache). Expert wall-clock = solving the 128 held-out starts.",
        "Every row is scored by the family train.py's own fly/evaluate and metric on its 128 held-out "
        "starts; docking+cbf flies through cwh_envs.cbf.safe_actions (SB3 also trains through "
        "CBFSafetyFilter there) and CBF edits is the share of steps the filter changed; docking flies "
        "unfiltered.",
        "energy / expert and Δv / expert: the sums over the 128 starts of Σ|u|²dt (what the minimum-energy "
        "expert minimises) and of Σ|u|dt/m, over the expert's own from the same starts (its open-loop row "
        "is 1 up to rounding); logged, never optimised by any method here.",
    ]
    table = markdown(rows, notes)
    (args.out / "results.md").write_text(table)
    (args.out / "results.json").write_text(json.dumps(rows, indent=1, default=float, allow_nan=False))
    plot(rows, args.out / "metric_vs_wallclock.png")
    print(table)
    print(f"wrote {args.out / 'results.md'}, results.json, metric_vs_wallclock.png")


if __name__ == "__main__":
    main()
