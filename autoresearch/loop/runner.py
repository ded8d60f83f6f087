"""Run one configuration of a family: patch a copy of train.py, execute it, parse its metric.

The family's own train.py is never written. The patched copy lives in the run's directory,
which is also the working directory of the subprocess; ``FAMILY_DIR`` tells the script where its
family's files are, and the family directory is put on ``PYTHONPATH`` so sibling modules import.
The subprocess runs without a shell in its own session (process group); a wall-clock timeout,
an interrupt of the caller, or leftover children after exit all end in ``os.killpg`` of that
group, and in the kill of every other process the run started, found by the run directory in its
``AUTORESEARCH_RUN`` wherever it moved (autoresearch.loop.tracking, which also gives each run a
watchdog that holds its deadline should the supervisor die). A run succeeds only if it exits 0
and prints exactly one valid ``FINAL_METRIC:`` line; stdout is read in bounded memory.

``eval_split="test"`` (the audit, for a family with a sealed test split) adds ``--eval-split
test``: the record is then scored on the test split and must carry the search split's metrics of
the same run under ``search_split``. A search run whose record says it saw the test split fails.

A train.py may also print ``PROGRESS: {"step": <int>, "<metric>": <number>}`` lines (family
contract, optional). They are read from the run's stdout file as they come, by the thread that
supervises the run, kept as the run's learning curve, and handed to ``on_report``; when it answers
True the run is stopped early (its process group killed) with status ``early_stopped``.
"""

from __future__ import annotations

import functools
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Literal

from autoresearch import editable
from autoresearch.family import SEARCH, TEST, Family
from autoresearch.journal import read_json, read_jsonl, repair_torn_tail, write_json_atomic
from autoresearch.loop import tracking
from autoresearch.space import ValidationError, is_finite_number

FINAL_METRIC_PREFIX = "FINAL_METRIC:"
PROGRESS_PREFIX = "PROGRESS:"
_FINAL, _PROGRESS = FINAL_METRIC_PREFIX.encode(), PROGRESS_PREFIX.encode()
KILL_GRACE_S = 2.0
POLL_S = 0.05
STDERR_TAIL = 600
# stdout is read in blocks, at most POLL_READ bytes a poll, keeping no line longer than MAX_LINE
# bytes: a protocol line is about 1 KB, so the loop's memory never grows with what a run prints.
READ_BLOCK = 1 << 20
POLL_READ = 16 << 20
MAX_LINE = 1 << 20

RunStatus = Literal["ok", "failed", "timeout", "early_stopped"]

# Set by a signal while interruptible_runs() is active: every run in flight, in any thread, stops.
_INTERRUPTED = threading.Event()


@dataclass(frozen=True)
class RunResult:
    status: RunStatus
    run_id: str
    record: dict[str, Any] | None
    reason: str | None
    wall_seconds: float | None
    returncode: int | None
    metric: float | None = None
    progress: list[dict[str, Any]] | None = None  # the PROGRESS points, as {"step", "value"}

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> RunResult:
        return cls(**data)


def family_env(family: Family) -> dict[str, str]:
    """The environment of every family subprocess (train.py, prepare.py)."""
    env = dict(os.environ)
    env["FAMILY_DIR"] = str(family.path)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(family.path), env.get("PYTHONPATH")) if p)
    env["PYTHONDONTWRITEBYTECODE"] = "1"  # imports must not leave __pycache__ in the family dir
    env["PYTHONUNBUFFERED"] = "1"
    return env


def check_record(record: Any, metric: str, run_id: str) -> tuple[float | None, str | None]:
    """(metric value, None) for a valid FINAL_METRIC record, else (None, why not)."""
    if not isinstance(record, dict):
        return None, f"FINAL_METRIC is not a JSON object: {str(record)[:80]}"
    if record.get("run_id") != run_id:
        return None, f"FINAL_METRIC run_id is {record.get('run_id')!r}, expected {run_id!r}"
    if metric not in record:
        return None, f"FINAL_METRIC has no primary metric {metric!r}"
    value = record[metric]
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return None, f"FINAL_METRIC {metric!r} is not a number: {_describe(value)}"
    if isinstance(value, float) and not math.isfinite(value):
        return None, f"FINAL_METRIC {metric!r} is not finite: {value!r}"
    where = _unbounded_int(record)
    if where is not None:
        return None, f"FINAL_METRIC holds an integer too large for a float at {where}"
    return float(value), None


