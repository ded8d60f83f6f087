"""Fly committed policy.onnx files on the rendezvous test split as built here, beside their logged reseeds.

Each file is flown by examples/fly_onnx.py (the user's tool: it checks the file's task and problem
constants and scores the flight with the family's metric function).

    .venv/bin/python results/keyfree-search/fly_onnx.py CAMPAIGN... > results/logs/keyfree_fly_onnx.txt
"""

import json
import subprocess
import sys
from pathlib import Path

from cwh_envs.datasets import evaluation_set
from cwh_envs.prepare import load_train

REPO = Path(__file__).resolve().parents[2]
train = load_train(REPO / "families" / "rendezvous")
print(
    "test split key",
    evaluation_set(train.TASK, train.N_TEST, problem=train.PROBLEM, split="test").content_key,
)
for d in sys.argv[1:]:
    flown = subprocess.run(
        [
            sys.executable,
            REPO / "examples" / "fly_onnx.py",
            "--family",
            "rendezvous",
            f"{d}/policy.onnx",
            "--split",
            "test",
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    mean = json.loads(flown.stdout)[train.METRIC]
    rows = [json.loads(line) for line in open(f"{d}/audit/verify/runs.jsonl")]
    logged = sorted(round(r["splits"]["test"][train.METRIC], 5) for r in rows)
    print(d, "flown here", round(mean, 5), "logged reseeds", logged)
