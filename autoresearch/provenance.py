"""What produced a record: the interpreter, the library versions, the code's commit, the family's files.

campaign.json keeps one :func:`collect` per session and audit.json one per step, so a number can
be traced to what made it. ``loop --resume``, ``autoresearch check`` and a re-run audit step list
every :func:`differences` between the recorded environment and the current one;
``--strict-provenance`` refuses to go on when there is any (:class:`ProvenanceError`).

Versions are read from the installed distributions' metadata, never by importing them (this
package does not import torch). The git state is that of the repository holding the family
directory: its commit, and whether tracked files differ from it (recorded, not compared: the audit
itself rewrites the family's best and its ledger). ``git status`` runs programs the repository's
own config names (``core.fsmonitor``, clean filters), so it is asked only by the commands that run
the family's code anyway (loop, audit); a read-only command (``check``, ``report``) asks git for the
commit alone (``rev-parse`` runs none of them) and records ``dirty`` as None. family.json is hashed without ``best``, which the
audit writes, nor ``seed_noise`` (the audit wrote it there before the ledger), so that a hash names the
problem and its search space in either layout; ledger.json is not hashed.
"""

from __future__ import annotations

import hashlib
import json
import platform
import subprocess
from importlib import metadata
from itertools import combinations, product
from pathlib import Path
from typing import Any

# The distributions whose version can change a number: the numerics, the learner, the env stack,
# the proposers' samplers and SDKs, and this project.
PACKAGES = (
    "numpy",
    "scipy",
    "torch",
    "gymnasium",
    "proxsuite",
    "optuna",
    "anthropic",
    "openai",
    "cwh-autoresearch",
)
FAMILY_FILES = ("train.py", "family.json", "program.md", "program_blind.md", "prepare.py")
AUDIT_WRITES = ("seed_noise", "best")  # family.json fields the audit writes (or wrote): left out of its hash
# family.json fields only the audit reads, to judge runs (autoresearch.audit.tails; split_ids, the data
# a run must have been scored on, checked run by run: autoresearch.splits): they change no run, so they
# are left out of the hash too, and declaring them leaves every campaign of the family resumable
AUDIT_READS = ("tails", "split_ids")
GIT_TIMEOUT_S = 10.0
MAX_UNSEEN_CHOICES = 8  # categorical choices a campaign did not see: up to this many, every subset is tried


class ProvenanceError(RuntimeError):
    """The environment differs from the recorded one and --strict-provenance was given."""


def collect(family_dir: str | Path, read_only: bool = False) -> dict[str, Any]:
    """The provenance of work done now on the family in ``family_dir``; ``read_only``: for a command
    that runs nothing of the family's or its repository's (module docstring)."""
    family_dir = Path(family_dir)
    return {
        "python": platform.python_version(),
        "implementation": platform.python_implementation(),
        "platform": platform.platform(),
        "packages": {name: _version(name) for name in PACKAGES},
        "git": git_state(family_dir, status=not read_only),
        "family_files": family_hashes(family_dir),
    }


def family_hashes(family_dir: Path) -> dict[str, str | None]:
    """sha256 (16 hex digits) of each family file; family.json without the fields the audit writes."""
    hashes: dict[str, str | None] = {}
    for name in FAMILY_FILES:
        path = family_dir / name
        if not path.is_file():
            hashes[name] = None
            continue
        data = path.read_bytes()
        if name == "family.json":
            try:
                registry = json.loads(data)
            except ValueError:
                registry = None
            if isinstance(registry, dict):
                kept = {k: v for k, v in registry.items() if k not in AUDIT_WRITES + AUDIT_READS}
                data = json.dumps(kept, sort_keys=True).encode()
        hashes[name] = hashlib.sha256(data).hexdigest()[:16]
    return hashes


