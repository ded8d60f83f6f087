"""Each family best re-measured on the shipped splits (issue 57, item 4).

The rendezvous and docking family bests were audited on builds of the splits whose expert floats
differ from this machine's (content keys b29379c5 and 022f389f, results/splits/marks.md): the same
starts by the issue's check, but not proven. Each best is retrained here at the seeds its audit
reseeded it at, with the training budget it was certified under, and scored on both shipped splits
from one training (train.py --eval-split test). The gate (Eq. reseedgate, the runaway gate) is applied
on each split against the seed noise measured on the shipped splits (families' ledger.json).
Constrained docking's best was audited on the shipped starts themselves (its content key 45109ea6 is
the shipped split's here), so it is not retrained. Under a time budget a run's length depends on the
machine's speed, so a rerun is another draw of the same recipe, not a replay: run it alone.

    .venv/bin/python results/splits/family_bests.py > results/logs/splits_family_bests.txt 2>&1

Resumable: a re-run skips every run already logged. Writes family_bests.json and .md here.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from autoresearch.audit import tails
from autoresearch.audit.inputs import config_id, seed_noise
from autoresearch.audit.trials import Trial, run_trials
from autoresearch.audit.verify import assess
from autoresearch.campaign.audit_log import read_audit
from autoresearch.execution.executors import LocalExecutor
from autoresearch.family import Family
from autoresearch.splits import Split

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
TIMEOUT_S = 3600.0
FAMILIES = ("rendezvous", "docking")
KEEP = ("mu_r", "sigma_r", "n", "n_feasible", "margin", "passed", "reason")


def remeasure(name: str, executor) -> dict:
    family = Family.load(ROOT / "families" / name)
    best = family.ledger.current(family.best)
    campaign = best["source"]["campaign"]
    seeds = read_audit(ROOT / campaign)["verify"]["seeds"]
    cid = config_id(best["config"])
    root = HERE / "runs" / name / cid
    trials = [Trial(f"best-{cid}-s{seed}", best["config"], seed) for seed in seeds]
    rows = run_trials(
        family,
        trials,
        executor,
        root / "trials.jsonl",
        root,
        TIMEOUT_S,
        label=f"{name} family best",
        time_budget=best.get("time_budget"),
    )
    now = {
        split.value: assess(
            rows, None, seed_noise(family, split), family.direction, split, family.tail_fields, tails.RUNAWAY
        )
        for split in Split
    }
    return {
        "family": name,
        "campaign": campaign,
        "config_id": cid,
        "seeds": seeds,
        "time_budget": best.get("time_budget"),
        "split_ids": family.split_ids,
        "committed": best["by_split"],
        "shipped": {split: {k: part.get(k) for k in KEEP} for split, part in now.items()},
        "per_seed": {
            row.seed: {split.value: row.on(split).metric for split in Split if row.ok} for row in rows
        },
        # the tail: each split's worst start over every reseed, and on which seed (p99 is not in the
        # records; the leaderboard's rows carry it)
        "worst_start": {
            split.value: max(
                (
                    {"distance": split_metrics(row, split)["max_terminal_distance"], "seed": row.seed}
                    for row in rows
                    if row.ok
                ),
                key=lambda worst: worst["distance"],
            )
            for split in Split
        },
    }


def split_metrics(row, split: Split) -> dict:
    """A reseed's metrics on one split, as its FINAL_METRIC holds them."""
    return row.final_metric["splits"][split.value]


def table(results: list[dict]) -> str:
    lines = [
        "| family best | split | committed (earlier build): mean ± sd, n | on the shipped split: mean ± sd, n "
        "| worst start [m] (seed) | m, gate |",
        "|---|---|---:|---:|---:|---|",
    ]
    for r in results:
        for split in ("search", "test"):
            old, new = r["committed"][split], r["shipped"][split]
            lines.append(
                f"| {r['family']} ({r['campaign']}) | {split} | {old['mu_r']:.4g} ± {old['sigma_r']:.2g}, "
                f"{old['n']} | {new['mu_r']:.4g} ± {new['sigma_r']:.2g}, {new['n']} | "
                f"{r['worst_start'][split]['distance']:.3g} ({r['worst_start'][split]['seed']}) | "
                f"{new['margin']:.1f}σ, {'PASS' if new['passed'] else 'FAIL: ' + str(new['reason'])} |"
            )
    return "\n".join(lines) + "\n"


def main() -> int:
    executor = LocalExecutor(2)
    results = [remeasure(name, executor) for name in FAMILIES]
    (HERE / "family_bests.json").write_text(json.dumps(results, indent=1) + "\n", encoding="utf-8")
    (HERE / "family_bests.md").write_text(table(results), encoding="utf-8")
    print(table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
