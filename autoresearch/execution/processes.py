"""A training run as a process group: started without a shell in its own session, stopped as a
whole (on timeout, on an interrupt of the caller, after exit), and, after a supervisor died, found
again and killed without touching an unrelated process (autoresearch.execution.tracking)."""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from autoresearch.execution import tracking
from autoresearch.journal import read_json

KILL_GRACE_S = 2.0
POLL_S = 0.05

# Set by a signal while interruptible_runs() is active: every run in flight, in any thread, stops.
_INTERRUPTED = threading.Event()


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
    (autoresearch.execution.tracking), wherever they moved and whatever session they made; its watchdog
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
