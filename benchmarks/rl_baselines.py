"""Reinforcement-learning baselines trained as the field trains them (issue 60): several seeds per row,
long budgets, resumable, with learning curves and an rliable summary.

    python benchmarks/rl_baselines.py --task docking --algo ppo --seeds 0 1 2 3 4 --timesteps 10000000
    python benchmarks/rl_baselines.py --task docking --algo residual-ppo --seeds 0 1 2 3 4 --timesteps 2000000
    python benchmarks/rl_baselines.py --task docking --algo ppo --seeds 0 1 --smoke   # plumbing, seconds

Rows (``--algo``), on the families' problems (``--task``: the env takes the family's PROBLEM; on both
docking tasks the family's filter sits in the training loop, as ACT3's run-time assurance does):

- ``ppo``, ``sac``: SB3 with ``examples/sb3_compare.py``'s settings (rl-baselines3-zoo's continuous-
  control practice: VecNormalize, gSDE, two layers of 256), only the budget longer.
- ``residual-ppo``: PPO learning a correction of at most ``--residual-scale`` of u_max per axis on the
  closed-form law (the routed law on constrained docking): :class:`cwh_envs.sb3.ResidualVecEnv`. The
  policy's mean layer starts at zero, so the row starts as the law.
- ``bc-ppo``: PPO whose policy mean starts as a clone of the expert: before learning, VecNormalize's
  observation statistics are set from the family's demonstrations and held there
  (:class:`cwh_envs.sb3.FixedStatistics`: the clone keeps the inputs it was fitted on) and the actor
  is fitted to their actions (mean squared error, Adam, ``--bc-epochs`` passes); then the first
  ``--critic-warmup`` env steps train the value function alone, the actor frozen, so that PPO's first
  policy updates use advantages from a critic of the clone, not from a random one (measured without
  both: the clone's 1.63 on the search split became 4.71 within 254k steps). ``--bc-weight`` keeps a
  cloning term in PPO's updates, as DAPG does (Rajeswaran et al. 2018): every minibatch step adds
  ``bc_weight * bc_decay**k`` times the gradient of the clone's loss on a minibatch of demonstrations,
  ``k`` the PPO iteration, so the demonstrations hold the actor early and fade out
  (:func:`cloning_term`).

Each seed trains in ``--work/<task>/<algo>/s<seed>`` and saves the model, VecNormalize's statistics and
its learning curve (metric and success on the family's search split, its N_EVAL starts, against env
steps and training wall-clock; the first point is the policy before learning) at every evaluation, so
that a stopped run resumes from its last one. When every
seed is done the row is scored on the sealed test split (the family's ``N_TEST`` starts, the family's
metric) and summarised with rliable: the interquartile mean over the seeds with its 95 %
stratified-bootstrap interval (Agarwal et al. 2021), written to ``--out/<task>/<algo>.json`` with the
curves (``<algo>_curves.png``).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import EngFormatter

ROOT = Path(__file__).resolve().parents[1]
TASKS = {
    "rendezvous": "rendezvous",
    "docking": "docking+cbf",
    "docking-constrained": "docking-constrained+cbf",
}
ALGOS = ("ppo", "sac", "residual-ppo", "bc-ppo")
BOOTSTRAP_REPS = 2000  # rliable's stratified bootstrap resamples (its examples use 2000 to 50000)
BOOTSTRAP_SEED = 0
SMOKE_STARTS = 8  # --smoke: the starts each split is scored on (plumbing only)
# recipe()'s keys, in a curve's first point
RECIPE_KEYS = (
    "critic_warmup",
    "reward",
    "log_std_init",
    "learning_rate",
    "lr_anneal",
    "bc_weight",
    "bc_decay",
)
# a seed's checkpoint, in its work directory; REPLAY: an off-policy row's replay buffer, which SB3's
# model.save leaves out and without which a resumed SAC would learn from an empty buffer
MODEL, STATISTICS, REPLAY = "model.zip", "vecnormalize.pkl", "replay.pkl"
METRIC_FLOOR = 1e-9  # the curves are on a log axis: a metric below this is drawn at it (the laws reach ~1e-7)


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", choices=sorted(TASKS), required=True)
    parser.add_argument("--algo", choices=ALGOS, required=True)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--timesteps", type=int, default=1_000_000, help="env steps per seed")
    parser.add_argument("--eval-every", type=int, default=None, help="env steps between curve points")
    parser.add_argument("--residual-scale", type=float, default=0.2, help="residual-ppo: the bound, of u_max")
    parser.add_argument("--bc-epochs", type=int, default=20, help="bc-ppo: cloning passes over the demos")
    parser.add_argument(
        "--critic-warmup",
        type=int,
        default=100_000,
        help="bc-ppo: env steps that train the value function alone, the cloned actor frozen",
    )
    parser.add_argument(
        "--bc-weight",
        type=float,
        default=0.0,
        help="bc-ppo: the cloning term's weight in PPO's updates at the first iteration (DAPG's lambda_0; 0: none)",
    )
    parser.add_argument(
        "--bc-decay",
        type=float,
        default=0.95,
        help="bc-ppo: the cloning term's weight is multiplied by this every PPO iteration (DAPG's lambda_1)",
    )
    parser.add_argument(
        "--reward",
        nargs="+",
        default=[],
        metavar="NAME=VALUE",
        help="the env's reward weights where not its defaults (its keyword arguments, e.g. terminal_weight=10)",
    )
    parser.add_argument(
        "--log-std-init", type=float, default=None, help="the policy's initial log std (the zoo's: -2)"
    )
    parser.add_argument(
        "--learning-rate",
        type=float,
        default=None,
        help="the optimiser's learning rate where not the algo's (the zoo's: 3e-4 for PPO); with --lr-anneal, "
        "where the schedule starts",
    )
    parser.add_argument(
        "--lr-anneal",
        action="store_true",
        help="the learning rate annealed linearly to 0 over --timesteps (the zoo's lin_ schedules), not held; "
        "a longer budget resumed stretches the rest of it from where the run stands",
    )
    parser.add_argument(
        "--tag", default=None, help="a recipe's name beside the algo's: work and results under <algo>-<tag>"
    )
    parser.add_argument("--work", type=Path, default=ROOT / "runs" / "rl-baselines")
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "rl-baselines")
    parser.add_argument(
        "--smoke",
        action="store_true",
        help="2,048 steps, small rollouts, SMOKE_STARTS starts a split: plumbing only",
    )
    args = parser.parse_args(argv)
    if args.smoke:
        args.timesteps = min(args.timesteps, 2_048)
    if args.timesteps < 1:
        parser.error("--timesteps must be >= 1")
    if args.learning_rate is not None and not 0 < args.learning_rate < float("inf"):
        parser.error(f"--learning-rate must be a positive finite number, got {args.learning_rate}")
    if not (np.isfinite(args.bc_weight) and args.bc_weight >= 0):
        parser.error(f"--bc-weight must be a finite number >= 0, got {args.bc_weight}")
    if not 0 < args.bc_decay <= 1:
        parser.error(f"--bc-decay must be in (0, 1], got {args.bc_decay}")
    if args.bc_weight and args.algo != "bc-ppo":
        parser.error(f"--bc-weight keeps a cloning term: only bc-ppo has a clone, not {args.algo}")
    args.reward = _weights(parser, args.reward)
    if args.tag is not None and not args.tag.replace("-", "").isalnum():
        parser.error(f"--tag must be letters, digits and '-', got {args.tag!r}")
    args.label = args.algo if args.tag is None else f"{args.algo}-{args.tag}"
    args.eval_every = args.eval_every or max(1, args.timesteps // 10)
    return args


def _weights(parser, pairs: list[str]) -> dict:
    """``--reward``'s NAME=VALUE pairs as floats (the env checks the names and signs: a clear error)."""
    weights = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        try:
            weights[name] = float(value)
        except ValueError:
            sep = ""
        if not (sep and name):
            parser.error(f"--reward takes NAME=VALUE pairs with a number, got {pair!r}")
    return weights


