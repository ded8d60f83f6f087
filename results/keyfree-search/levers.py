"""The fourth arm's two levers, each measured on fixed recipes at the ten seeds its audits reseeded
at (11-20), two runs at a time through the audit's own trial runner, on both splits:

1. The off switch: the hand recipe as certified (`DROPOUT` 0) and with `DROPOUT` 0.0003, 0.002 and
   0.03 (the range of the three first arms' audited bests), no time budget, as certified.
2. The paced schedule: the fourth arm's three one-seed picks under their campaigns' 120 s budget,
   trained by the rendezvous train.py from before the schedule was paced by the clock (b5ec98b^,
   the step-only cosine), against their audits' reseeds at the same seeds (paced, committed in
   tpe-hyperband-off/repeat-*/audit/verify/verify.jsonl): paired differences.

    OMP_NUM_THREADS=1 .venv/bin/python results/keyfree-search/levers.py > results/logs/keyfree_levers.txt 2>&1

Writes levers.json beside it. Time-budgeted runs depend on the CPU they get: run it alone.
"""

import json
import shutil
import statistics
import subprocess
import tempfile
from pathlib import Path

from scipy import stats

from autoresearch.audit.trials import Trial, run_trials
from autoresearch.campaign.audit_log import StepLog, read_audit
from autoresearch.execution.executors import LocalExecutor
from autoresearch.family import Family
from autoresearch.splits import Split

ROOT = Path(__file__).resolve().parents[2]
HERE = ROOT / "results" / "keyfree-search"
SEEDS = list(range(11, 21))
DROPOUTS = [0.0, 0.0003, 0.002, 0.03]
STEP_ONLY = "b5ec98b^"  # the commit before the cosine schedule was paced by a time budget
EXECUTOR = LocalExecutor(2)
SPLITS = (Split.SEARCH, Split.TEST)


def summary(values: list[float]) -> dict:
    return {"mean": statistics.mean(values), "sd": statistics.stdev(values), "n": len(values)}


def paired(a: list[float], b: list[float]) -> dict:
    """a - b seed by seed: the mean difference and its 95 % t interval."""
    d = [x - y for x, y in zip(a, b, strict=True)]
    if len(set(d)) == 1:  # the same at every seed (a run the budget never cut): no interval
        return {"mean": d[0], "low": None, "high": None, "n": len(d)}
    low, high = stats.t.interval(0.95, len(d) - 1, loc=statistics.mean(d), scale=stats.sem(d))
    return {"mean": statistics.mean(d), "low": float(low), "high": float(high), "n": len(d)}


def shown(d: dict) -> str:
    if d["low"] is None:
        return f"{d['mean']:+.4f} (the same at every seed)"
    return f"{d['mean']:+.4f} [{d['low']:+.4f}, {d['high']:+.4f}]"


def scores(rows) -> dict[str, list[float]]:
    return {split.value: [row.on(split).metric for row in rows] for split in SPLITS}


def line(name: str, values: dict[str, list[float]]) -> str:
    return name + "".join(
        f" | {s}: {summary(v)['mean']:.4f} ± {summary(v)['sd']:.4f}" for s, v in values.items()
    )


work = Path(tempfile.mkdtemp(prefix="keyfree-levers-"))
family = Family.load(ROOT / "families" / "rendezvous")
out: dict = {"command": "python results/keyfree-search/levers.py", "seeds": SEEDS}

# 1. The off switch, on the hand recipe.
hand = read_audit(ROOT / "results" / "rendezvous" / "hand")["verify"]
recipe = next(c for c in hand["candidates"] if c["config_id"] == hand["promoted"])["config"]
recipe = {**family.baseline_config, **recipe}
trials = [Trial(f"dropout-{p}-s{s}", {**recipe, "DROPOUT": p}, s) for p in DROPOUTS for s in SEEDS]
rows = run_trials(family, trials, EXECUTOR, work / "dropout.jsonl", work / "dropout", 3600.0)
by_p = {p: scores(rows[i * len(SEEDS) : (i + 1) * len(SEEDS)]) for i, p in enumerate(DROPOUTS)}
print("1. the off switch: the hand recipe with DROPOUT p, no budget, seeds 11-20")
out["dropout"] = []
for p in DROPOUTS:
    entry = {"dropout": p, **{s: summary(v) for s, v in by_p[p].items()}}
    if p:
        entry["minus_dropout_0"] = {s: paired(by_p[p][s], by_p[0.0][s]) for s in by_p[p]}
    out["dropout"].append(entry)
    diff = entry.get("minus_dropout_0", {}).get("test")
    extra = f" | test - DROPOUT 0: {shown(diff)}" if diff else ""
    print(line(f"  DROPOUT {p:g}", by_p[p]) + extra, flush=True)

# 2. The paced schedule, on the fourth arm's one-seed picks.
old = work / "step-only"
shutil.copytree(family.path, old, ignore=shutil.ignore_patterns("runs.jsonl*", "out", "__pycache__"))
source = subprocess.run(
    ["git", "show", f"{STEP_ONLY}:families/rendezvous/train.py"], cwd=ROOT, check=True, capture_output=True
).stdout
(old / "train.py").write_bytes(source)
step_only = Family.load(old)
print(
    "\n2. the paced schedule: each one-seed pick at its 120 s budget, step-only (b5ec98b^) against paced (its audit)"
)
out["schedule"] = []
for repeat in sorted(HERE.glob("tpe-hyperband-off/repeat-*")):
    verify = read_audit(repeat)["verify"]
    pick = verify["candidates"][0]
    budget = json.loads((repeat / "campaign.json").read_text())["settings"]["time_budget"]
    logged = {row.seed: row for row in StepLog(repeat / "audit" / "verify" / "verify.jsonl").read()}
    paced = scores([logged[s] for s in SEEDS])
    trials = [Trial(f"step-only-{pick['config_id']}-s{s}", pick["config"], s) for s in SEEDS]
    rows = run_trials(
        step_only,
        trials,
        EXECUTOR,
        work / f"{repeat.name}.jsonl",
        work / repeat.name,
        3600.0,
        time_budget=budget,
    )
    steps = scores(rows)
    entry = {
        "repeat": repeat.name,
        "config_id": pick["config_id"],
        "time_budget": budget,
        "paced": {s: summary(v) for s, v in paced.items()},
        "step_only": {s: summary(v) for s, v in steps.items()},
        "paced_minus_step_only": {s: paired(paced[s], steps[s]) for s in paced},
        "budget_exhausted_step_only": sum(bool(r.final_metric.get("budget_exhausted")) for r in rows),
    }
    out["schedule"].append(entry)
    d = entry["paced_minus_step_only"]["test"]
    print(line(f"  {repeat.name} {pick['config_id']} paced", paced))
    print(
        line(f"  {repeat.name} {pick['config_id']} step-only", steps)
        + f" | test paced - step-only: {shown(d)}"
        + f" | cut by the budget: {entry['budget_exhausted_step_only']} of {len(rows)}",
        flush=True,
    )
(HERE / "levers.json").write_text(json.dumps(out, indent=1) + "\n")
shutil.rmtree(work)
print(f"\nwritten: {(HERE / 'levers.json').relative_to(ROOT)}")
