"""Campaign wall time with ``loop --workers 2`` vs 1, and the loop's own overhead per iteration.

1. The same random-search campaign (same proposer seed, same --max-runs) on a real family, run
   through the CLI with --workers 1 and then 2; the ratio of wall times is the gain (target <= 0.6x
   on a 2-core machine). The load average is printed: other processes on the machine slow it.
2. The loop's per-iteration overhead without training: a toy-family campaign whose train.py
   returns at once; overhead = the loop's elapsed time not spent inside runs, per iteration
   (target < 50 ms).

Usage:

    .venv/bin/python benchmarks/bench_loop_parallel.py [--family docking] [--max-runs 6] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from autoresearch.family import Family
from autoresearch.journal import read_jsonl
from autoresearch.loop.orchestrator import LoopSettings, Orchestrator
from autoresearch.loop.stopping import Budgets
from autoresearch.proposers.random_search import RandomProposer

TOY = Path(__file__).resolve().parents[1] / "autoresearch" / "templates" / "minimal"


def campaign_wall(family: str, workers: int, max_runs: int, seed: int, where: Path) -> tuple[float, int]:
    """(wall seconds, successful runs) of one CLI campaign."""
    campaign = where / f"workers-{workers}"
    cmd = [sys.executable, "-m", "autoresearch", "loop", "--family", family, "--proposer", "random"]
    cmd += ["--max-runs", str(max_runs), "--seed", str(seed), "--workers", str(workers)]
    cmd += ["--plateau-window", "100", "--campaign", str(campaign), "--plain"]
    started = time.monotonic()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wall = time.monotonic() - started
    return wall, sum(r["status"] == "ran" for r in read_jsonl(campaign / "proposals.jsonl"))


def loop_overhead_ms(where: Path, iterations: int = 30) -> float:
    """Milliseconds per iteration the loop spends outside its runs (toy family, no training)."""
    shutil.copytree(TOY, where / "toy", ignore=shutil.ignore_patterns("runs.jsonl*", "__pycache__"))
    family = Family.load(where / "toy")
    proposer = RandomProposer(family.registry, seed=0)
    settings = LoopSettings(proposer_name="random", budgets=Budgets(max_iters=iterations, plateau_window=100))
    Orchestrator(family, proposer, where / "c", settings).run()
    records = [r for r in read_jsonl(where / "c" / "proposals.jsonl") if r["status"] == "ran"]
    first, rest = records[0], records[1:]  # from the first record on: prepare.py --check left out
    in_runs = sum(r["wall_seconds"] for r in rest)
    return 1000 * (rest[-1]["elapsed_s"] - first["elapsed_s"] - in_runs) / len(rest)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--family", default="docking")
    parser.add_argument("--max-runs", type=int, default=6)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        load_before = os.getloadavg()[0]
        walls = {}
        for workers in (1, 2):
            walls[workers], ran = campaign_wall(args.family, workers, args.max_runs, args.seed, Path(tmp))
            rows.append(
                (
                    f"{args.family} random, --max-runs {args.max_runs}, --workers {workers}",
                    f"{walls[workers]:.1f} s",
                    f"{ran} runs ok",
                )
            )
        ratio = walls[2] / walls[1]
        rows.append(("wall time ratio, --workers 2 / 1", f"{ratio:.2f}x", "target <= 0.6x"))
        load_after = os.getloadavg()[0]
        overhead = loop_overhead_ms(Path(tmp) / "overhead")
        rows.append(
            ("loop overhead per iteration (toy, no training)", f"{overhead:.1f} ms", "target < 50 ms")
        )
    print(
        f"{os.cpu_count()} CPUs; 1-min load average {load_before:.1f} before, {load_after:.1f} after the campaigns"
    )
    width = max(len(r[0]) for r in rows)
    print(f"{'measure':<{width}}  {'value':>10}  note")
    for name, value, note in rows:
        print(f"{name:<{width}}  {value:>10}  {note}")


if __name__ == "__main__":
    main()
