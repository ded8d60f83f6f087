"""Optional dependencies: the extra that brings each, and one line saying so when it is missing.

The base install runs the envs and the key-free agent; ``--proposer anthropic | openai`` needs
``[llm]``, ``--proposer gp`` ``[gp]`` (Optuna's GPSampler is written in torch), ``--executor
ray`` ``[ray]``. A command that needs one checks it before it starts (``autoresearch`` prints the
message and exits 2), never half-way through a campaign.
"""

from __future__ import annotations

import importlib
from types import ModuleType


class MissingExtra(ImportError):
    """An optional dependency is not installed; the message names the extra that brings it."""


def require(module: str, extra: str, needed_by: str) -> ModuleType:
    """Import ``module``, or raise MissingExtra: '``needed_by`` needs ``module`` ... pip install'."""
    try:
        return importlib.import_module(module)
    except ImportError as err:
        raise MissingExtra(
            f"{needed_by} needs {module}, which is not installed here ({err}): "
            f"pip install 'cwh-autoresearch[{extra}]'"
        ) from err
