"""What the loop shows while it runs: a rich live table on a terminal, one line per event otherwise.

The orchestrator calls a :class:`View`; the base class shows nothing (used in tests and by
callers that want silence). ``run_progress`` comes from the thread supervising that run (with
``loop --workers K`` several at once); every other event comes from the loop's main thread.
"""

from __future__ import annotations

import json
import sys
import threading
from typing import Any, ClassVar, TextIO

from autoresearch.campaign import Record, Status
from autoresearch.proposers.base import Proposal

MAX_ROWS = 20
# What a plain line may not pass to the terminal from a run's output or a proposal: control
# characters (ESC starts ANSI sequences that retitle or clear it), bar the tab and the newline.
_CONTROL = {c: f"\\x{c:02x}" for c in (*range(0x20), *range(0x7F, 0xA0)) if c not in (0x09, 0x0A)}


def _short(value: Any, width: int) -> str:
    text = value if isinstance(value, str) else json.dumps(value)
    return text if len(text) <= width else text[: width - 1] + "…"


def _compact(overrides: Any) -> str:
    """NAME=value pairs with short floats: one table cell, not a JSON dump."""
    if not isinstance(overrides, dict):
        return _short(overrides, 60)
    return " ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in overrides.items())


def _number(value: Any) -> str:
    return "-" if value is None else f"{value:.5g}"


def _verdict(record: Record) -> str:
    """The run's verdict and the noise it was judged against (a later one may judge it otherwise)."""
    noise = record.verdict_noise
    if not noise:
        return str(record.verdict)
    if noise.get("measured_at"):
        return f"{record.verdict}, against seed noise σ {noise['sigma']:.3g}"
    return f"{record.verdict}, against 5% of the best ({noise['sigma']:.3g}): no seed noise measured yet"


def _outcome(record: Record) -> str:
    """Status column: what happened, with the run id when something ran."""
    if record.ran:
        wall = record.wall_seconds
        return record.run_id + (f" ({wall:.1f}s)" if wall is not None else "")
    if record.status.started_a_run:
        return f"{record.run_id} {record.run_status}"
    if record.status is Status.STOPPED:
        return f"stopped: {record.trigger}"
    return record.status.value


class View:
    """Receives the loop's events; shows nothing."""

    def iteration_started(self, iteration: int) -> None:
        pass

    def proposal(self, iteration: int, proposer: str, proposal: Proposal) -> None:
        pass

    def run_started(self, run_id: str) -> None:
        pass

    def run_progress(self, elapsed: float, run_id: str | None = None) -> None:
        pass

    def record(self, record: Record, closest: str) -> None:
        pass

    def close(self) -> None:
        pass


class PlainView(View):
    """One line per event, for logs and pipes: a run started (with several in flight), a record.
    ``spend``: an LLM proposer's cumulative spend goes on each line (a key-free one spends nothing)."""

    def __init__(self, metric: str, stream: TextIO | None = None, spend: bool = True):
        self.metric = metric
        self.spend = spend
        self.stream = stream or sys.stdout
        self.iteration: int | None = None
        self.in_flight: set[str] = set()

    def iteration_started(self, iteration: int) -> None:
        self.iteration = iteration

    def run_started(self, run_id: str) -> None:
        self.in_flight.add(run_id)
        if len(self.in_flight) > 1:  # one at a time, the record line says it all
            others = ", ".join(sorted(self.in_flight - {run_id}))
            print(
                f"[it {self.iteration}] started {run_id} (also running: {others})",
                file=self.stream,
                flush=True,
            )

    def record(self, record: Record, closest: str) -> None:
        # The loop's own stop took the next iteration number but is no experiment: not numbered.
        where = "[stop]" if record.status is Status.STOPPED else f"[it {record.iteration}]"
        head = f"{where} {record.proposer}: {_outcome(record)}"
        if record.ran:
            body = f"{self.metric}={_number(record.metric)} ({_verdict(record)})"
        else:
            body = record.reason or ""
        spent = f" spend=${record.cumulative_cost_usd:.4f}" if self.spend else ""
        tail = f"best={_number(record.best_so_far)}{spent} | {closest}"
        self.in_flight.discard(record.run_id)
        print(f"{head} {body} | {tail}".translate(_CONTROL), file=self.stream, flush=True)


