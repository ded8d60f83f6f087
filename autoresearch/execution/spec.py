"""RunSpec: everything one training run needs, as one value that any executor can carry; RunHooks:
who hears the run while it trains, and what stops it."""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from autoresearch.family import Family
from autoresearch.splits import Split


@dataclass(frozen=True)
class RunSpec:
    """Train ``config`` of ``family`` at ``seed`` in ``run_dir`` (used once), appending its FINAL_METRIC
    line to ``runs_log``, within ``timeout`` seconds, scored on ``split`` (the sealed test split: the
    audit only, and then on the search split too). ``time_budget`` is the training seconds the run is
    granted (``AUTORESEARCH_TIME_BUDGET``): a family that honours it stops training there and is
    scored as it stands; ``timeout`` still kills one that does not."""

    family: Family
    config: dict[str, Any]
    run_id: str
    seed: int
    run_dir: Path
    runs_log: Path
    timeout: float
    split: Split = Split.SEARCH
    time_budget: float | None = None


@dataclass(frozen=True)
class RunHooks:
    """``on_progress(seconds)`` hears the run is alive; ``on_report(step, value)`` hears each PROGRESS
    point, and True stops the run early; setting ``cancel`` (another thread) kills the run and raises
    KeyboardInterrupt, leaving no result."""

    on_progress: Callable[[float], None] | None = None
    on_report: Callable[[int, float], bool] | None = None
    cancel: threading.Event | None = None


NO_HOOKS = RunHooks()  # a run nobody hears, stopped only by its timeout