def _unbounded_int(data: Any) -> str | None:
    """Where parsed JSON holds an integer float() cannot hold (JSON integers are unbounded), or None.
    Such a number anywhere in a record (its metric, its constraints) raises OverflowError where used."""
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
    text = repr(value) if is_finite_number(value) or not isinstance(value, int) else "a huge integer"
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
    """(record, metric value, None) from exactly one valid FINAL_METRIC line, else (.., .., reason)."""
    lines = [line for line in stdout.splitlines() if line.startswith(FINAL_METRIC_PREFIX)]
    return final_metric(lines[:1], len(lines), metric, run_id)


def final_metric(
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
        record = _loads(lines[0][len(FINAL_METRIC_PREFIX) :])
    except ValueError as err:
        return None, None, f"FINAL_METRIC is not valid JSON ({err})"
    value, reason = check_record(record, metric, run_id)
    return (record if reason is None else None), value, reason


def check_split(record: dict[str, Any], metric: str, eval_split: str) -> str | None:
    """Why a valid record does not hold what an ``eval_split`` run must, or None."""
    said = record.get("eval_split", SEARCH)
    if said != eval_split:
        return f"FINAL_METRIC says it was scored on the {said!r} split, but the run asked for {eval_split!r}"
    if eval_split == TEST:
        search = record.get("search_split")
        if not isinstance(search, dict):
            return "FINAL_METRIC of an --eval-split test run has no 'search_split' object"
        if check_record({**search, "run_id": record["run_id"]}, metric, record["run_id"])[1] is not None:
            return f"FINAL_METRIC search_split has no finite primary metric {metric!r}"
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
    read once and dropped). Each PROGRESS point is kept and ``on_report(step, value)`` is asked;
    once it answers True, ``stop`` is set. Of the FINAL_METRIC lines the first is kept and all are
    counted. A line longer than :data:`MAX_LINE` bytes is skipped (a FINAL_METRIC one is counted),
    so memory stays bounded whatever the run prints.
    """

    def __init__(self, path: Path, metric: str, on_report: Callable[[int, float], bool] | None):
        self.path, self.metric, self.on_report = path, metric, on_report
        self.offset = 0
        self.partial = b""  # the start of a line not yet ended
        self.skipping = False  # inside a line longer than MAX_LINE, dropped up to its end
        self.points: list[dict[str, Any]] = []
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
        self.points.append(point)
        if self.on_report is not None and self.on_report(point["step"], point["value"]):
            self.stop = True


def _tail(path: Path) -> str:
    """The last :data:`STDERR_TAIL` characters of a file, read from its end (it may be huge)."""
    try:
        with open(path, "rb") as f:
            size = f.seek(0, os.SEEK_END)
            f.seek(max(0, size - 4 * STDERR_TAIL))  # up to 4 bytes a character
            text = f.read().decode("utf-8", errors="replace").strip()
    except FileNotFoundError:
        return ""
    return text if len(text) <= STDERR_TAIL and size <= 4 * STDERR_TAIL else "..." + text[-STDERR_TAIL:]


def _kill_group(pgid: int) -> None:
    try:
        os.killpg(pgid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def _terminate(proc: subprocess.Popen) -> None:
    """SIGTERM the whole group, then SIGKILL it after a grace period."""
    try:
        os.killpg(proc.pid, signal.SIGTERM)
    except (ProcessLookupError, PermissionError):
        pass
    try:
        proc.wait(timeout=KILL_GRACE_S)
    except subprocess.TimeoutExpired:
        pass
    _kill_group(proc.pid)
    proc.wait()


@contextmanager
def interruptible_runs() -> Iterator[None]:
    """While active (main thread only), SIGINT and SIGTERM stop every run in flight, in any worker
    thread, killing its process group, then raise KeyboardInterrupt in the main thread.

    Without it a terminated pool leaves its training runs orphaned: they sit in their own sessions.
    """

    def interrupt(signum, frame):
        _INTERRUPTED.set()
        raise KeyboardInterrupt

    _INTERRUPTED.clear()
    previous = {sig: signal.signal(sig, interrupt) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        _INTERRUPTED.clear()


def run_in_group(
    cmd: list[str],
    *,
    cwd: Path,
    env: dict[str, str],
    stdout: Any,
    stderr: Any,
    timeout: float,
    on_start: Callable[[int], None] | None = None,
    on_progress: Callable[[float], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    cancel: threading.Event | None = None,
) -> tuple[int, bool]:
    """(return code, timed out) of ``cmd`` run without a shell in its own process group.

    On timeout, on an exception in the caller (Ctrl-C), when ``should_stop()`` (asked every poll)
    answers True, when ``cancel`` is set (raising KeyboardInterrupt), and after a normal exit (children it left running), the whole group is killed.
    """
    started = time.monotonic()
    proc = subprocess.Popen(
        cmd, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=stdout, stderr=stderr, start_new_session=True
    )
    try:
        if on_start is not None:
            on_start(proc.pid)
        while proc.poll() is None:
            if _INTERRUPTED.is_set() or (cancel is not None and cancel.is_set()):
                raise KeyboardInterrupt
            elapsed = time.monotonic() - started
            if elapsed > timeout:
                _terminate(proc)
                return proc.returncode, True
            if on_progress is not None:
                on_progress(elapsed)
            if should_stop is not None and should_stop():
                _terminate(proc)
                return proc.returncode, False
            time.sleep(POLL_S)
    except BaseException:
        _terminate(proc)
        raise
    _kill_group(proc.pid)
    return proc.returncode, False


@functools.lru_cache(maxsize=8)
def _editable_defaults(train_source: str) -> dict[str, Any]:
    """The editable values of a train.py source; parsed once, not once per run (loop overhead)."""
    return dict(editable.read_region(train_source).values())


def write_train_copy(family: Family, config: dict[str, Any], run_dir: Path) -> Path:
    """runs/<run_id>/train.py: the family's train.py with ``config`` patched in (only changed values)."""
    config = family.space.validate_full(config)
    defaults = family.space.validate_full(_editable_defaults(family.train_source))
    changes = {k: v for k, v in config.items() if type(v) is not type(defaults[k]) or v != defaults[k]}
    target = run_dir / "train.py"
    if target.exists():
        raise FileExistsError(f"{target} already exists: a run directory is used once")
    target.write_text(editable.patch(family.train_source, changes), encoding="utf-8")
    return target


