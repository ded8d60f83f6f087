"""Run one configuration of a family: patch a copy of train.py, execute it, parse its metric.

The family's own train.py is never written. The patched copy lives in the run's directory,
which is also the working directory of the subprocess; ``FAMILY_DIR`` tells the script where its
family's files are, and the family directory is put on ``PYTHONPATH`` so sibling modules import.
The subprocess runs without a shell in its own session (process group); a wall-clock timeout,
an interrupt of the caller, or leftover children after exit all end in ``os.killpg`` of that
group. A run succeeds only if it exits 0 and prints exactly one valid ``FINAL_METRIC:`` line.

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

from autoresearch.family import SEARCH, TEST, Family
from autoresearch.journal import read_json, repair_torn_tail, write_json_atomic
from autoresearch.loop import editable

FINAL_METRIC_PREFIX = "FINAL_METRIC:"
PROGRESS_PREFIX = "PROGRESS:"
KILL_GRACE_S = 2.0
POLL_S = 0.05
STDERR_TAIL = 600

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
        return None, f"FINAL_METRIC {metric!r} is not a number: {value!r}"
    if not math.isfinite(value):
        return None, f"FINAL_METRIC {metric!r} is not finite: {value!r}"
    return float(value), None


def parse_final_metric(
    stdout: str, metric: str, run_id: str
) -> tuple[dict[str, Any] | None, float | None, str | None]:
    """(record, metric value, None) from exactly one valid FINAL_METRIC line, else (.., .., reason)."""
    lines = [line for line in stdout.splitlines() if line.startswith(FINAL_METRIC_PREFIX)]
    if not lines:
        return None, None, "no FINAL_METRIC line on stdout"
    if len(lines) > 1:
        return None, None, f"{len(lines)} FINAL_METRIC lines on stdout; exactly one is required"
    try:
        record = json.loads(lines[0][len(FINAL_METRIC_PREFIX) :])
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
        data = json.loads(line[len(PROGRESS_PREFIX) :])
    except ValueError:
        return None
    if not isinstance(data, dict):
        return None
    step, value = data.get("step"), data.get(metric)
    if not isinstance(step, int) or isinstance(step, bool):
        return None
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        return None
    return {"step": step, "value": float(value)}


class ProgressReader:
    """Reads the PROGRESS lines a run appends to its stdout file, as they come.

    ``on_report(step, value)`` is asked at each new point; once it answers True, ``stop`` is set.
    """

    def __init__(self, path: Path, metric: str, on_report: Callable[[int, float], bool] | None):
        self.path, self.metric, self.on_report = path, metric, on_report
        self.offset = 0
        self.points: list[dict[str, Any]] = []
        self.stop = False

    def poll(self) -> bool:
        """Read what was appended since the last call; True when the run should stop."""
        try:
            with open(self.path, "rb") as f:
                f.seek(self.offset)
                chunk = f.read()
        except FileNotFoundError:
            return False
        complete = chunk[: chunk.rfind(b"\n") + 1]  # a line still being written waits for the next poll
        self.offset += len(complete)
        for raw in complete.splitlines():
            point = parse_progress(raw.decode("utf-8", errors="replace"), self.metric)
            if point is None or self.stop:
                continue
            self.points.append(point)
            if self.on_report is not None and self.on_report(point["step"], point["value"]):
                self.stop = True
        return self.stop


def _tail(path: Path) -> str:
    text = path.read_text(encoding="utf-8", errors="replace").strip() if path.exists() else ""
    return text if len(text) <= STDERR_TAIL else "..." + text[-STDERR_TAIL:]


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
    reader = ProgressReader(run_dir / "stdout.txt", family.metric, on_report)
    with open(run_dir / "stdout.txt", "wb") as out, open(run_dir / "stderr.txt", "wb") as err:
        returncode, timed_out = run_in_group(
            cmd,
            cwd=run_dir,
            env=family_env(family),
            stdout=out,
            stderr=err,
            timeout=timeout,
            on_start=lambda pid: write_json_atomic(run_dir / "process.json", {"pid": pid, "cmd": cmd}),
            on_progress=on_progress,
            should_stop=reader.poll,
            cancel=cancel,
        )
    wall = time.monotonic() - started
    if reader.stop:
        last = reader.points[-1]
        reason = f"stopped early at step {last['step']} ({family.metric} {last['value']:.6g} then)"
        result = RunResult("early_stopped", run_id, None, reason, wall, returncode)
    else:
        reader.on_report = None  # the run is over: the last lines are kept, not judged
        reader.poll()
        result = _result(family, run_id, run_dir, returncode, wall, timed_out, timeout, eval_split)
    result = replace(result, progress=reader.points or None)
    write_json_atomic(run_dir / "result.json", result.to_json())
    return result


def _result(
    family: Family,
    run_id: str,
    run_dir: Path,
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
    stdout = (run_dir / "stdout.txt").read_text(encoding="utf-8", errors="replace")
    record, value, reason = parse_final_metric(stdout, family.metric, run_id)
    if reason is None:
        reason = check_split(record, family.metric, eval_split)
    if reason is not None:
        return RunResult("failed", run_id, None, reason, wall, returncode)
    return RunResult("ok", run_id, record, None, wall, returncode, value)


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


def stop_orphaned_run(run_dir: Path, wait_s: float = 10.0) -> bool:
    """Kill what is left of a run whose supervisor died (e.g. kill -9 of the loop); True if any was.

    The process group is killed only once a member is proven to be this run's (its working
    directory is ``run_dir``), so a recycled pid can never take an unrelated process down.
    """
    info_path = run_dir / "process.json"
    if not info_path.exists() or not Path("/proc").is_dir():
        return False
    pgid = int(read_json(info_path)["pid"])
    ours = False
    for pid, _ in _group_members(pgid):
        try:
            ours = ours or Path(os.readlink(f"/proc/{pid}/cwd")) == run_dir.resolve()
        except OSError:
            continue
    if not ours:
        return False
    _kill_group(pgid)
    deadline = time.monotonic() + wait_s
    while _group_members(pgid) and time.monotonic() < deadline:
        time.sleep(POLL_S)
    return True
