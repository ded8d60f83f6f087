"""Fly an exported ONNX policy with onnxruntime from a family's evaluation starts; print its metrics.

    .venv/bin/python families/docking/train.py --out /tmp/bc_docking --runs-log /tmp/bc_docking/runs.jsonl
    .venv/bin/python families/docking/export.py --policy /tmp/bc_docking --onnx /tmp/bc_docking/policy.onnx
    .venv/bin/python examples/fly_onnx.py --family docking /tmp/bc_docking/policy.onnx [--split search|test]

The policy runs in onnxruntime, not torch: the file (families/<name>/export.py) holds the
standardisation and the network, and its metadata says the task, the problem constants and
whether the run-time CBF filter is on (the family's train.py, loaded for its constants and metric
function, still imports torch). The
starts are the family's evaluation split (cwh_envs.datasets.evaluation_set, as its train.py
scores), flown at once through cwh_envs.rollout.fly, with the filter (cwh_envs.cbf.safe_actions,
outside the graph) where the metadata has it on, the robust one (cwh_envs.robust_cbf, sized for the
family's DISPERSIONS) where it records ``robust_filter_k``, and scored by the family's own metric function
(``<task>_metrics`` of its train.py, loaded like examples/fly_policy.py loads it). Prints one JSON
line: the family's metrics, and the split, the number of starts, the filter setting and the file.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
from pathlib import Path

from cwh_envs.datasets import evaluation_set
from cwh_envs.onnx_policy import OnnxPolicy
from cwh_envs.robust_cbf import ErrorBounds
from cwh_envs.rollout import fly

ROOT = Path(__file__).resolve().parents[1]


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--family", required=True, help="a family name under families/, or a family directory"
    )
    parser.add_argument("onnx", type=Path, help="a file written by families/<name>/export.py")
    parser.add_argument("--split", choices=["search", "test"], default="search", help="the evaluation split")
    parser.add_argument("--threads", type=int, default=1, help="onnxruntime intra-op threads")
    return parser.parse_args()


def load_family(name: str):
    """The family's train.py as a module (its main() is guarded): TASK, PROBLEM, N_EVAL, metrics."""
    directory = ROOT / "families" / name
    if not (directory / "train.py").is_file():
        directory = Path(name)
    if not (directory / "train.py").is_file():
        raise SystemExit(f"--family {name}: neither a family under families/ nor a directory with a train.py")
    spec = importlib.util.spec_from_file_location(f"{directory.name}_train", directory / "train.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def safety(policy: OnnxPolicy, family) -> dict:
    """The filter the recipe flew, from the file's metadata, as ``fly``'s keywords: none, the nominal
    filter (``cbf_margin``), or the robust one sized for the family's DISPERSIONS at the recorded
    ``robust_filter_k``. A file of another task or other problem constants is refused."""
    meta = policy.metadata
    if meta.get("task") != family.TASK:
        raise SystemExit(f"{policy.path} holds a {meta.get('task')!r} policy, not {family.TASK!r}")
    if meta.get("problem") != json.loads(json.dumps(family.PROBLEM.as_dict())):
        raise SystemExit(f"{policy.path} was exported for other problem constants than the family's")
    if not meta.get("runtime_cbf_filter"):
        return {}
    out = {"cbf_margin": float(meta["cbf_margin"])}
    if meta.get("robust_filter_k"):
        out["cbf_bounds"] = ErrorBounds.from_dispersions(
            family.DISPERSIONS, k_sigma=float(meta["robust_filter_k"])
        )
    return out


def main() -> None:
    args = parse_args()
    family = load_family(args.family)
    policy = OnnxPolicy(args.onnx, threads=args.threads)
    filtered = safety(policy, family)
    n = family.N_EVAL if args.split == "search" else family.N_TEST
    held_out = evaluation_set(family.TASK, n, problem=family.PROBLEM, split=args.split)
    goals = held_out.goals if family.TASK == "docking" else None
    flight = fly(family.PROBLEM, policy, held_out.starts, goals, **filtered)
    metrics = getattr(family, f"{family.TASK}_metrics")(flight, held_out.trajectory_thrust())
    context = {
        "split": args.split,
        "n_starts": n,
        "runtime_cbf_filter": bool(filtered),
        "robust_filter_k": filtered["cbf_bounds"].k_sigma if "cbf_bounds" in filtered else None,
        "onnx": str(args.onnx),
    }
    print(json.dumps({**metrics, **context}, allow_nan=False), flush=True)


if __name__ == "__main__":
    main()