def run_experiment(
    family: Family,
    config: dict[str, Any],
    *,
    run_id: str,
    seed: int,
    run_dir: Path,
    runs_log: Path,
    timeout: float,
    on_progress: Callable[[float], None] | None = None,
    on_report: Callable[[int, float], bool] | None = None,
    cancel: threading.Event | None = None,
    eval_split: str = SEARCH,
) -> RunResult:
    """Train ``config`` at ``seed`` in ``run_dir``; the result is also saved as run_dir/result.json.

    ``on_report(step, value)`` hears each PROGRESS point; True stops the run early. Setting
    ``cancel`` (another thread) kills the run and raises KeyboardInterrupt, leaving no result.
    ``eval_split="test"`` scores the run on the family's sealed test split (the audit only).
    """
    if eval_split not in (SEARCH, TEST) or (eval_split == TEST and not family.has_test_split):
        raise ValueError(f"eval_split {eval_split!r}: family {family.name!r} has no such split")
    run_dir.mkdir(parents=True, exist_ok=True)
    write_train_copy(family, config, run_dir)
    repair_torn_tail(runs_log)  # a run killed mid-append must not glue its fragment to this record
    cmd = [
        sys.executable,
        "train.py",
        "--seed",
        str(seed),
        "--run-id",
        run_id,
        "--runs-log",
        str(Path(runs_log).resolve()),
        "--out",
        str((run_dir / "out").resolve()),
        *(["--eval-split", TEST] if eval_split == TEST else []),
    ]
    started = time.monotonic()
    reader = StdoutReader(run_dir / "stdout.txt", family.metric, on_report)
    tracked = run_dir.resolve()  # what every process of the run carries in RUN_ENV
    watchdog: subprocess.Popen | None = None

    def on_start(pid: int) -> None:
        nonlocal watchdog
        deadline, born = time.time() + timeout, tracking.start_time(pid)
        info = {"pid": pid, "start_time": born, "deadline": deadline, "timeout": timeout, "cmd": cmd}
        write_json_atomic(run_dir / "process.json", info)
        if born is not None:  # None: no /proc, so nothing to watch with
            watchdog = tracking.start_watchdog(tracked, pid, born, deadline)

    try:
        with open(run_dir / "stdout.txt", "wb") as out, open(run_dir / "stderr.txt", "wb") as err:
            returncode, timed_out = run_in_group(
                cmd,
                cwd=run_dir,
                env={**family_env(family), tracking.RUN_ENV: str(tracked)},
                stdout=out,
                stderr=err,
                timeout=timeout,
                on_start=on_start,
                on_progress=on_progress,
                should_stop=reader.poll,
                cancel=cancel,
            )
    finally:
        # However the run ended: what it left outside its process group (a child that called setsid)
        # dies with it, and so does its watchdog, needed only without a supervisor.
        if watchdog is not None:
            watchdog.kill()
            watchdog.wait()
        tracking.kill_all(tracked)
    wall = time.monotonic() - started
    if reader.stop:
        last = reader.points[-1]
        reason = f"stopped early at step {last['step']} ({family.metric} {last['value']:.6g} then)"
        result = RunResult("early_stopped", run_id, None, reason, wall, returncode)
    else:
        reader.finish()
        result = _result(family, run_id, run_dir, reader, returncode, wall, timed_out, timeout, eval_split)
    result = replace(result, progress=reader.points or None)
    write_json_atomic(run_dir / "result.json", result.to_json())
    return result


