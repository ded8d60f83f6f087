"""Make the shipped evaluation splits (cwh_envs/data/): screen each split once, write its starts,
docking points and the expert's energy per start, and record the file's sha256 in the manifest.

    python scripts/make_splits.py                 # every split in SPLITS (constrained docking: ~45 min)
    python scripts/make_splits.py docking/test    # one of them

This is the only place the benchmark's starts are screened; users' machines read the files
(cwh_envs.splits). A split whose starts come out other than the shipped ones is written as a new
version (the old file and entry stay, as Gymnasium keeps an env's old ids), and
tests/test_shipped_splits.py then fails until the new (name, version, identity) is added to its
table: a shipped split never changes silently.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import sys

import numpy as np

from cwh_envs import datasets, splits
from cwh_envs.problems import DockingProblem, RendezvousProblem
from cwh_envs.rollout import control_effort

# The problem of every family that ships (families/*/train.py: TASK, PROBLEM, N_EVAL, N_TEST), with
# the size of each split; a family scores on the first N of it. tests/test_shipped_splits.py checks
# that every bundled family's problem and sizes are covered.
CONSTRAINED = DockingProblem(speed_limit=(0.01, 2 * DockingProblem().n), approach_cone=(30.0, 15.0))
SPLITS = {
    "rendezvous/search": ("rendezvous", RendezvousProblem(), "search", 512),
    "rendezvous/test": ("rendezvous", RendezvousProblem(), "test", 1024),
    "docking/search": ("docking", DockingProblem(), "search", 512),
    "docking/test": ("docking", DockingProblem(), "test", 1024),
    "docking-constrained/search": ("docking", CONSTRAINED, "search", 128),
    "docking-constrained/test": ("docking", CONSTRAINED, "test", 1024),
}


def split_file(name: str, version: int) -> str:
    return f"{name.replace('/', '-')}-v{version}.npz"


def write_split(name: str, starts: np.ndarray, goals: np.ndarray, energy: np.ndarray) -> dict:
    """Write one split's file and its manifest entry; a new version if its starts changed."""
    task, problem, split, _ = SPLITS[name]
    identity = splits.split_identity(starts, goals)
    data = json.loads(splits.MANIFEST.read_text()) if splits.MANIFEST.exists() else None
    data = data or {"format": splits.MANIFEST_FORMAT, "splits": []}
    same_name = [e for e in data["splits"] if e["name"] == name]
    if any(e["identity"] == identity for e in same_name):
        print(f"{name}: unchanged (identity {identity})")
        return next(e for e in same_name if e["identity"] == identity)
    version = max((e["version"] for e in same_name), default=-1) + 1
    buffer = io.BytesIO()
    arrays = {"starts": starts, "goals": goals, "energy": energy}
    np.savez_compressed(buffer, **{k: np.ascontiguousarray(v, dtype="<f8") for k, v in arrays.items()})
    payload = buffer.getvalue()
    (splits.DATA_DIR / split_file(name, version)).write_bytes(payload)
    entry = {
        "name": name,
        "version": version,
        "task": task,
        "split": split,
        "n": len(starts),
        "identity": identity,
        "file": split_file(name, version),
        "sha256": hashlib.sha256(payload).hexdigest(),
        "problem": splits.problem_fields(problem),
    }
    data["splits"].append(entry)
    text = json.dumps(data, indent=1) + "\n"
    tmp = splits.MANIFEST.with_suffix(".tmp")
    tmp.write_text(text)
    tmp.replace(splits.MANIFEST)  # the manifest is replaced whole, never half-written
    print(f"{name}: written as version {version} ({len(starts)} starts, identity {identity})")
    return entry


def make(name: str) -> dict:
    task, problem, split, n = SPLITS[name]
    held = datasets.screen_split(task, n, problem, split=split)
    energy = control_effort(held.trajectory_thrust(), problem)[0]
    return write_split(name, held.starts, held.goals, energy)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help=f"splits to make (default: all of {', '.join(SPLITS)})")
    args = parser.parse_args()
    unknown = sorted(set(args.names) - set(SPLITS))
    if unknown:
        parser.error(f"unknown split(s) {unknown}; known: {', '.join(SPLITS)}")
    splits.DATA_DIR.mkdir(exist_ok=True)
    for name in args.names or SPLITS:
        make(name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
