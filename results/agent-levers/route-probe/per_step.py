"""A trained constrained-docking policy's compute per step: torch and its ONNX export, one observation.

    OMP_NUM_THREADS=1 .venv/bin/python results/agent-levers/route-probe/per_step.py RUN_OUT_DIR [...]

For each train.py ``--out`` directory given: the policy restored by the family's train.py
(``load_policy``), exported by the family's export.py (checked against torch there), then each of
``Policy.act`` (torch, one thread) and the ONNX file (onnxruntime, one thread) called on one
observation of the search split at a time, 2000 calls after 200 to warm up: the median and the 99th
percentile in µs. The routed law's table lookups are in both; the CBF filter is not (it is timed
in the leaderboard). Run it alone: nothing else on the cores.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from cwh_envs.datasets import evaluation_set
from cwh_envs.onnx_policy import OnnxPolicy
from cwh_envs.prepare import load_train

FAMILY = Path(__file__).resolve().parents[3] / "families" / "docking-constrained"
CALLS, WARM_UP = 2000, 200


def timed(act, observations: np.ndarray) -> tuple[float, float]:
    seconds = []
    for i in range(WARM_UP + CALLS):
        obs = observations[i % len(observations)][None]
        started = time.perf_counter()
        act(obs)
        seconds.append(time.perf_counter() - started)
    micro = 1e6 * np.array(seconds[WARM_UP:])
    return float(np.median(micro)), float(np.percentile(micro, 99))


def main() -> None:
    train = load_train(FAMILY)
    torch.set_num_threads(train.TORCH_THREADS)
    search = evaluation_set(train.TASK, train.N_EVAL, problem=train.PROBLEM, split="search", build=False)
    observations = search.observations.astype(np.float32)
    for out in sys.argv[1:]:
        policy, _ = train.load_policy(out)
        with tempfile.TemporaryDirectory() as tmp:
            onnx = Path(tmp) / "policy.onnx"
            subprocess.run(
                [sys.executable, "export.py", "--policy", str(Path(out).resolve()), "--onnx", str(onnx)],
                cwd=FAMILY,
                check=True,
            )
            exported = OnnxPolicy(onnx, threads=1)
            rows = {"torch (Policy.act)": policy.act, "ONNX (onnxruntime)": exported.act}
            for name, act in rows.items():
                p50, p99 = timed(act, observations)
                print(f"{out}: {name}: {p50:.1f} µs p50, {p99:.1f} µs p99 per step", flush=True)


if __name__ == "__main__":
    sys.exit(main())
