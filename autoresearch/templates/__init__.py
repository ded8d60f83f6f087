"""Family templates for ``autoresearch init``.

A template is a directory holding a family (docs/family-contract.md). Packages offer templates
through the ``autoresearch.templates`` entry-point group: each entry is a callable that returns
the directory (a path or an ``importlib.resources`` Traversable). This package offers
``minimal``, a torch-free family that runs in milliseconds; cwh-autoresearch's own entry points
add its research families (``docking``, ``rendezvous``), and any other package may add more.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from importlib.metadata import EntryPoint, entry_points
from importlib.resources import files
from pathlib import Path
from typing import Any

from autoresearch.family import PLAIN_NAME, family_problems, own_file
from autoresearch.ledger import LEDGER_FILE

GROUP = "autoresearch.templates"
MINIMAL_TEMPLATE = Path(__file__).resolve().parent / "minimal"


class TemplateError(ValueError):
    """The template or the target directory cannot make a family."""


def minimal():
    return files(__name__) / "minimal"


def available() -> dict[str, EntryPoint]:
    """Template name -> its entry point, over every installed package."""
    return {ep.name: ep for ep in entry_points(group=GROUP)}


def write_family(target: Path, template: str, name: str | None = None) -> dict[str, Any]:
    """Write a new family at ``target`` (absent or an empty directory) from ``template`` and return
    its family.json. The family is named ``name`` (default: the directory's name) and starts with
    no best and no ledger (no measured seed noise), which belong to the template's own campaigns. The files
    are written into a temporary sibling and renamed into place, so a failure leaves nothing."""
    templates = available()
    if template not in templates:
        raise TemplateError(f"no template {template!r}; installed: {', '.join(sorted(templates)) or 'none'}")
    name = target.name if name is None else name
    if not PLAIN_NAME.fullmatch(name) or ".." in name:
        raise TemplateError(
            f"{name!r} is not a plain family name (letters, digits, '_', '-', '.'); give one with --name"
        )
    if target.exists() and not (target.is_dir() and not any(target.iterdir())):
        raise TemplateError(f"{target}: exists and is not an empty directory")
    if target.is_symlink():  # a link to an empty directory: the family goes where it points
        target = target.resolve()
    source, registry = _read_template(templates[template])
    registry = {k: v for k, v in registry.items() if k != "seed_noise"}  # a template in the old layout
    registry.update(name=name, best=None)
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.parent))
    try:
        for item in source.iterdir():
            # no run output dir, and neither the registry nor the ledger of the template's own campaigns
            if item.is_file() and own_file(item.name) and item.name not in ("family.json", LEDGER_FILE):
                (staging / item.name).write_bytes(item.read_bytes())
        (staging / "family.json").write_text(json.dumps(registry, indent=2) + "\n", encoding="utf-8")
        problems = family_problems(staging)
        if problems:
            raise TemplateError(f"template {template!r} does not make a valid family: {problems[0]}")
        os.chmod(staging, 0o777 & ~_umask())
        os.replace(staging, target)  # replaces an empty directory in one step
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return registry


def _read_template(entry: EntryPoint) -> tuple[Any, dict[str, Any]]:
    """The template's directory and its family.json; TemplateError for whatever a third-party
    template gets wrong (its entry point raises, its family.json is missing or no JSON object)."""
    try:
        source = entry.load()()
        registry = json.loads((source / "family.json").read_text(encoding="utf-8"))
    except RecursionError:
        registry = None
    except Exception as err:  # the template's own code, and its files: anything can go wrong there
        raise TemplateError(
            f"template {entry.name!r} ({entry.value}) cannot be read: {type(err).__name__}: {err}"
        ) from None
    if not isinstance(registry, dict):
        raise TemplateError(f"template {entry.name!r} ({entry.value}): its family.json holds no JSON object")
    return source, registry


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
