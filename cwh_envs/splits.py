"""The shipped evaluation splits: the benchmark's fixed starts, their identity and their checks.

A benchmark's test set is an artefact, not a computation. The screened starts (and docking points)
of every search and sealed test split that the families score on ship with the package, in
``cwh_envs/data/`` beside ``manifest.json``, which holds each file's sha256. Screening (drawing
starts and keeping those the expert solves) ran once, when a split was made
(``scripts/make_splits.py``); a user's machine never screens them again, so two machines whose
solvers round differently still score on the same starts.

A split's **identity** (:func:`split_identity`) is a hash of its starts and docking points alone,
never of the expert's floats: the expert's trajectories from those starts are still solved on the
user's machine (they give the fuel reference) and are checked against the energy shipped per
start, within :data:`ENERGY_RTOL`. Splits are nested: the first n starts of a shipped split are
the split of size n, with their own identity.

Versioning, as Gymnasium versions an env id: a shipped split never changes under its name. A new
set of starts for the same problem and split is a new entry with ``version`` one higher; a change to
a problem's constants or an env's behaviour is a new env id (``-v1``), with its own splits.
``tests/test_shipped_splits.py`` holds every (name, version)'s identity and fails when a file
changes without a new version.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from cwh_envs.problems import SCORING_ONLY

DATA_DIR = Path(__file__).with_name("data")
MANIFEST = DATA_DIR / "manifest.json"
MANIFEST_FORMAT = 1
# Relative agreement asked of a locally solved expert energy with the shipped one, per start. The
# docking SCP stops on a relative cost change of 1e-6 (cwh_envs.experts.SCP_COST_TOLERANCE), so two
# machines that round differently may stop an iterate apart and agree to about 1e-6; 1e-4 leaves a
# factor 100. A different start, or another local optimum of the non-convex keep-out problem, moves
# a start's energy by percents.
ENERGY_RTOL = 1e-4


class SplitError(ValueError):
    """Shipped split data that does not match its manifest, or an expert that disagrees with it."""


def split_identity(starts, goals) -> str:
    """sha256 (16 hex digits) of the starts (n, 6) and docking points (n, 3) as float64: what a split
    is, whatever the expert computes from it."""
    digest = hashlib.sha256()
    for name, array in (("starts", starts), ("goals", goals)):
        array = np.ascontiguousarray(array, dtype="<f8")
        digest.update(f"{name}:{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()[:16]


def describe_start(state) -> str:
    """A start on one line, for an error message: [x, y, z, vx, vy, vz] to 6 digits."""
    return "[" + ", ".join(f"{float(v):.6g}" for v in state) + "]"


def problem_fields(problem) -> dict:
    """A problem as the manifest writes it: its type and every constant that decides the starts and
    the expert, tuples as lists (scoring-only constants, :data:`cwh_envs.problems.SCORING_ONLY`, are
    left out: the same starts and expert serve every capture envelope)."""
    fields = {
        k: list(v) if isinstance(v, tuple) else v
        for k, v in problem.as_dict().items()
        if k not in SCORING_ONLY
    }
    return {"type": type(problem).__name__, **fields}


@dataclass(frozen=True)
class ShippedSplit:
    """One shipped split: ``starts`` (n, 6) [m, m/s], ``goals`` (n, 3) [m] (zeros for rendezvous) and
    the expert's ``energy`` (n,) [N^2 s] from each start, as built when the split was made."""

    name: str  # e.g. "docking-constrained/test"
    version: int
    task: str
    split: str
    starts: np.ndarray
    goals: np.ndarray
    energy: np.ndarray

    @property
    def label(self) -> str:
        return f"{self.name}-v{self.version}"

    def __len__(self) -> int:
        return len(self.starts)

    def first(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The split of size ``n``: its first n starts and docking points."""
        if n > len(self):
            raise ValueError(
                f"the shipped split {self.label} holds {len(self)} starts; n={n} asks for more "
                "(a benchmark split has a fixed size: ask for at most that many)"
            )
        return self.starts[:n], self.goals[:n]

    def energy_mismatch(self, energy: np.ndarray) -> str | None:
        """Why an expert's energies from the first len(energy) starts disagree with the shipped ones."""
        reference = self.energy[: len(energy)]
        off = np.abs(energy - reference) > ENERGY_RTOL * np.abs(reference)
        if not off.any():
            return None
        i = int(np.flatnonzero(off)[0])
        return (
            f"the expert solved here from start {i} of {self.label} ({describe_start(self.starts[i])})"
            f" spends energy {energy[i]:.9g}, the shipped reference is {reference[i]:.9g} (relative"
            f" tolerance {ENERGY_RTOL:g}); {int(off.sum())} start(s) disagree. The fuel ratios of this"
            " machine would not be the benchmark's: report it with the output of `pip freeze`"
        )


@lru_cache(maxsize=1)
def manifest() -> dict:
    """The manifest of every shipped split (read once per process)."""
    data = json.loads(MANIFEST.read_text(encoding="utf-8"))
    if data.get("format") != MANIFEST_FORMAT:
        raise SplitError(f"{MANIFEST}: format {data.get('format')!r}, this cwh_envs reads {MANIFEST_FORMAT}")
    return data


def find(task: str, problem, split: str) -> dict | None:
    """The newest manifest entry for (task, problem, split), or None when none ships."""
    wanted = problem_fields(problem)
    entries = [
        e
        for e in manifest()["splits"]
        if e["task"] == task and e["split"] == split and e["problem"] == wanted
    ]
    return max(entries, key=lambda e: e["version"], default=None)


def shipped_split(task: str, problem, split: str) -> ShippedSplit | None:
    """The shipped split for (task, problem, split), verified against its checksum; None when no split
    ships for this problem (a problem of the user's own: its starts are screened locally)."""
    entry = find(task, problem, split)
    return None if entry is None else _load(entry["name"], entry["version"])


@lru_cache(maxsize=16)
def _load(name: str, version: int) -> ShippedSplit:
    entry = next(e for e in manifest()["splits"] if e["name"] == name and e["version"] == version)
    path = DATA_DIR / entry["file"]
    try:
        payload = path.read_bytes()
    except OSError as err:
        raise SplitError(f"shipped split {name}-v{version}: cannot read {path} ({err})") from err
    found = hashlib.sha256(payload).hexdigest()
    if found != entry["sha256"]:
        raise SplitError(
            f"shipped split {name}-v{version}: {path} has sha256 {found}, the manifest says "
            f"{entry['sha256']}: the file was changed or damaged; reinstall cwh-autoresearch"
        )
    with np.load(path, allow_pickle=False) as stored:
        arrays = {key: stored[key] for key in ("starts", "goals", "energy")}
    for array in arrays.values():
        array.setflags(write=False)
    if split_identity(arrays["starts"], arrays["goals"]) != entry["identity"]:
        raise SplitError(f"shipped split {name}-v{version}: its starts do not have the manifest's identity")
    return ShippedSplit(name, version, entry["task"], entry["split"], **arrays)
