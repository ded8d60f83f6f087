"""The family.json fields the audit owns.

family.json is read-modify-written under its lock and replaced atomically, so two audits (or an
audit and a campaign updating its own family.json copy) never lose each other's writes.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from autoresearch.journal import update_json

T = TypeVar("T")


def set_family_field(family_dir: str | os.PathLike[str], field: str, value: Any) -> None:
    """Write one field of a family's family.json (seed_noise or best): a deliberate write, since the
    seed noise and the audited best are properties of the family, not of one campaign."""
    update_json(Path(family_dir) / "family.json", lambda data: data.__setitem__(field, value))


def update_family(family_dir: str | os.PathLike[str], decide: Callable[[dict[str, Any]], T]) -> T:
    """Read-modify-write family.json under its lock and return what ``decide`` returns. ``decide``
    sees the file as it is at the moment of writing, so two audits of one family (each deciding
    whether its candidate replaces the best) never decide on a state the other has since changed."""
    outcome: list[T] = []
    update_json(Path(family_dir) / "family.json", lambda data: outcome.append(decide(data)))
    return outcome[0]