class RichView(View):
    """A live table: iteration, hypothesis, overrides, run progress (seconds of its limit), metric,
    verdict, best, and an LLM proposer's spend. The columns the eye reads first (run, metric,
    verdict, best) keep their width at 120 columns; the free text shares what is left."""

    # column -> width settings: fixed widths for short fields, shares of the rest for free text
    COLUMNS: ClassVar[dict[str, dict[str, int]]] = {
        "it": {"min_width": 3},
        "proposer": {"max_width": 8},
        "hypothesis": {"ratio": 2, "min_width": 8},
        "overrides": {"ratio": 3, "min_width": 10},
        "run": {"min_width": 19},
        "metric": {"min_width": 8},
        "verdict": {"min_width": 12, "ratio": 1},
        "best": {"min_width": 8},
        "spend": {"min_width": 7},
    }

    def __init__(self, metric: str, console: Any = None, spend: bool = True, run_limit: float | None = None):
        from rich.console import Console
        from rich.live import Live

        self.columns = {k: v for k, v in self.COLUMNS.items() if spend or k != "spend"}
        self.run_limit = run_limit
        self.metric = metric
        self.rows: list[dict[str, str]] = []
        self.current: dict[str, str] | None = None  # the iteration being proposed
        self.running: dict[str, dict[str, str]] = {}  # run id -> its row, every run in flight
        self.shown_second: dict[str, int] = {}
        self.latest_run = ""
        self.closest = ""
        self.lock = threading.Lock()  # rows change from the main thread, seconds from run threads
        self.live = Live(self._table(), console=console or Console(), refresh_per_second=4)
        self.live.start()

    def _table(self):
        from rich.table import Table

        table = Table(title=f"autoresearch loop ({self.metric})", caption=self.closest or None, expand=True)
        for column, width in self.columns.items():
            table.add_column(column, no_wrap=True, overflow="ellipsis", **width)  # one line per iteration
        rows = self.rows[-MAX_ROWS:] + list(self.running.values()) + ([self.current] if self.current else [])
        for row in rows:
            table.add_row(*(row.get(c, "") for c in self.columns))
        return table

    def _refresh(self) -> None:
        with self.lock:
            table = self._table()
        self.live.update(table)

    def iteration_started(self, iteration: int) -> None:
        self.current = {"it": str(iteration), "run": "proposing…"}
        self._refresh()

    def proposal(self, iteration: int, proposer: str, proposal: Proposal) -> None:
        annotation = proposal.annotation if isinstance(proposal.annotation, dict) else {}
        hypothesis = annotation.get("hypothesis") or annotation.get("conclusion") or proposal.error or ""
        self.current = {
            "it": str(iteration),
            "proposer": proposer,
            "hypothesis": str(hypothesis),
            "overrides": _compact(proposal.overrides) if proposal.kind == "propose" else proposal.kind,
            "run": "",
        }
        self._refresh()

    def run_started(self, run_id: str) -> None:
        with self.lock:
            self.running[run_id] = dict(self.current or {})
            self.current = None
            self.shown_second[run_id] = -1
            self.latest_run = run_id
        self.run_progress(0.0, run_id)

    def run_progress(self, elapsed: float, run_id: str | None = None) -> None:
        run_id = run_id or self.latest_run
        with self.lock:
            row = self.running.get(run_id)
            if row is None or int(elapsed) == self.shown_second.get(run_id):
                return
            self.shown_second[run_id] = int(elapsed)
            limit = f"/{self.run_limit:.0f}" if self.run_limit else ""  # how far it may still go
            row["run"] = f"{run_id} {int(elapsed)}{limit} s"
        self._refresh()

    def record(self, record: Record, closest: str) -> None:
        with self.lock:
            started = self.running.pop(record.run_id, None) if record.run_id else None
        row = dict(started or self.current or {"it": str(record.iteration), "proposer": record.proposer})
        row.update(
            run=_outcome(record),
            metric=_number(record.metric),
            verdict=record.verdict or ("" if record.ran else record.reason or ""),
            best=_number(record.best_so_far),
            spend=f"${record.cumulative_cost_usd:.4f}",
        )
        self.rows.append(row)
        if started is None:
            self.current = None
        self.closest = f"closest stop: {closest}"
        self._refresh()

    def close(self) -> None:
        self.live.stop()


def make_view(metric: str, plain: bool = False, spend: bool = True, run_limit: float | None = None) -> View:
    """A rich live table on a terminal, else (or with ``plain``) one line per iteration; ``spend``
    shows an LLM proposer's spend, ``run_limit`` (s) the limit each run's elapsed time counts to."""
    if plain or not sys.stdout.isatty():
        return PlainView(metric, spend=spend)
    return RichView(metric, spend=spend, run_limit=run_limit)
