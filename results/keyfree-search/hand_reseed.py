"""The hand recipe reseeded at its verification's seeds on the rendezvous test split as built on this
machine, two runs at a time, through the audit's own trial runner (results/sealed/remeasure.py does
the same for every promoted recipe; this is the one the key-free comparison is measured against):

    OMP_NUM_THREADS=1 .venv/bin/python results/keyfree-search/hand_reseed.py > results/logs/keyfree_hand_reseed.txt
"""

import statistics
import tempfile
from pathlib import Path

from autoresearch.audit.trials import Trial, run_trials
from autoresearch.campaign.audit_log import read_audit
from autoresearch.execution.executors import LocalExecutor
from autoresearch.family import Family

ROOT = Path(__file__).resolve().parents[2]
HAND = ROOT / "results" / "rendezvous" / "hand"
METRIC = "mean_terminal_distance"

verify = read_audit(HAND)["verify"]
family = Family.load(ROOT / "families" / "rendezvous")
# the recipe as promoted, on the baseline of the parameters the family declared since
promoted = next(c for c in verify["candidates"] if c["config_id"] == verify["promoted"])["config"]
config = {**family.baseline_config, **promoted}
trials = [Trial(f"hand-s{seed}", config, seed) for seed in verify["seeds"]]
work = Path(tempfile.mkdtemp(prefix="keyfree-hand-"))
rows = run_trials(family, trials, LocalExecutor(2), work / "trials.jsonl", work, 3600.0)
splits = [row.final_metric["splits"] for row in rows]
for row, split in zip(rows, splits, strict=True):
    print(row.seed, round(split["test"][METRIC], 5), round(split["search"][METRIC], 5), flush=True)
test = [split["test"][METRIC] for split in splits]
print("test mean", statistics.mean(test), "sd", statistics.stdev(test), end=" ")
print("search mean", statistics.mean(split["search"][METRIC] for split in splits))
print("datasets", rows[0].final_metric["datasets"])
