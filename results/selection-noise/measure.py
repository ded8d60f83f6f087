"""Selection noise against the size of the search split (issue 37, item 5).

    OMP_NUM_THREADS=1 python results/selection-noise/measure.py --family rendezvous \
        --from results/evidence/rendezvous-gp [--sizes 128 512 1024] [--workers 2] [--limit K]

A search picks its best on the search split, so the number it picks carries the luck of having been
picked there: the audit certifies on the sealed split, and the difference is the selection gap
(rendezvous: r01 read 0.129 on the 128 search starts and 0.199 on the sealed split). A larger
search split shrinks the luck and costs evaluation time in every run. This measures both.

1. The pool: the distinct configurations a campaign ran (``--from``, one or more; parameters the
   family's space has gained since set to the baseline, as ``loop --warm-start`` matches them),
   each trained once here at the family's default seed, as the campaign trained it, scored by its
   train.py on the search split and the sealed test split (``--eval-split test``), its policy saved.
   Runs live in ``OUT/<family>/runs`` and are reused when the script runs again.
2. Every saved policy is scored again on the first N starts of the search split for each size N (the
   split is nested: its first 128 starts are the 128 every search sees), timed.
3. Selection: ``--draws`` times, a search of ``--pool-size`` experiments is drawn from the pool; its
   pick is the best on the N-start search split (feasible first). The gap is the pick's test metric
   minus its search metric, the regret its test metric minus the best test metric in that search
   (how much worse the pick is than what the search could have certified), the hit rate how often it
   is that best. Means with 95 % intervals over the draws, per N, and the cost of scoring N starts.

The recommended size is the smallest N whose mean regret is within 10 % of the smallest mean regret of
all sizes: what a larger split would still buy is smaller than the measurement's own resolution.
Writes OUT/<family>.json and OUT/<family>.md (OUT: results/selection-noise).
"""

from __future__ import annotations

import argparse
import inspect
import json
import math
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from autoresearch.audit.inputs import config_id
from autoresearch.execution.executors import LocalExecutor
from autoresearch.execution.spec import RunSpec
from autoresearch.family import Family
from autoresearch.journal import read_jsonl
from autoresearch.loop.warm_start import WarmStart
from autoresearch.splits import Split
from cwh_envs.datasets import evaluation_set
from cwh_envs.prepare import load_train

REPO = Path(__file__).resolve().parents[2]
TOLERANCE = 0.10  # a size within 10 % of the best mean regret is as good as the measurement can tell


def pool_configs(family: Family, campaigns: list[str], limit: int | None) -> list[dict]:
    """The distinct configurations the campaigns ran, in the family's current space."""
    warm = WarmStart.load(campaigns, family, family.space)
    configs = {config_id(run.outcome.config): run.outcome.config for run in warm.runs}
    return list(configs.values())[:limit]


def train_pool(family: Family, configs: list[dict], root: Path, workers: int, timeout: float) -> list[dict]:
    """Each configuration trained once at the default seed, scored on both splits; a run already in
    the pool's runs.jsonl (an earlier invocation) is reused."""
    runs_log = (root / "runs.jsonl").resolve()
    logged = {line.get("run_id"): line for line in read_jsonl(runs_log) if isinstance(line, dict)}

    def one(config: dict) -> dict:
        run_id = config_id(config)
        if run_id in logged:
            return {"run_id": run_id, "config": config, "final_metric": logged[run_id]}
        run_dir = (root / run_id).resolve()
        shutil.rmtree(run_dir, ignore_errors=True)  # an attempt that did not finish: run it again
        spec = RunSpec(family, config, run_id, family.default_seed, run_dir, runs_log, timeout, Split.TEST)
        result = LocalExecutor(1).run(spec)
        if not result.ok:
            print(f"[selection-noise] {run_id} failed and is left out: {result.reason}", file=sys.stderr)
        return {"run_id": run_id, "config": config, "final_metric": result.final_metric}

    return [d for d in LocalExecutor(workers).map(one, configs) if d["final_metric"] is not None]


def scorer(train):
    """The family's evaluate(policy, held_out) for a configuration (the docking families' take its filter)."""
    params = inspect.signature(train.evaluate).parameters

    def score(policy, config: dict, held_out) -> dict:
        if not hasattr(train, "safety_filter") and "cbf" not in params:  # rendezvous: no filter
            return train.evaluate(policy, held_out)
        extra = {"dispersed": False} if "dispersed" in params else {}  # an auxiliary: not the metric
        # the recipe's filter as the family flies it (the robust one included, where it has the lever)
        safety = (
            train.safety_filter(config) if hasattr(train, "safety_filter") else config["RUNTIME_CBF_FILTER"]
        )
        return train.evaluate(policy, held_out, safety, **extra)

    return score


def rescore(family: Family, runs: list[dict], root: Path, sizes: list[int]) -> dict[int, float]:
    """Each run's metric and feasibility on the first N search starts, for every N; the mean seconds a
    scoring of N starts took."""
    train = load_train(family.path)
    score = scorer(train)
    search = evaluation_set(train.TASK, max(sizes), problem=train.PROBLEM, split="search")
    seconds = {n: [] for n in sizes}
    for run in runs:
        policy, _ = train.load_policy(root / run["run_id"] / "out" / "policy.pt")
        final = run["final_metric"]
        run["test"] = (final["splits"]["test"][family.metric], family.is_feasible(final["splits"]["test"]))
        run["search"] = {}
        for n in sizes:
            started = time.perf_counter()
            metrics = score(policy, run["config"], search.take(n))
            seconds[n].append(time.perf_counter() - started)
            run["search"][n] = (metrics[family.metric], family.is_feasible(metrics))
        recorded = final["splits"]["search"][family.metric]
        if train.N_EVAL in run["search"] and not math.isclose(
            run["search"][train.N_EVAL][0], recorded, rel_tol=1e-6
        ):
            raise RuntimeError(
                f"{run['run_id']}: scored {run['search'][train.N_EVAL][0]} again, {recorded} in training"
            )
    return {n: float(np.mean(s)) for n, s in seconds.items()}


