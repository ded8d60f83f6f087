"""The seed noise measured again (results/noise/run.sh) against the noise it replaces, seed by seed
on both splits, and each family best's margin m under either (its reseeded test-split mean against
the test-split noise: the gate's m >= 2).

    python results/noise/compare.py
"""

from pathlib import Path

from autoresearch.audit.stats import mean_sd
from autoresearch.campaign.audit_log import StepLog
from autoresearch.family import Family
from autoresearch.splits import Split

OLD = {  # where the replaced noise was measured (its ledger's runs_dir)
    "rendezvous": "results/sealed/rendezvous/noise-512",
    "docking": "results/sealed/docking/noise-512",
    "docking-constrained": "results/docking-constrained/gp/audit/noise",
}


print(
    "| family | split | replaced: mean ± sd | now: mean ± sd | largest change at one seed | family best: m then | m now |"
)
print("|---|---|---:|---:|---:|---:|---:|")
for name, old_dir in OLD.items():
    family = Family.load(Path("families") / name)
    best = family.ledger.current(family.best)
    sign = family.direction
    for split in (Split.SEARCH, Split.TEST):
        runs = {}
        for label, where in (("old", old_dir), ("new", f"results/noise/{name}")):
            rows = StepLog(Path(where) / "noise.jsonl").read()
            runs[label] = {row.seed: row.on(split).metric for row in rows if row.ok}
        seeds = sorted(runs["new"])
        old, new = ([runs[k][s] for s in seeds] for k in ("old", "new"))
        (m0, s0), (m1, s1) = mean_sd(old), mean_sd(new)
        change = max(abs(a - b) for a, b in zip(old, new, strict=True))
        margins = " | "
        if split is Split.TEST and best and best.get("split") == "test":
            mu = best["metric"]
            margins = f"{sign * (mu - m0) / s0:.1f} | {sign * (mu - m1) / s1:.1f}"
        print(
            f"| {name} | {split.value} | {m0:.6g} ± {s0:.4g} | {m1:.6g} ± {s1:.4g} | {change:.2g} | {margins} |"
        )
