"""The bundled research families as templates for ``autoresearch init --template docking`` (or
``rendezvous``), registered in the ``autoresearch.templates`` entry-point group.

Each directory here is a link to ``families/<name>`` of the source tree, so the wheel ships the
very files the repository runs and git holds them once.
"""

from __future__ import annotations

from importlib.resources import files
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # importlib.resources.abc is new in Python 3.11
    from importlib.resources.abc import Traversable


def docking() -> Traversable:
    return files(__name__) / "docking"


def rendezvous() -> Traversable:
    return files(__name__) / "rendezvous"
