"""Campaign and audit wall time against Ray workers, and Ray's overhead per run in each file mode.

    .venv/bin/python benchmarks/bench_ray_scaling.py [--workers 1 2 4] [--sleep 1.0] [--tasks 30]

On the minimal template, patched to print a four-point learning curve, with a sleep-dominated
train.py (``--sleep`` seconds a run, plus 4 x 0.1 s between its PROGRESS points), so the numbers
measure the executor and the scheduling, not this machine's arithmetic: on 2 cores, 4 sleeping
runs overlap as 4 training runs on 4 cores would.

- Scaling: for each worker count, a fresh local Ray instance of that many CPUs, one campaign
  (random search, ``--iters`` experiments, ``--early-stop median``) and one audit of it (seed noise
  K=8 and reseeded verification of the best at 8 seeds), each as a ratio to 1 worker.
- Overhead: ``--tasks`` runs without sleep, one at a time, locally and as Ray tasks with the family
  shipped (``--ray-files ship``) and read in place (``shared``); seconds per run.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

from autoresearch.audit.inputs import open_campaign
from autoresearch.audit.noise import measure_noise
from autoresearch.audit.trials import Trial, run_trials
from autoresearch.audit.verify import verify
from autoresearch.campaign import CampaignMeta
from autoresearch.execution.executors import Executor, LocalExecutor
from autoresearch.family import Family
from autoresearch.loop.orchestrator import LoopSettings, Orchestrator
from autoresearch.loop.stopping import Budgets
from autoresearch.proposers.random_search import RandomProposer
from autoresearch.templates import MINIMAL_TEMPLATE

CURVE = (
    "    for step in range(1, 5):  # a learning curve ending at the final loss\n"
    '        print("PROGRESS: " + json.dumps({"step": step, "loss": loss * (2 - step / 4)}), flush=True)\n'
    "        time.sleep(0.1)\n"
)


def progress_family(where: Path) -> Family:
    target = where / "family"
    shutil.copytree(MINIMAL_TEMPLATE, target, ignore=shutil.ignore_patterns("runs.jsonl*", "__pycache__"))
    train = target / "train.py"
    anchor = "    noise = random.Random(seed)"
    train.write_text(train.read_text().replace(anchor, CURVE + anchor, 1))
    return Family.load(target)


def campaign_and_audit(family: Family, root: Path, executor: Executor, iters: int) -> tuple[float, float]:
    """(campaign wall s, audit wall s) with ``executor``."""
    settings = LoopSettings(
        "random",
        Budgets(max_iters=iters, plateau_window=10**6),
        timeout_per_run=120.0,
        workers=executor.workers,
        early_stop="median",
    )
    root.mkdir(parents=True)
    CampaignMeta(
        str(family.path), family.name, "random", {"timeout_per_run": 120.0, "seed": 0}, "bench"
    ).write(root)
    started = time.monotonic()
    Orchestrator(family, RandomProposer(family.registry, 0), root, settings, executor=executor).run()
    campaign = time.monotonic() - started
    started = time.monotonic()
    measure_noise(family, executor, k=8, campaign=open_campaign(root))
    verify(open_campaign(root), executor, top=1, n_seeds=8)
    return campaign, time.monotonic() - started


def overhead(family: Family, where: Path, tasks: int) -> dict[str, float]:
    """Seconds per run, one at a time: locally, and on Ray in each file mode."""
    from autoresearch.execution.ray_executor import RayExecutor

    trials = [Trial(f"t{i}", family.baseline_config, i) for i in range(tasks)]

    def per_run(executor: Executor, name: str) -> float:
        run_trials(family, trials[:1], executor, where / f"{name}-warm.jsonl", where / f"{name}-warm", 60)
        started = time.monotonic()
        run_trials(family, trials, executor, where / f"{name}.jsonl", where / name, 60)
        return (time.monotonic() - started) / tasks

    out = {"local": per_run(LocalExecutor(1), "local")}
    for files in ("ship", "shared"):
        with RayExecutor(workers=1, files=files) as executor:
            out[files] = per_run(executor, files)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--sleep", type=float, default=1.0, help="seconds each training run sleeps")
    parser.add_argument("--iters", type=int, default=12, help="experiments in each campaign")
    parser.add_argument("--tasks", type=int, default=30, help="runs for the overhead measurement")
    args = parser.parse_args()
    import ray

    from autoresearch.execution.ray_executor import RayExecutor

    walls = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        family = progress_family(tmp)
        os.environ["TOY_SLEEP_S"] = "0"
        per_run = overhead(family, tmp / "overhead", args.tasks)
        os.environ["TOY_SLEEP_S"] = str(args.sleep)  # a local Ray instance's workers inherit it
        for workers in args.workers:
            print(f"[bench_ray_scaling] {workers} worker(s)", file=sys.stderr, flush=True)
            with RayExecutor(workers=workers) as executor:
                walls[workers] = campaign_and_audit(family, tmp / f"w{workers}", executor, args.iters)
    print(
        f"Python {platform.python_version()}, ray {ray.__version__}, {os.cpu_count()} CPUs (load average "
        f"{os.getloadavg()[0]:.2f}); minimal template with a 4-point curve, train.py sleeping {args.sleep:g} s; "
        f"campaign: random, {args.iters} experiments, --early-stop median; audit: noise K=8 + verify 1 x 8 seeds\n"
    )
    print("| Ray workers | campaign wall | vs 1 worker | audit wall | vs 1 worker |")
    print("|---:|---:|---:|---:|---:|")
    base_campaign, base_audit = walls[args.workers[0]]
    for workers, (campaign, audit) in walls.items():
        print(
            f"| {workers} | {campaign:.1f} s | {campaign / base_campaign:.2f}x | {audit:.1f} s | "
            f"{audit / base_audit:.2f}x |"
        )
    print()
    print("| one run at a time, no sleep | seconds per run | Ray overhead per run |")
    print("|---|---:|---:|")
    print(f"| local subprocess | {per_run['local']:.3f} | reference |")
    for files in ("ship", "shared"):
        print(
            f"| Ray task, --ray-files {files} | {per_run[files]:.3f} | {per_run[files] - per_run['local']:+.3f} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