def select(runs: list[dict], n: int, sign: int) -> dict:
    """A search's pick on the N-start search split (feasible first), against the pool's best on test."""
    pick = min(runs, key=lambda r: (not r["search"][n][1], -sign * r["search"][n][0]))
    feasible_test = [r["test"][0] for r in runs if r["test"][1]] or [r["test"][0] for r in runs]
    best_test = min(feasible_test, key=lambda v: -sign * v)
    return {
        "gap": -sign * (pick["test"][0] - pick["search"][n][0]),
        "regret": -sign * (pick["test"][0] - best_test),
        "hit": pick["test"][0] == best_test,
    }


def interval(values: list[float]) -> list[float]:
    return [float(np.percentile(values, 2.5)), float(np.percentile(values, 97.5))]


def analyse(runs: list[dict], sizes: list[int], sign: int, pool_size: int, draws: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    k = min(pool_size, len(runs))
    picks = [rng.choice(len(runs), size=k, replace=False) for _ in range(draws)]
    out = {}
    for n in sizes:
        chosen = [select([runs[i] for i in pick], n, sign) for pick in picks]
        whole = select(runs, n, sign)
        out[n] = {
            "mean_gap": float(np.mean([c["gap"] for c in chosen])),
            "gap_95": interval([c["gap"] for c in chosen]),
            "mean_regret": float(np.mean([c["regret"] for c in chosen])),
            "regret_95": interval([c["regret"] for c in chosen]),
            "hit_rate": float(np.mean([c["hit"] for c in chosen])),
            "whole_pool": whole,
        }
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--family", required=True, help="a family under families/")
    parser.add_argument(
        "--from", dest="campaigns", nargs="+", required=True, help="campaigns whose runs make the pool"
    )
    parser.add_argument("--sizes", type=int, nargs="+", default=[128, 512, 1024])
    parser.add_argument("--pool-size", type=int, default=20, help="experiments in one simulated search")
    parser.add_argument("--draws", type=int, default=2000)
    parser.add_argument("--limit", type=int, help="train only the first K configurations (a smoke run)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--timeout", type=float, default=3600.0, help="per training run, s")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=REPO / "results" / "selection-noise")
    args = parser.parse_args()
    family = Family.load(REPO / "families" / args.family)
    sizes = sorted(set(args.sizes))
    root = args.out / args.family / "runs"
    root.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    configs = pool_configs(family, args.campaigns, args.limit)
    print(f"[selection-noise] {args.family}: {len(configs)} configurations from {', '.join(args.campaigns)}")
    runs = train_pool(family, configs, root, args.workers, args.timeout)
    if len(runs) < 2:
        print(
            "[selection-noise] fewer than two trained configurations: nothing to select from", file=sys.stderr
        )
        return 2
    seconds = rescore(family, runs, root, sizes)
    sign = family.direction
    results = analyse(runs, sizes, sign, args.pool_size, args.draws, args.seed)
    best_regret = min(r["mean_regret"] for r in results.values())
    recommended = next(n for n in sizes if results[n]["mean_regret"] <= best_regret * (1 + TOLERANCE) + 1e-12)
    summary = {
        "family": args.family,
        "campaigns": args.campaigns,
        "pool": len(runs),
        "pool_size": min(args.pool_size, len(runs)),
        "draws": args.draws,
        "metric": family.metric,
        "sizes": {str(n): {**results[n], "eval_seconds_per_run": seconds[n]} for n in sizes},
        "recommended_size": recommended,
        "rule": f"the smallest size whose mean regret is within {TOLERANCE:.0%} of the smallest",
        "wall_seconds": round(time.perf_counter() - started, 1),
        "runs": [
            {
                "run_id": r["run_id"],
                "config": r["config"],
                "test": r["test"],
                "search": {str(n): r["search"][n] for n in sizes},
            }
            for r in runs
        ],
    }
    (args.out / f"{args.family}.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    lines = [
        f"# Selection noise against the search split's size: {args.family}",
        "",
        f"`python results/selection-noise/measure.py --family {args.family} --from {' '.join(args.campaigns)}`: "
        f"{len(runs)} configurations trained once at the default seed; {args.draws} searches of "
        f"{summary['pool_size']} drawn from them; {family.metric}, in the family's units.",
        "",
        "| search starts | mean gap (test - search) [95 %] | mean regret [95 %] | pick is the test-best | "
        "scoring seconds per run |",
        "|---|---|---|---|---|",
    ]
    for n in sizes:
        r = results[n]
        lines.append(
            f"| {n} | {r['mean_gap']:.4g} [{r['gap_95'][0]:.3g}, {r['gap_95'][1]:.3g}] | {r['mean_regret']:.4g} "
            f"[{r['regret_95'][0]:.3g}, {r['regret_95'][1]:.3g}] | {r['hit_rate']:.0%} | {seconds[n]:.3f} |"
        )
    lines += ["", f"Recommended: {recommended} search starts ({summary['rule']})."]
    (args.out / f"{args.family}.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