def recipe(args: argparse.Namespace) -> dict:
    """What a seed's checkpoint was trained with beyond the algo's defaults; a resumed run must ask
    for the same (:func:`train_seed`)."""
    out = {"critic_warmup": args.critic_warmup} if args.algo == "bc-ppo" and args.critic_warmup else {}
    if args.reward:
        out["reward"] = args.reward
    if args.log_std_init is not None:
        out["log_std_init"] = args.log_std_init
    if args.learning_rate is not None:
        out["learning_rate"] = args.learning_rate
    if args.lr_anneal:
        out["lr_anneal"] = True
    if args.bc_weight:
        out |= {"bc_weight": args.bc_weight, "bc_decay": args.bc_decay}
    return out


def _sb3_compare():
    spec = importlib.util.spec_from_file_location("sb3_compare", ROOT / "examples" / "sb3_compare.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class Row:
    """One (task, algo): how its envs, model and base law are built (module docstring)."""

    def __init__(self, args: argparse.Namespace):
        self.args, self.sb3 = args, _sb3_compare()
        self.name = TASKS[args.task]
        self.problem_spec = {"name": self.name, **self.sb3.PROBLEMS[self.name]}
        self.family = self.sb3.load_family(args.task)
        self.kind = "sac" if args.algo == "sac" else "ppo"
        self._check_reward(args.reward)

    def _check_reward(self, reward: dict) -> None:
        """Only the env's reward weights: its other keyword arguments would change the problem."""
        import dataclasses

        from cwh_envs.core import DockingReward, RendezvousReward

        weights = DockingReward if self.family.TASK == "docking" else RendezvousReward
        names = {f.name for f in dataclasses.fields(weights)}
        if unknown := sorted(set(reward) - names):
            raise ValueError(f"--reward: {unknown} are not reward weights of the env; it has {sorted(names)}")
        weights(**reward)  # its own check of each value (finite, >= 0)

    def base(self):
        """The law the residual corrects: the routed law where the problem has a cone, else the
        closed-form minimum-energy law on the problem without path constraints."""
        from cwh_envs.controllers import MinEnergyFeedback, WaypointFeedback

        problem = self.family.PROBLEM
        if getattr(problem, "approach_cone", None) is not None:
            return WaypointFeedback(problem)
        plain = (
            problem.replace(speed_limit=None, approach_cone=None)
            if self.family.TASK == "docking"
            else problem
        )
        return MinEnergyFeedback(plain)

    def envs(self, seed: int, n_envs: int):
        from cwh_envs.sb3 import ResidualVecEnv

        pool = self.sb3.SMOKE_POOL if self.args.smoke else self.sb3.START_POOL
        namespace = argparse.Namespace(start_pool=pool, vec_env="native", seed=seed)
        venv = self.sb3.training_envs(self.problem_spec, self.family, n_envs, namespace, self.args.reward)
        if self.args.algo == "residual-ppo":
            venv = ResidualVecEnv(venv, self.base(), self.args.residual_scale)
        return venv

    def params(self) -> dict:
        params = dict(self.sb3.HYPERPARAMS[self.kind][self.problem_spec["family"]])
        if self.args.smoke:
            params |= self.sb3.SMOKE[self.kind]
        if self.args.log_std_init is not None:
            params["policy_kwargs"] = {**params["policy_kwargs"], "log_std_init": self.args.log_std_init}
        if self.args.learning_rate is not None:
            params["learning_rate"] = self.args.learning_rate
        return params

    def eval_set(self, split: str, dispersed: bool = True):
        """The family's evaluation on ``split``, through the filter the row trains with; --smoke scores
        only the first SMOKE_STARTS starts (a cold cache builds constrained experts' sets slowly)."""
        count = SMOKE_STARTS if self.args.smoke else None
        return self.sb3.EvalSet(
            self.family, self.problem_spec["cbf"], split, dispersed=dispersed, count=count
        )

    def load(self, work: Path, venv):
        """The checkpoint in ``work``: the model, and VecNormalize's statistics wrapped around ``venv``."""
        from stable_baselines3.common.vec_env import VecNormalize

        normalizer = VecNormalize.load(str(work / STATISTICS), venv)
        model = self.sb3.ALGOS[self.kind].load(work / MODEL, env=normalizer, device="cpu")
        if hasattr(model, "load_replay_buffer"):
            model.load_replay_buffer(work / REPLAY)
        return model, normalizer

    def policy(self, model, normalizer):
        """The trained row as a policy on observations (deterministic; the base added back for a residual)."""
        from cwh_envs.sb3 import residual_policy

        def correction(obs: np.ndarray) -> np.ndarray:
            action, _ = model.predict(normalizer.normalize_obs(obs), deterministic=True)
            return np.clip(action.astype(np.float64), -1.0, 1.0)

        if self.args.algo == "residual-ppo":
            return residual_policy(self.base(), correction, self.args.residual_scale)
        return correction


def demonstration_pairs(family) -> tuple[np.ndarray, np.ndarray]:
    """The family's demonstrations as the env sees them: observations, and actions (thrust / u_max)."""
    from cwh_envs.datasets import demonstrations

    demos = demonstrations(family.TASK, family.POOL_DEMOS, seed=0, problem=family.PROBLEM)
    return demos.observations.astype(np.float32), np.clip(demos.actions / family.PROBLEM.u_max, -1.0, 1.0)


def cloning_loss(policy, x, y):
    """The clone's loss: the squared error of the actor's mean on normalised observations ``x``."""
    latent = policy.mlp_extractor.forward_actor(policy.extract_features(x, policy.pi_features_extractor))
    return ((policy.action_net(latent) - y) ** 2).mean()


def clone_into(model, normalizer, family, epochs: int, seed: int) -> dict:
    """bc-ppo: VecNormalize's observation statistics from the family's demonstrations, then the actor's
    mean fitted to their actions (MSE, Adam), so that PPO starts from the clone. Returns the fit's loss."""
    import torch

    from cwh_envs.sb3 import FixedStatistics

    obs, actions = demonstration_pairs(family)
    normalizer.obs_rms = FixedStatistics.of(obs.mean(axis=0), obs.var(axis=0) + 1e-8, float(len(obs)))
    policy = model.policy
    x = torch.as_tensor(normalizer.normalize_obs(obs), dtype=torch.float32)
    y = torch.as_tensor(actions, dtype=torch.float32)
    parameters = list(policy.mlp_extractor.policy_net.parameters()) + list(policy.action_net.parameters())
    optimiser = torch.optim.Adam(parameters, lr=1e-3)
    generator = torch.Generator().manual_seed(seed)
    loss = torch.tensor(float("nan"))
    for _ in range(epochs):
        for batch in torch.randperm(len(x), generator=generator).split(256):
            loss = cloning_loss(policy, x[batch], y[batch])
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
    return {"bc_loss": loss.item(), "bc_pairs": len(x)}


def cloning_term(model, normalizer, family, weight: float, decay: float, seed: int):
    """--bc-weight: DAPG's augmented gradient (Rajeswaran et al. 2018) on SB3's PPO, through the
    optimiser's own step pre-hook (PPO's loss is built inside its ``train``): before every minibatch
    step, the gradient of ``weight * decay**k`` times the clone's loss on a minibatch of
    demonstrations (PPO's batch size) is added to PPO's, ``k`` the PPO iteration (env steps so far
    over the rollout's size), so that a resumed run continues the schedule. The term is added after
    PPO's gradient-norm clip, and not while the actor is frozen (the critic's warm-up). DAPG weights
    it by the batch's largest advantage as well; here the weight alone sets its scale. Returns the
    hook's handle."""
    import torch

    obs, actions = demonstration_pairs(family)
    # the statistics the clone was fitted with: held fixed (FixedStatistics), so x stays valid
    x = torch.as_tensor(normalizer.normalize_obs(obs), dtype=torch.float32)
    y = torch.as_tensor(actions, dtype=torch.float32)
    policy, per_iteration = model.policy, model.n_steps * model.n_envs
    generator = torch.Generator().manual_seed(seed)

    def add_cloning_gradient(optimizer, args, kwargs) -> None:
        if not policy.action_net.weight.requires_grad:
            return
        batch = torch.randint(len(x), (model.batch_size,), generator=generator)
        (
            weight
            * decay ** (model.num_timesteps // per_iteration)
            * cloning_loss(policy, x[batch], y[batch])
        ).backward()

    return policy.optimizer.register_step_pre_hook(add_cloning_gradient)


def actor_parameters(model) -> list:
    """The parameters that make PPO's action distribution: the actor's layers and its log std."""
    policy = model.policy
    return [*policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters(), policy.log_std]


def anneal(model, start: float, budget: int, chunk: int) -> None:
    """--lr-anneal: the learning rate falls linearly from ``start`` at step 0 to 0 at ``budget``.

    SB3's progress runs from 1 to 0 over each ``learn()`` call, and a row calls it once per curve point
    (and again on resuming); so before each call the schedule is set again, on the whole budget: SB3
    counts the call's total as the steps already taken plus ``chunk`` (``reset_num_timesteps=False``)."""
    total = model.num_timesteps + chunk

    def rate(progress_remaining: float) -> float:
        return start * max(0.0, 1.0 - (1.0 - progress_remaining) * total / budget)

    model.lr_schedule = rate


def zero_residual(model) -> None:
    """residual-ppo: the policy's mean starts at zero, so the row starts as the base law (the residual
    RL practice of Silver et al. 2018; SB3 initialises the action layer at random)."""
    import torch

    with torch.no_grad():
        model.policy.action_net.weight.zero_()
        model.policy.action_net.bias.zero_()


def train_seed(row: Row, seed: int) -> dict:
    """Train (or resume) one seed to the budget; its curve points. Every evaluation saves a checkpoint."""
    from stable_baselines3.common.vec_env import VecNormalize

    args = row.args
    work = args.work / args.task / args.label / f"s{seed}"
    work.mkdir(parents=True, exist_ok=True)
    curve_path, model_path, stats_path = work / "curve.jsonl", work / MODEL, work / STATISTICS
    params = row.params()
    n_envs, normalize = params.pop("n_envs"), params.pop("normalize")
    venv = row.envs(seed, n_envs)
    algo = row.sb3.ALGOS[row.kind]
    points = [json.loads(line) for line in curve_path.read_text().splitlines()] if curve_path.exists() else []
    extra = recipe(args)
    if points and (trained := {k: points[0][k] for k in RECIPE_KEYS if k in points[0]}) != extra:
        raise SystemExit(
            f"{work}: trained with {trained or 'the defaults'}, asked for {extra or 'the defaults'}: "
            "remove the directory to train it again, or ask for the same"
        )
    if model_path.exists() and stats_path.exists():
        model, normalizer = row.load(work, venv)
        spent = points[-1]["train_seconds"] if points else 0.0
    else:
        normalizer = VecNormalize(venv, gamma=params["gamma"], **normalize)
        model = algo("MlpPolicy", normalizer, seed=seed, device="cpu", **params)
        spent, points = 0.0, []
        if args.algo == "bc-ppo":
            extra = {**clone_into(model, normalizer, row.family, args.bc_epochs, seed), **extra}
        if args.algo == "residual-ppo":
            zero_residual(model)
    if args.bc_weight:  # on the optimiser a loaded model has just made, too
        cloning_term(model, normalizer, row.family, args.bc_weight, args.bc_decay, seed)
    warmup = args.critic_warmup if args.algo == "bc-ppo" else 0
    evaluate = row.eval_set("search", dispersed=False)
    while model.num_timesteps < args.timesteps or not points:
        # the first point is the policy before learning (the base law, the clone): where RL starts
        chunk = min(args.eval_every, args.timesteps - model.num_timesteps) if points else 0
        warming = model.num_timesteps < warmup
        if warming:  # the critic learns the clone's values before the actor moves (module docstring)
            chunk = min(chunk, warmup - model.num_timesteps)
        if chunk:
            frozen = actor_parameters(model) if warming else []
            for parameter in frozen:
                parameter.requires_grad_(False)
            if args.lr_anneal:
                anneal(model, params["learning_rate"], args.timesteps, chunk)
            started = time.perf_counter()
            model.learn(chunk, reset_num_timesteps=False, progress_bar=False)
            spent += time.perf_counter() - started
            for parameter in frozen:
                parameter.requires_grad_(True)
        normalizer.training = False
        metrics = evaluate(_Act(row.policy(model, normalizer)))
        normalizer.training = True
        point = {
            "timesteps": int(model.num_timesteps),
            "train_seconds": spent,
            "metric": float(metrics[row.family.METRIC]),
            "success_rate": float(metrics["success_rate"]),
            **extra,
        }
        model.save(model_path)
        normalizer.save(str(stats_path))
        if hasattr(model, "save_replay_buffer"):
            model.save_replay_buffer(work / REPLAY)
        with curve_path.open("a", encoding="utf-8") as log:  # appended after the checkpoint it scores
            log.write(json.dumps(point) + "\n")
        points.append(point)
        print(
            f"[{args.task} {args.label} s{seed}] {point['timesteps']:,} steps, {spent:.0f} s: "
            f"{row.family.METRIC} {point['metric']:.4g}, success {point['success_rate']:.1%}",
            flush=True,
        )
    normalizer.training = False
    return {"seed": seed, "curve": points, "policy": row.policy(model, normalizer)}


class _Act:
    """A policy function behind the families' ``act`` interface."""

    def __init__(self, policy):
        self.act = policy


def sealed_score(row: Row, policy) -> dict:
    """The family's metrics of ``policy`` on its sealed test split (every start; --smoke: the first
    SMOKE_STARTS): its metric, success, energy over the expert's (``effort_ratio``) and the dispersed
    success at 1 and 3 sigma, where the family reports them."""
    metrics = row.eval_set("test")(_Act(policy))
    score = {
        key: metrics[key] for key in (row.family.METRIC, "success_rate", "effort_ratio") if key in metrics
    }
    for key in ("dispersed", "dispersed_3sigma"):
        if key in metrics:
            score[f"{key}_success"] = float(metrics[key]["success_rate"])
    return score


def iqm_interval(values: list[float]) -> dict:
    """rliable's interquartile mean over the runs with its 95 % stratified-bootstrap interval (one task)."""
    from rliable import library as rly
    from rliable import metrics as rly_metrics

    scores = {"row": np.asarray(values, dtype=np.float64)[:, None]}  # (runs, tasks)
    # arch (under rliable) still draws part of the interval from numpy's global generator, whatever
    # random_state says (measured: two calls, two lower bounds): seed it too, and put it back after.
    state = np.random.get_state()  # noqa: NPY002 (the global generator is what arch reads)
    np.random.seed(BOOTSTRAP_SEED)  # noqa: NPY002
    try:
        with warnings.catch_warnings():
            # arch 7 deprecates the random_state rliable passes it (a FutureWarning each call): theirs to change
            warnings.filterwarnings("ignore", message="random_state is deprecated", category=FutureWarning)
            point, interval = rly.get_interval_estimates(
                scores,
                lambda x: np.array([rly_metrics.aggregate_iqm(x)]),
                reps=BOOTSTRAP_REPS,
                random_state=np.random.RandomState(BOOTSTRAP_SEED),  # the same interval on every re-summary
            )
    finally:
        np.random.set_state(state)  # noqa: NPY002
    return {
        "iqm": float(point["row"][0]),
        "ci95": [float(interval["row"][0, 0]), float(interval["row"][1, 0])],
    }


def plot(curves: list[dict], metric: str, path: Path, title: str) -> None:
    figure = Figure(figsize=(10, 4), layout="constrained")
    steps, seconds = figure.subplots(1, 2, sharey=True)
    for run in curves:
        x = [p["timesteps"] for p in run["curve"]]
        y = [max(p["metric"], METRIC_FLOOR) for p in run["curve"]]
        steps.plot(x, y, marker=".", label=f"seed {run['seed']}")
        seconds.plot([p["train_seconds"] for p in run["curve"]], y, marker=".")
    steps.set(xlabel="env steps", ylabel=f"{metric}\non the search split (lower is better)", yscale="log")
    steps.xaxis.set_major_formatter(EngFormatter())  # 200k, 1M: raw step counts run into each other
    seconds.set(xlabel="training wall-clock [s] (evaluation excluded)", yscale="log")
    steps.legend(fontsize="small")
    figure.suptitle(title)
    figure.savefig(path, dpi=100)


def main(argv=None) -> None:
    args = parse_args(argv)
    import torch

    torch.set_num_threads(1)
    row = Row(args)
    runs = [train_seed(row, seed) for seed in args.seeds]
    sealed = [sealed_score(row, run.pop("policy")) for run in runs]
    metric = row.family.METRIC
    summary = {
        "task": args.task,
        "algo": args.algo,
        "env_steps": args.timesteps,
        "seeds": args.seeds,
        "split": "test",
        "metric_name": metric,
        "metric_per_seed": [s[metric] for s in sealed],
        "success_per_seed": [s["success_rate"] for s in sealed],
        **{
            f"{key}_per_seed": [s[key] for s in sealed]
            for key in ("effort_ratio", "dispersed_success", "dispersed_3sigma_success")
            if key in sealed[0]
        },
        "train_seconds_per_seed": [run["curve"][-1]["train_seconds"] for run in runs],
        **({"residual_scale": args.residual_scale} if args.algo == "residual-ppo" else {}),
        **({"tag": args.tag} if args.tag else {}),
        **{k: v for k, v in recipe(args).items() if k != "critic_warmup"},
        "smoke": args.smoke,
        "command": "python benchmarks/rl_baselines.py " + " ".join(sys.argv[1:] if argv is None else argv),
    }
    if len(args.seeds) >= 2:
        summary["iqm"] = iqm_interval(summary["metric_per_seed"])
    out = args.out / args.task
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{args.label}.json").write_text(json.dumps({**summary, "curves": runs}, indent=1) + "\n")
    plot(runs, metric, out / f"{args.label}_curves.png", f"{args.task}: {args.label}, {len(runs)} seeds")
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
