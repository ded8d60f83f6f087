"""Export a trained docking policy to ONNX: the file that flies, with the CBF setting it flew with.

    python families/docking/export.py --policy OUT_DIR_OR_policy.pt --onnx policy.onnx
    python families/docking/export.py --policy OUT_DIR_OR_policy.pt --compiled policy.npz

The policy is restored by this family's own train.py (``load_policy``); the graph takes the
observation [r, v, g, tau] (N, 10) float32 as the env shows it, standardises it inside, and returns
the env action, thrust / u_max clipped to [-1, 1] (N, 3), exactly as ``Policy.act``. The run-time
CBF filter is not in the graph: it stays ``cwh_envs.cbf.safe_actions``, applied to the actions
outside it, and the file's metadata says whether the recipe had it on (``runtime_cbf_filter``,
``cbf_margin``), with the task, the problem constants and the recipe. Before writing, the file is
checked against the torch policy on 1024 observations; one summary line is printed.

``--compiled`` writes the same function for :class:`cwh_envs.compiled_policy.CompiledPolicy` (numba,
one chaser a call, in microseconds: the MLP's layers and the law a residual form corrects, as
arrays in an .npz with the same metadata), held to the torch policy the same way.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import torch
import train

from cwh_envs.onnx_policy import export_checked

ENV_ID = "CWHDockKOZ-v1"
CHECK_ROWS = 1024  # observations the exported file is compared with the torch policy on
CHECK_TOLERANCE = 1e-4  # largest |action difference| accepted (actions in [-1, 1]); why: docs/examples.md


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--policy", type=Path, required=True, help="a train.py --out directory or its policy.pt"
    )
    parser.add_argument("--onnx", type=Path, help="the ONNX file to write")
    parser.add_argument("--compiled", type=Path, help="the .npz to write for cwh_envs.compiled_policy")
    args = parser.parse_args()
    if args.onnx is None and args.compiled is None:
        parser.error("give --onnx, --compiled or both")
    torch.set_num_threads(train.TORCH_THREADS)
    policy, saved = train.load_policy(args.policy)
    if saved["task"] != train.TASK:
        raise SystemExit(f"export.py: {args.policy} holds a {saved['task']} policy, not {train.TASK}")
    cbf = bool(saved["config"]["RUNTIME_CBF_FILTER"])
    source = args.policy / "policy.pt" if args.policy.is_dir() else args.policy
    metadata = {
        "task": train.TASK,
        "env_id": ENV_ID,
        "observation": "[r (3), v (3), g (3), tau] float32 (N, 10), as the env shows it; standardised in the graph",
        "action": "thrust / u_max per axis, clipped to [-1, 1], float32 (N, 3), as the env takes it",
        "runtime_cbf_filter": cbf,
        "cbf_margin": train.PROBLEM.margin if cbf else None,
        "cbf": "not in the graph: cwh_envs.cbf.safe_actions on the actions, as cwh_envs.rollout.fly(cbf_margin=...)",
        # > 0: the robust filter (cwh_envs.robust_cbf), sized for train.DISPERSIONS at this many sigmas
        "robust_filter_k": saved["config"].get("ROBUST_FILTER_K", 0.0) if cbf else None,
        "problem": train.PROBLEM.as_dict(),
        "metric": train.METRIC,
        "config": saved["config"],
        "record": {key: saved["record"].get(key) for key in ("run_id", "seed", train.METRIC, "eval_split")},
    }
    if args.onnx is not None:
        try:
            summary = export_checked(
                policy, args.onnx, metadata, source, rows=CHECK_ROWS, tolerance=CHECK_TOLERANCE
            )
        except ValueError as err:
            raise SystemExit(f"export.py: {err}") from None
        print("EXPORTED: " + json.dumps(summary), flush=True)
    if args.compiled is not None:
        # stamped with its source's sha256, as the ONNX file is (export_checked)
        stamped = {**metadata, "policy_sha256": hashlib.sha256(source.read_bytes()).hexdigest()}
        print("COMPILED: " + json.dumps(write_compiled(policy, args.compiled, stamped)), flush=True)


def write_compiled(policy, path: Path, metadata: dict) -> dict:
    """``policy`` as a CompiledPolicy at ``path``, kept only if its actions are within
    CHECK_TOLERANCE of the torch policy's on CHECK_ROWS observations; its summary line."""
    from cwh_envs.compiled_policy import ResidualLaw, compile_checked

    form = getattr(policy, "form", "residual" if policy.residual else "direct")
    law = None
    if form != "direct":
        route = form == "route"
        law = ResidualLaw(
            policy.scale,
            policy.target_gain.numpy(),
            policy.state_gain.numpy(),
            policy.u_max,
            policy.route_along.detach().numpy()[:, 0] if route else np.zeros(0),
            policy.route_across.detach().numpy()[:, 0] if route else np.zeros(0),
            # Policy.forward: the route's correction is off past its last waypoint
            train.PROBLEM.horizon - train.CONE_ROUTE[-1].step if route else -1,
        )
    try:
        return compile_checked(policy, path, metadata, law, rows=CHECK_ROWS, tolerance=CHECK_TOLERANCE)
    except ValueError as err:
        raise SystemExit(f"export.py: {err}") from None


if __name__ == "__main__":
    sys.exit(main())
