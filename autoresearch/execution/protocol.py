"""What a family's train.py prints that autoresearch reads (docs/family-contract.md): one
``FINAL_METRIC: {json}`` line, optional ``PROGRESS: {"step", <metric>}`` lines, both read from the
run's stdout in bounded memory (:class:`StdoutReader`); what makes a FINAL_METRIC object valid, and
valid for the split the run was scored on (autoresearch.splits reads its scores).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from autoresearch.space import is_finite_number
from autoresearch.splits import Split, split_parts

FINAL_METRIC_PREFIX = "FINAL_METRIC:"
PROGRESS_PREFIX = "PROGRESS:"
_FINAL, _PROGRESS = FINAL_METRIC_PREFIX.encode(), PROGRESS_PREFIX.encode()
# stdout is read in blocks, at most POLL_READ bytes a poll, keeping no line longer than MAX_LINE
# bytes: a protocol line is about 1 KB, so the loop's memory never grows with what a run prints.
READ_BLOCK = 1 << 20
POLL_READ = 16 << 20
MAX_LINE = 1 << 20
# A run's learning curve is kept thinned to at most this many points, evenly spaced, and its last;
# every point is still heard (an early-stop pruner judges each). The prompts subsample it further.
MAX_POINTS = 1000


def check_final_metric(final_metric: Any, metric: str, run_id: str) -> tuple[float | None, str | None]:
    """(primary metric, None) for a valid FINAL_METRIC object, else (None, why not)."""
    if not isinstance(final_metric, dict):
        return None, f"FINAL_METRIC is not a JSON object: {str(final_metric)[:80]}"
    if final_metric.get("run_id") != run_id:
        return None, f"FINAL_METRIC run_id is {final_metric.get('run_id')!r}, expected {run_id!r}"
    if metric not in final_metric:
        return None, f"FINAL_METRIC has no primary metric {metric!r}"
    value = final_metric[metric]
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return None, f"FINAL_METRIC {metric!r} is not a number: {_describe(value)}"
    if isinstance(value, float) and not math.isfinite(value):
        return None, f"FINAL_METRIC {metric!r} is not finite: {value!r}"
    where = _unbounded_int(final_metric)
    if where is not None:
        return None, f"FINAL_METRIC holds an integer too large for a float at {where}"
    return float(value), None


def _unbounded_int(data: Any) -> str | None:
    """Where parsed JSON holds an integer float() cannot hold (JSON integers are unbounded), or None.
    Such a number anywhere in a FINAL_METRIC object (its metric, its constraints) raises OverflowError where used."""
    stack: list[tuple[tuple[Any, ...], Any]] = [((), data)]
    while stack:  # iterative: the data came from an untrusted line
        path, item = stack.pop()
        if isinstance(item, dict):
            stack.extend(((*path, k), v) for k, v in item.items())
        elif isinstance(item, list):
            stack.extend(((*path, i), v) for i, v in enumerate(item))
        elif isinstance(item, int) and not isinstance(item, bool) and not is_finite_number(item):
            return "".join(f"[{key!r}]" for key in path) or "its top level"
    return None


def _describe(value: Any) -> str:
    huge = isinstance(value, int) and not isinstance(value, bool) and not is_finite_number(value)
    text = "a huge integer" if huge else json.dumps(value) if isinstance(value, bool) else repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _loads(text: str | bytes) -> Any:
    """json.loads that fails with ValueError only: a nesting too deep raises RecursionError."""
    try:
        return json.loads(text)
    except RecursionError:
        raise ValueError("nested too deeply") from None


def parse_final_metric(
    stdout: str, metric: str, run_id: str
) -> tuple[dict[str, Any] | None, float | None, str | None]:
    """(FINAL_METRIC object, primary metric, None) from exactly one valid FINAL_METRIC line, else
    (.., .., reason)."""
    lines = [line for line in stdout.splitlines() if line.startswith(FINAL_METRIC_PREFIX)]
    return read_final_metric(lines[:1], len(lines), metric, run_id)


def read_final_metric(
    lines: list[str], count: int, metric: str, run_id: str
) -> tuple[dict[str, Any] | None, float | None, str | None]:
    """:func:`parse_final_metric` from the first FINAL_METRIC line (or none) and how many there were."""
    if count == 0:
        return None, None, "no FINAL_METRIC line on stdout"
    if count > 1:
        return None, None, f"{count} FINAL_METRIC lines on stdout; exactly one is required"
    if not lines:
        return None, None, f"the FINAL_METRIC line is longer than {MAX_LINE} bytes"
    try:
        final_metric = _loads(lines[0][len(FINAL_METRIC_PREFIX) :])
    except ValueError as err:
        return None, None, f"FINAL_METRIC is not valid JSON ({err})"
    value, reason = check_final_metric(final_metric, metric, run_id)
    return (final_metric if reason is None else None), value, reason


def check_split(final_metric: dict[str, Any], metric: str, split: Split) -> str | None:
    """Why a valid FINAL_METRIC object does not hold what a run scored on ``split`` must, or None:
    the split named, the primary metric on each split it holds (the search split's always, the top's
    among them), and no test-split value in a search run."""
    said = final_metric.get("eval_split", Split.SEARCH.value)
    if said != split.value:
        return f"FINAL_METRIC says it was scored on the {said!r} split, but the run asked for {split.value!r}"
    parts = split_parts(final_metric)
    if split is Split.SEARCH and Split.TEST in parts:
        return "FINAL_METRIC of a search run holds test-split metrics (splits.test)"
    for needed in dict.fromkeys((Split.SEARCH, split)):
        if not isinstance(parts.get(needed), dict):
            return f"FINAL_METRIC of a {split.value} run has no splits.{needed.value} object"
    run_id = final_metric["run_id"]
    for part_split, part in parts.items():
        if not isinstance(part, dict) or check_final_metric({**part, "run_id": run_id}, metric, run_id)[1]:
            return f"FINAL_METRIC splits.{part_split.value} has no finite primary metric {metric!r}"
    if parts[split][metric] != final_metric[metric]:
        return f"FINAL_METRIC splits.{split.value}.{metric} differs from the {metric!r} on top"
    return None


def parse_progress(line: str, metric: str) -> dict[str, Any] | None:
    """{"step", "value"} from a valid PROGRESS line, else None (a malformed line is ignored)."""
    if not line.startswith(PROGRESS_PREFIX):
        return None
    try:
        data = _loads(line[len(PROGRESS_PREFIX) :])
    except ValueError:
        return None
    if not isinstance(data, dict):
        return None
    step, value = data.get("step"), data.get(metric)
    if not isinstance(step, int) or not is_finite_number(step) or not is_finite_number(value):
        return None
    return {"step": step, "value": float(value)}


class StdoutReader:
    """Reads a run's stdout file as it grows, in bounded memory, and keeps only the protocol lines.

    A line ends at ``\n`` or ``\r`` (a progress bar's carriage returns end lines too, so they are
    read once and dropped). Each PROGRESS point is heard by ``on_report(step, value)``; once it
    answers True, ``stop`` is set. The points are kept thinned (:attr:`curve`: at most
    :data:`MAX_POINTS` of them, evenly spaced, and the last). Of the FINAL_METRIC lines the first is kept and all are
    counted. A line longer than :data:`MAX_LINE` bytes is skipped (a FINAL_METRIC one is counted),
    so memory stays bounded whatever the run prints.
    """

    def __init__(self, path: Path, metric: str, on_report: Callable[[int, float], bool] | None):
        self.path, self.metric, self.on_report = path, metric, on_report
        self.offset = 0
        self.partial = b""  # the start of a line not yet ended
        self.skipping = False  # inside a line longer than MAX_LINE, dropped up to its end
        self.points: list[dict[str, Any]] = []  # every stride-th point heard
        self.last: dict[str, Any] | None = None  # the last point heard
        self._heard, self._stride = 0, 1
        self.finals: list[str] = []  # the first FINAL_METRIC line
        self.n_finals = 0
        self.stop = False

    def poll(self, budget: int = POLL_READ) -> bool:
        """Read (up to ``budget`` bytes of) what was appended since the last call; True when the run
        should stop. A line still being written waits for the next call."""
        try:
            with open(self.path, "rb") as f:
                f.seek(self.offset)
                while budget > 0 and (block := f.read(min(READ_BLOCK, budget))):
                    self.offset += len(block)
                    budget -= len(block)
                    self._feed(block)
        except FileNotFoundError:
            pass
        return self.stop

    def finish(self) -> None:
        """The run is over: read the rest; its last line needs no line end. Points are kept, not judged."""
        self.on_report = None
        before = -1
        while self.offset != before:
            before = self.offset
            self.poll()
        if self.partial and not self.skipping:
            self._line(self.partial)
        self.partial, self.skipping = b"", False

    def _feed(self, block: bytes) -> None:
        data = self.partial + block
        end = max(data.rfind(b"\n"), data.rfind(b"\r"))
        complete, self.partial = data[: end + 1], data[end + 1 :]
        if self.skipping and complete:  # the overlong line ends at the first line end
            cut = min(i for i in (complete.find(b"\n"), complete.find(b"\r")) if i >= 0)
            complete, self.skipping = complete[cut + 1 :], False
        if self.skipping:
            self.partial = b""
        elif len(self.partial) > MAX_LINE:
            self._overlong(self.partial)
            self.partial, self.skipping = b"", True
        # Most output holds no protocol line: skip the split unless one may be there.
        if _PROGRESS in complete or _FINAL in complete:
            for raw in complete.splitlines():
                self._line(raw)

    def _overlong(self, start: bytes) -> None:
        if start.startswith(_FINAL):
            self.n_finals += 1  # counted, not kept: the run fails with the reason

    def _line(self, raw: bytes) -> None:
        if len(raw) > MAX_LINE:
            self._overlong(raw)
            return
        if raw.startswith(_FINAL):
            self.n_finals += 1
            if self.n_finals == 1:
                self.finals.append(raw.decode("utf-8", errors="replace"))
            return
        point = parse_progress(raw.decode("utf-8", errors="replace"), self.metric)
        if point is None or self.stop:
            return
        self._keep(point)
        if self.on_report is not None and self.on_report(point["step"], point["value"]):
            self.stop = True

    def _keep(self, point: dict[str, Any]) -> None:
        index, self._heard, self.last = self._heard, self._heard + 1, point
        if index % self._stride:
            return
        if len(self.points) == MAX_POINTS:  # full: every other point goes and the spacing doubles
            self.points, self._stride = self.points[::2], 2 * self._stride
            if index % self._stride:
                return
        self.points.append(point)

    @property
    def curve(self) -> list[dict[str, Any]]:
        """The learning curve as kept: the thinned points, then the last point heard."""
        if self.last is None or (self.points and self.points[-1] is self.last):
            return list(self.points)
        return [*self.points, self.last]