def family_hashes_as_seen(family_dir: Path, seen: dict[str, Any]) -> set[str]:
    """The hashes family.json (as :func:`family_hashes`) may have had when a campaign that was shown
    the registry ``seen`` recorded it, had the family only grown since: the top-level fields,
    parameters and axes declared since left out, the baseline restricted to the parameters seen,
    the baseline's metric as seen, and each categorical's choices less any of those the campaign
    did not see (each such subset is tried: a protocol shows a campaign an axis narrowed to its
    baseline, so which choices came later is not in ``seen``), and, tried with and without, each
    numeric range put back to the one seen where it has only widened since. One equals the recorded
    hash exactly when the family only grew (new parameters, which every earlier run held at their
    baseline value; new choices, which no earlier run drew; ranges widened, which every earlier run
    lies inside; new fields such as ``protocols``, and new protocols, which
    no earlier campaign searched) or its baseline was
    measured again (the metric is a measurement, like the seed noise, and every campaign measures
    its own baseline first: the search split moving from 128 to 512 starts re-measured it); empty
    when family.json does not read."""
    try:
        registry = json.loads((family_dir / "family.json").read_bytes())
        space, axes = seen["search_space"], seen["axes"]
        kept = {k: v for k, v in registry.items() if k not in AUDIT_WRITES + AUDIT_READS and k in seen}
        kept["search_space"] = {k: v for k, v in registry["search_space"].items() if k in space}
        kept["axes"] = [axis for axis in registry["axes"] if axis in axes]
        if isinstance(seen.get("protocols"), dict) and isinstance(registry.get("protocols"), dict):
            kept["protocols"] = {k: v for k, v in registry["protocols"].items() if k in seen["protocols"]}
        baseline = registry["baseline"]
        kept["baseline"] = {**baseline, "config": {k: v for k, v in baseline["config"].items() if k in space}}
        kept["baseline"].pop("metric", None)
        if "metric" in seen["baseline"]:
            kept["baseline"]["metric"] = seen["baseline"]["metric"]
        unseen = [
            (name, choice)
            for name, spec in kept["search_space"].items()
            if isinstance(spec.get("choices"), list) and isinstance(space[name].get("choices"), list)
            for choice in spec["choices"]
            if choice not in space[name]["choices"]
        ]
        widened = {
            name: {**spec, "low": space[name]["low"], "high": space[name]["high"]}
            for name, spec in kept["search_space"].items()
            if spec.get("type") == space[name].get("type")
            and all(isinstance(spec.get(k), int | float) for k in ("low", "high"))
            and all(isinstance(space[name].get(k), int | float) for k in ("low", "high"))
            and spec["low"] <= space[name]["low"] <= space[name]["high"] <= spec["high"]
            and (spec["low"], spec["high"]) != (space[name]["low"], space[name]["high"])
        }
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return set()
    sizes = range(len(unseen) + 1) if len(unseen) <= MAX_UNSEEN_CHOICES else (0, len(unseen))
    hashes = set()
    for size, ranges in product(sizes, ({}, widened) if widened else ({},)):
        for later in combinations(unseen, size):
            specs = {**kept["search_space"], **ranges}
            for name, choice in later:
                specs[name] = {**specs[name], "choices": [c for c in specs[name]["choices"] if c != choice]}
            text = json.dumps({**kept, "search_space": specs}, sort_keys=True)
            hashes.add(hashlib.sha256(text.encode()).hexdigest()[:16])
    return hashes


def git_state(directory: Path, status: bool = True) -> dict[str, Any] | None:
    """{"commit", "dirty"} of the git repository holding ``directory``, or None outside one; without
    ``status``, ``dirty`` is None (not asked)."""
    commit = _git(directory, "rev-parse", "HEAD")
    if commit is None:
        return None
    if not status:
        return {"commit": commit, "dirty": None}
    changed = _git(directory, "status", "--porcelain", "--untracked-files=no")
    return {"commit": commit, "dirty": bool(changed)}


def differences(recorded: dict[str, Any] | None, current: dict[str, Any]) -> list[str]:
    """Every difference that can change a number, one line each ("" recorded means unrecorded)."""
    if not recorded:
        return ["no provenance was recorded (made before provenance was kept)"]
    found = []
    for key in ("python", "implementation", "platform"):
        if recorded.get(key) != current.get(key):
            found.append(f"{key}: {recorded.get(key)} -> {current.get(key)}")
    for name in sorted(set(recorded.get("packages") or {}) | set(current.get("packages") or {})):
        was, now = (recorded.get("packages") or {}).get(name), (current.get("packages") or {}).get(name)
        if was != now:
            found.append(f"{name}: {was or 'not installed'} -> {now or 'not installed'}")
    was, now = (recorded.get("git") or {}).get("commit"), (current.get("git") or {}).get("commit")
    if was != now:
        found.append(f"git commit: {was or 'none'} -> {now or 'none'}")
    for name in FAMILY_FILES:
        was, now = (
            (recorded.get("family_files") or {}).get(name),
            (current.get("family_files") or {}).get(name),
        )
        if was != now:
            found.append(f"family {name}: sha256 {was or 'absent'} -> {now or 'absent'}")
    return found


def report(
    sources: list[tuple[str, dict[str, Any] | None]], current: dict[str, Any], strict: bool
) -> list[str]:
    """The differences of ``current`` against each recorded (label, provenance), as lines; raises
    ProvenanceError when ``strict`` and there is any."""
    lines = []
    for label, recorded in sources:
        lines += [f"{label}: {line}" for line in differences(recorded, current)]
    if strict and lines:
        raise ProvenanceError(
            "--strict-provenance: the environment differs from the recorded one:\n  " + "\n  ".join(lines)
        )
    return lines


def _version(distribution: str) -> str | None:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return None


def _git(directory: Path, *args: str) -> str | None:
    try:
        done = subprocess.run(
            ["git", "-C", str(directory), *args],
            capture_output=True,
            text=True,
            timeout=GIT_TIMEOUT_S,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.strip() if done.returncode == 0 else None
