"""Fly committed policy.onnx files on the rendezvous test split as built here, beside their logged reseeds.

.venv/bin/python results/keyfree-search/fly_onnx.py CAMPAIGN... > results/logs/keyfree_fly_onnx.txt
"""

import json
import sys

import numpy as np

sys.path.insert(0, "families/rendezvous")
import train

from cwh_envs.datasets import evaluation_set
from cwh_envs.onnx_policy import OnnxPolicy
from cwh_envs.rollout import fly

test = evaluation_set(train.TASK, train.N_TEST, problem=train.PROBLEM, split="test")
print("test split key", test.content_key)
for d in sys.argv[1:]:
    flight = fly(train.PROBLEM, OnnxPolicy(f"{d}/policy.onnx"), test.starts)
    mean = float(np.mean(flight.terminal_distance))
    rows = [json.loads(line) for line in open(f"{d}/audit/verify/runs.jsonl")]
    logged = sorted(round(r["splits"]["test"]["mean_terminal_distance"], 5) for r in rows)
    print(d, "flown here", round(mean, 5), "logged reseeds", logged)
