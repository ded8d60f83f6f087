"""Audit wall time with 2 workers vs 1, and the Ray executor's overhead per task.

Runs on autoresearch/templates/minimal with a sleep-dominated train.py (TOY_SLEEP_S), so the numbers measure
the executor, not the machine's arithmetic. Usage:

    .venv/bin/python benchmarks/bench_audit.py [--sleep 0.3] [--ray-tasks 40]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

from autoresearch.audit.inputs import open_campaign
from autoresearch.audit.noise import measure_noise
from autoresearch.audit.prune import prune
from autoresearch.audit.random_arm import run_random_arm
from autoresearch.audit.trials import Trial, run_trials
from autoresearch.audit.verify import verify
from autoresearch.execution.executors import Executor, LocalExecutor
from autoresearch.family import Family
from autoresearch.journal import read_jsonl, write_json_atomic
from autoresearch.loop.orchestrator import LoopSettings, Orchestrator
from autoresearch.loop.stopping import Budgets
from autoresearch.proposers.random_search import RandomProposer

TOY = Path(__file__).resolve().parents[1] / "autoresearch" / "templates" / "minimal"
ITERATIONS, NOISE_SEEDS, TOP, SEEDS = 8, 6, 2, 6


def make_campaign(where: Path, iterations: int = ITERATIONS) -> Path:
    """A private toy family and a random-search campaign of up to ``iterations`` iterations on it."""
    shutil.copytree(TOY, where / "family", ignore=shutil.ignore_patterns("runs.jsonl*", "__pycache__"))
    family = Family.load(where / "family")
    root = where / "campaign"
    root.mkdir()
    meta = {"family": str(family.path), "family_name": family.name, "proposer": "random"}
    write_json_atomic(root / "campaign.json", {**meta, "settings": {"timeout_per_run": 120.0, "seed": 0}})
    budgets = Budgets(max_iters=iterations, plateau_window=10**6)
    Orchestrator(family, RandomProposer(family.registry, 0), root, LoopSettings("random", budgets)).run()
    return root


def audit(root: Path, executor: Executor) -> tuple[float, int]:
    """(wall seconds, runs) of noise, verify, prune and the random arm."""
    started = time.monotonic()
    measure_noise(open_campaign(root).family, executor, k=NOISE_SEEDS, campaign=open_campaign(root))
    verify(open_campaign(root), executor, top=TOP, n_seeds=SEEDS)
    prune(open_campaign(root), executor)
    run_random_arm(open_campaign(root), executor)
    wall = time.monotonic() - started
    logs = [*(root / "audit").glob("*/*.jsonl"), root.parent / f"{root.name}-random" / "trials.jsonl"]
    return wall, sum(len(read_jsonl(log)) for log in logs if log.name != "runs.jsonl")


def audit_walls(roots: dict[int, Path], sleep: float) -> dict[int, tuple[float, int]]:
    """{workers: audit() of roots[workers]} with a local executor, train.py sleeping ``sleep`` s."""
    os.environ["TOY_SLEEP_S"] = str(sleep)
    try:
        return {w: audit(root, LocalExecutor(w)) for w, root in roots.items()}
    finally:
        os.environ["TOY_SLEEP_S"] = "0"


def ray_overhead(where: Path, n_tasks: int) -> tuple[float, float, float] | None:
    """(Ray start-up s, local s/task, Ray s/task), one worker each, train.py without sleep."""
    try:
        import ray  # noqa: F401  (the optional extra)
    except ImportError:
        return None
    from autoresearch.execution.ray_executor import RayExecutor

    family = Family.load(where / "family")
    trials = [Trial(f"t{i}", family.baseline_config, i) for i in range(n_tasks)]

    def timed(executor: Executor, name: str) -> float:
        started = time.monotonic()
        run_trials(family, trials, executor, where / f"{name}.jsonl", where / name, 60)
        return time.monotonic() - started

    local = timed(LocalExecutor(1), "local")
    started = time.monotonic()
    with RayExecutor(workers=1) as executor:
        startup = time.monotonic() - started
        run_trials(family, trials[:1], executor, where / "warm.jsonl", where / "warm", 60)  # worker start-up
        remote = timed(executor, "ray")
    return startup, local / n_tasks, remote / n_tasks


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sleep", type=float, default=0.3, help="seconds each toy training run sleeps")
    parser.add_argument("--ray-tasks", type=int, default=40, help="tasks for the Ray overhead measurement")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        roots = {w: make_campaign(Path(tempfile.mkdtemp(dir=tmp))) for w in (1, 2)}
        results = audit_walls(roots, args.sleep)
        ray = ray_overhead(roots[1].parent, args.ray_tasks)
    print(
        f"audit of a {ITERATIONS}-experiment toy campaign (noise K={NOISE_SEEDS}, verify top {TOP} x {SEEDS} "
        f"seeds, prune, random arm); train.py sleeps {args.sleep:g} s per run; {os.cpu_count()} cores"
    )
    print()
    print("| executor | workers | runs | wall (s) | vs 1 worker |")
    print("|---|---|---|---|---|")
    base = results[1][0]
    for workers, (wall, runs) in results.items():
        print(f"| local | {workers} | {runs} | {wall:.1f} | {wall / base:.2f}x |")
    print()
    if ray is None:
        print("Ray: not installed (pip install 'cwh-autoresearch[ray]')")
    else:
        startup, local, remote = ray
        print(f"| Ray, local instance, 1 worker ({args.ray_tasks} tasks, no sleep) | seconds |")
        print("|---|---|")
        print(f"| start-up (ray.init) | {startup:.2f} |")
        print(f"| per task, local executor | {local:.3f} |")
        print(f"| per task, Ray executor | {remote:.3f} |")
        print(f"| Ray overhead per task | {remote - local:+.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
