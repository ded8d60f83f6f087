"""What the sealed test split costs: building it once, and scoring a policy on it in every audit run.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_evaluation.py [--repeats 5]

For each family: the cold build of each evaluation split into an empty cache (expert solves and
the disjointness checks), then the family's own ``evaluate`` (cwh_envs.rollout through the env's
core; docking with the CBF filter) of the hand recipe's architecture, freshly initialised (the
cost of a forward pass does not depend on the weights), on the 128 search starts and on the 1024
test starts. Median of ``--repeats`` timings; the ratio is test over search. Prints a Markdown
table.
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import torch

from cwh_envs.datasets import evaluation_set
from cwh_envs.prepare import load_train

ROOT = Path(__file__).resolve().parents[1]
HAND = {  # the hand recipes' networks (results/*/hand_recipe.json): the largest the audits fly
    "rendezvous": {"HIDDEN_DIM": 256, "N_LAYERS": 4, "ACTIVATION": "gelu"},
    "docking": {"HIDDEN_DIM": 256, "N_LAYERS": 4, "ACTIVATION": "gelu"},
}


def timed(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        fn()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    torch.set_num_threads(1)  # as the families train and evaluate
    rows = []
    for name in ("rendezvous", "docking"):
        train = load_train(ROOT / "families" / name)
        builds = {}
        for split, n in (("search", train.N_EVAL), ("test", train.N_TEST)):
            with tempfile.TemporaryDirectory() as cache:
                started = time.perf_counter()
                evaluation_set(train.TASK, n, problem=train.PROBLEM, cache_dir=cache, split=split)
                builds[split] = time.perf_counter() - started
        config = {**{k: getattr(train, k) for k in train.CONFIG_NAMES}, **HAND[name]}
        policy = train.build_policy(config).eval()
        cbf = () if name == "rendezvous" else (True,)
        scores = {}
        for split, n in (("search", train.N_EVAL), ("test", train.N_TEST)):
            held_out = evaluation_set(train.TASK, n, problem=train.PROBLEM, split=split)
            scores[split] = timed(functools.partial(train.evaluate, policy, held_out, *cbf), args.repeats)
        rows.append((name, train.N_EVAL, builds, scores))
    print(
        f"Python {platform.python_version()}, torch {torch.__version__}, OMP_NUM_THREADS="
        f"{os.environ.get('OMP_NUM_THREADS')}, median of {args.repeats}\n"
    )
    sizes = sorted({n for _, n, _, _ in rows})  # the families' N_EVAL
    print(
        f"| family | build search ({'/'.join(map(str, sizes))}) | build test (1024) | evaluate search "
        "| evaluate test | test / search |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for name, _, builds, scores in rows:
        print(
            f"| {name}{' (CBF on)' if name == 'docking' else ''} | {builds['search']:.2f} s | {builds['test']:.2f} s "
            f"| {scores['search']:.3f} s | {scores['test']:.3f} s | {scores['test'] / scores['search']:.1f}x |"
        )


if __name__ == "__main__":
    main()
