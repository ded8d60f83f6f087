"""Export a trained rendezvous policy to ONNX: the file that flies.

    python families/rendezvous/export.py --policy OUT_DIR_OR_policy.pt --onnx policy.onnx

The policy is restored by this family's own train.py (``load_policy``); the graph takes the
observation [x, y, z, vx, vy, vz, tau] (N, 7) float32 as the env shows it, standardises it inside,
and returns the env action, thrust / u_max clipped to [-1, 1] (N, 3), exactly as ``Policy.act``.
The metadata holds the task, the problem constants and the recipe (``runtime_cbf_filter`` is false:
rendezvous has no keep-out). Before it is kept, the file is checked against the torch policy on
1024 observations; one summary line is printed.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import torch
import train

from cwh_envs.onnx_policy import OnnxPolicy, action_difference, export_policy

ENV_ID = "CWHRendezvous-v0"
CHECK_ROWS = 1024  # observations the exported file is compared with the torch policy on
CHECK_TOLERANCE = 1e-5  # largest |action difference| accepted (actions lie in [-1, 1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--policy", type=Path, required=True, help="a train.py --out directory or its policy.pt"
    )
    parser.add_argument("--onnx", type=Path, required=True, help="the ONNX file to write")
    args = parser.parse_args()
    torch.set_num_threads(train.TORCH_THREADS)
    policy, saved = train.load_policy(args.policy)
    if saved["task"] != train.TASK:
        raise SystemExit(f"export.py: {args.policy} holds a {saved['task']} policy, not {train.TASK}")
    cbf = False  # no keep-out, no filter
    source = args.policy / "policy.pt" if args.policy.is_dir() else args.policy
    metadata = {
        "task": train.TASK,
        "env_id": ENV_ID,
        "observation": "[x, y, z, vx, vy, vz, tau] float32 (N, 7), as the env shows it; standardised in the graph",
        "action": "thrust / u_max per axis, clipped to [-1, 1], float32 (N, 3), as the env takes it",
        "runtime_cbf_filter": cbf,
        "cbf_margin": None,
        "problem": train.PROBLEM.as_dict(),
        "metric": train.METRIC,
        "config": saved["config"],
        "record": {key: saved["record"].get(key) for key in ("run_id", "seed", train.METRIC, "eval_split")},
        "policy_sha256": hashlib.sha256(source.read_bytes()).hexdigest(),
        "torch": torch.__version__,
    }
    export_policy(policy, policy.obs_mean, policy.obs_std, args.onnx, metadata)
    gap = action_difference(policy.act, OnnxPolicy(args.onnx), policy.obs_mean, policy.obs_std, CHECK_ROWS)
    if not gap <= CHECK_TOLERANCE:
        args.onnx.unlink()
        raise SystemExit(
            f"export.py: the ONNX policy differs from the torch policy by {gap:.3g} (> {CHECK_TOLERANCE})"
        )
    summary = {
        "onnx": str(args.onnx),
        "task": train.TASK,
        "runtime_cbf_filter": cbf,
        "max_action_difference": gap,
    }
    print("EXPORTED: " + json.dumps(summary), flush=True)


if __name__ == "__main__":
    sys.exit(main())
