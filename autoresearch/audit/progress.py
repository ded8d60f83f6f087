"""What an audit step shows while its runs train: a rich bar on a terminal, one line per run otherwise.

Audit steps run for minutes to hours; a silent one looks hung. Output goes to stderr so that the
step summaries on stdout stay clean for pipes.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from autoresearch.campaign.audit_log import TrialRow
from autoresearch.splits import Split


def _outcome(row: TrialRow) -> str:
    """The row in a few words: its value on the split its step judges (verify: the sealed test split),
    named when it is not the search split, so that a run feasible on the search split and infeasible
    where the gate looks does not read as a contradiction."""
    if not row.ok:
        return f"{row.key} {row.status}"
    judged, wall = row.on(row.split), row.wall_seconds
    score = judged or row.scores.search
    where = f" on {row.split}" if judged is not None and row.split is not Split.SEARCH else ""
    feasible = "" if score.feasible else " infeasible"
    return f"{row.key} {score.metric:.5g}{where}{feasible}" + (f" ({wall:.0f}s)" if wall is not None else "")


class TrialProgress:
    """Context manager: ``advance(row)`` after each finished run of a step of ``total`` runs."""

    def __init__(self, step: str, total: int, already_done: int, stream: TextIO | None = None):
        self.step, self.total, self.done = step, total, already_done
        self.stream = stream or sys.stderr
        self.started = time.monotonic()
        self.bar: Progress | None = None

    def __enter__(self) -> TrialProgress:
        todo = self.total - self.done
        if self.stream.isatty():
            self.bar = Progress(
                TextColumn(f"[bold]{self.step}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                TextColumn("{task.description}"),
                console=Console(file=self.stream),
                transient=False,
            )
            self.bar.start()
            self.task = self.bar.add_task(f"{todo} to run", total=self.total, completed=self.done)
        else:
            print(f"[{self.step}] {todo} of {self.total} runs to do", file=self.stream, flush=True)
        return self

    def advance(self, row: TrialRow) -> None:
        self.done += 1
        if self.bar is not None:
            self.bar.update(self.task, advance=1, description=f"last: {_outcome(row)}")
        else:
            elapsed = time.monotonic() - self.started
            print(
                f"[{self.step}] {self.done}/{self.total} {_outcome(row)} | {elapsed:.0f}s elapsed",
                file=self.stream,
                flush=True,
            )

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.stop()
