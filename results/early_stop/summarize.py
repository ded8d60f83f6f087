"""Run-seconds, experiments and best of the two campaigns of results/early_stop/run.sh (runs nothing)."""

import json
import sys
from pathlib import Path

root = Path(sys.argv[1] if len(sys.argv) > 1 else "runs")
print("| early stop | experiments | ran / pruned / failed | run-seconds | per experiment | best | stopped by |")
print("|---|---|---|---|---|---|---|")
for stop in ("none", "asha"):
    records = [json.loads(line) for line in (root / f"early-stop-{stop}" / "proposals.jsonl").open()]
    runs = [r for r in records if r["status"] in ("ran", "failed", "pruned")]
    seconds = sum(r["wall_seconds"] or 0.0 for r in runs)
    counts = "/".join(str(sum(r["status"] == s for r in runs)) for s in ("ran", "pruned", "failed"))
    best = min((r["metric"] for r in runs if r["status"] == "ran"), default=None)
    last = records[-1]
    print(
        f"| {stop} | {len(runs)} | {counts} | {seconds:.0f} s | {seconds / len(runs):.1f} s | "
        f"{best:.4g} | {last.get('trigger')} |"
    )