def _result(
    family: Family,
    run_id: str,
    run_dir: Path,
    reader: StdoutReader,
    returncode: int,
    wall: float,
    timed_out: bool,
    timeout: float,
    eval_split: str,
) -> RunResult:
    if timed_out:
        reason = f"exceeded the {timeout:g} s wall-clock limit; its process group was killed"
        return RunResult("timeout", run_id, None, reason, wall, returncode)
    if returncode != 0:
        tail = _tail(run_dir / "stderr.txt")
        reason = f"train.py exited with code {returncode}" + (f": {tail}" if tail else "")
        return RunResult("failed", run_id, None, reason, wall, returncode)
    record, value, reason = final_metric(reader.finals, reader.n_finals, family.metric, run_id)
    if reason is None:
        reason = check_split(record, family.metric, eval_split)
    if reason is not None:
        return RunResult("failed", run_id, None, reason, wall, returncode)
    return RunResult("ok", run_id, record, None, wall, returncode, value)


def logged_run(
    family: Family, runs_log: Path, run_id: str, config: dict[str, Any], seed: int, eval_split: str = SEARCH
) -> RunResult | None:
    """The outcome of run ``run_id`` from its line in ``runs_log`` (train.py appends it as it ends), for
    a run whose supervisor died before saving its result; None without such a line. A line counts
    only with this configuration and seed: a forged or foreign line is never adopted."""
    for line in read_jsonl(runs_log):
        if not isinstance(line, dict) or line.get("run_id") != run_id or line.get("seed") != seed:
            continue
        try:
            if family.space.validate_full(line.get("config")) != config:
                continue
        except ValidationError:
            continue
        value, reason = check_record(line, family.metric, run_id)
        reason = reason or check_split(line, family.metric, eval_split)
        if reason is not None:
            return RunResult("failed", run_id, None, reason, None, None)
        return RunResult("ok", run_id, line, None, None, None, value)
    return None


