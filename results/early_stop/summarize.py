"""Run-seconds, experiments and best of campaigns (runs nothing).

python results/early_stop/summarize.py runs/early-stop-none runs/early-stop-asha
python results/early_stop/summarize.py results/rendezvous/tpe results/early_stop/rdv-tpe-asha
"""

import json
import sys
from pathlib import Path

campaigns = [Path(d) for d in sys.argv[1:]] or [Path("runs/early-stop-none"), Path("runs/early-stop-asha")]
print(
    "| campaign | early stop | experiments | ran / pruned / failed | run-seconds | per experiment | best | stopped by |"
)
print("|---|---|---|---|---|---|---|---|")
for root in campaigns:
    settings = json.loads((root / "campaign.json").read_text())["settings"]
    records = [json.loads(line) for line in (root / "proposals.jsonl").open()]
    runs = [r for r in records if r["status"] in ("ran", "failed", "pruned") and r["proposer"] != "baseline"]
    seconds = sum(r["wall_seconds"] or 0.0 for r in runs)
    counts = "/".join(str(sum(r["status"] == s for r in runs)) for s in ("ran", "pruned", "failed"))
    best = min((r["metric"] for r in runs if r["status"] == "ran"), default=float("nan"))
    print(
        f"| {root.as_posix()} | {settings.get('early_stop', 'none')} | {len(runs)} | {counts} | {seconds:.0f} s | "
        f"{seconds / len(runs):.1f} s | {best:.4g} | {records[-1].get('trigger')} |"
    )
