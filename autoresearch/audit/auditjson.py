"""audit.json (one key per audit step) and the family.json fields the audit owns.

Both files are read-modify-written under their lock and replaced atomically, so two steps (or a
step and a campaign updating its own family.json copy) never lose each other's writes.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from autoresearch.journal import JournalError, lock_for, read_json, write_json_atomic

AUDIT_JSON = "audit.json"
T = TypeVar("T")


def audit_path(campaign: str | os.PathLike[str]) -> Path:
    return Path(campaign) / AUDIT_JSON


def read_audit(campaign: str | os.PathLike[str]) -> dict[str, Any]:
    path = audit_path(campaign)
    return read_json(path) if path.exists() else {}


def _update(path: Path, change: Callable[[dict[str, Any]], None]) -> dict[str, Any]:
    lock = lock_for(path)
    with lock:
        data = read_json(path) if path.exists() else {}
        if not isinstance(data, dict):
            raise JournalError(f"{path}: must hold a JSON object")
        change(data)
        write_json_atomic(path, data)
    return data


def write_step(campaign: str | os.PathLike[str], step: str, part: dict[str, Any]) -> dict[str, Any]:
    """Replace audit.json[step] with ``part``."""
    return _update(audit_path(campaign), lambda data: data.__setitem__(step, part))


def set_family_field(family_dir: str | os.PathLike[str], field: str, value: Any) -> None:
    """Write one field of a family's family.json (seed_noise or best): a deliberate write, since the
    seed noise and the audited best are properties of the family, not of one campaign."""
    _update(Path(family_dir) / "family.json", lambda data: data.__setitem__(field, value))


def update_family(family_dir: str | os.PathLike[str], decide: Callable[[dict[str, Any]], T]) -> T:
    """Read-modify-write family.json under its lock and return what ``decide`` returns. ``decide``
    sees the file as it is at the moment of writing, so two audits of one family (each deciding
    whether its candidate replaces the best) never decide on a state the other has since changed."""
    outcome: list[T] = []
    _update(Path(family_dir) / "family.json", lambda data: outcome.append(decide(data)))
    return outcome[0]