def load_result(run_dir: Path) -> RunResult | None:
    """The saved result of a run that finished, or None."""
    path = run_dir / "result.json"
    return RunResult.from_json(read_json(path)) if path.exists() else None


def run_prepare_check(family: Family, timeout: float = 300.0) -> str | None:
    """None when ``prepare.py --check`` passes in the family directory, else its message."""
    with tempfile.TemporaryFile() as out:
        returncode, timed_out = run_in_group(
            [sys.executable, "prepare.py", "--check"],
            cwd=family.path,
            env=family_env(family),
            stdout=out,
            stderr=subprocess.STDOUT,
            timeout=timeout,
        )
        out.seek(0)
        output = out.read().decode("utf-8", errors="replace").strip()
    if timed_out:
        return f"prepare.py --check did not finish within {timeout:g} s"
    if returncode == 0:
        return None
    return f"prepare.py --check failed (exit {returncode}): {output[-STDERR_TAIL:] or 'no output'}"


def _group_members(pgid: int) -> list[tuple[int, str]]:
    """(pid, state) of the live processes in process group ``pgid`` (Linux /proc)."""
    members = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()  # after "pid (comm) ": state ppid pgrp ...
        if int(fields[2]) == pgid and fields[0] != "Z":
            members.append((int(entry.name), fields[0]))
    return members


@dataclass(frozen=True)
class Leftover:
    """What :func:`stop_orphaned_run` found of a run whose supervisor died. True when it killed any."""

    killed: int
    overdue: str | None = None  # why the run counts as timed out, when it does

    def __bool__(self) -> bool:
        return self.killed > 0


def stop_orphaned_run(run_dir: Path, wait_s: float = 10.0) -> Leftover:
    """Kill what is left of a run whose supervisor died (e.g. kill -9 of the loop or the audit).

    Its processes are those carrying the run directory in ``AUTORESEARCH_RUN``
    (autoresearch.loop.tracking), wherever they moved and whatever session they made; its watchdog
    goes first. A run still running past the deadline in process.json, or killed there by its
    watchdog, is overdue.
    A process.json without a deadline (written before runs were tracked) names a process group that
    is killed only once a member is proven to be this run's: its working directory is ``run_dir``.
    """
    run_dir = run_dir.resolve()
    info_path = run_dir / "process.json"
    info = read_json(info_path) if info_path.exists() else {}
    info = info if isinstance(info, dict) else {}
    tracking.kill_all(run_dir, tracking.WATCHDOG_ENV, wait_s)
    alive = tracking.processes(run_dir)
    overdue, deadline, timeout = None, info.get("deadline"), info.get("timeout")
    limit = f"{timeout:g} s wall-clock limit" if isinstance(timeout, (int, float)) else "wall-clock limit"
    if alive and isinstance(deadline, (int, float)) and time.time() > deadline:
        overdue = f"still running past its {limit} at resume; killed"
    elif (run_dir / tracking.WATCHDOG_FILE).exists():
        watchdog = read_json(run_dir / tracking.WATCHDOG_FILE)
        overdue = f"exceeded its {limit}: " + str(
            watchdog.get("reason") if isinstance(watchdog, dict) else ""
        )
    killed = tracking.kill_all(run_dir, tracking.RUN_ENV, wait_s) if alive else 0
    if "pid" in info and "deadline" not in info and Path("/proc").is_dir():
        killed += _stop_legacy_group(int(info["pid"]), run_dir, wait_s)
    return Leftover(killed, overdue)


def _stop_legacy_group(pgid: int, run_dir: Path, wait_s: float) -> int:
    """Kill process group ``pgid`` if a member's working directory is ``run_dir``; its size then."""
    members = _group_members(pgid)
    ours = False
    for pid, _ in members:
        try:
            ours = ours or Path(os.readlink(f"/proc/{pid}/cwd")) == run_dir
        except OSError:
            continue
    if not ours:
        return 0
    _kill_group(pgid)
    deadline = time.monotonic() + wait_s
    while _group_members(pgid) and time.monotonic() < deadline:
        time.sleep(POLL_S)
    return len(members)
