"""Which processes belong to a run, found whatever the run does with its working directory or its
session, and killed without ever touching an unrelated process (Linux /proc).

The runner starts train.py with ``AUTORESEARCH_RUN=<absolute run dir>`` in its environment. Every
process of the run inherits that entry however it chdirs, forks or calls setsid, and
/proc/<pid>/environ shows it for the process's lifetime; a recycled pid shows its own, new
environment. So the run's processes are the live ones whose environment carries the entry. A kill
pins the process with a pidfd before checking it, so the pid cannot be recycled in between. A
process that builds itself a fresh environment (``env={}``) is not found.

The watchdog is this file run as a script (standard library only, so it starts in milliseconds and
needs no import path). The runner starts one per run, in a session of its own, so it outlives a
kill -9 of the loop or the audit. It waits for the run's first process (train.py) to end and then
kills what the run left behind; at the run's deadline plus a grace it kills every process of the
run and writes ``watchdog.json`` into the run directory, which a resume reads as a timeout. While
its supervisor lives, the supervisor handles both and kills the watchdog when the run ends.

A run started by a Ray task also names its supervisor (the task's worker process): the watchdog
then kills the run as soon as the supervisor dies, so that no train.py outlives its task (a Ray
worker dies with its job, e.g. on kill -9 of the loop; the resumed loop re-runs the run).
"""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

RUN_ENV = "AUTORESEARCH_RUN"  # on every process of a run: the run directory
WATCHDOG_ENV = "AUTORESEARCH_RUN_WATCHDOG"  # on the run's watchdog
WATCHDOG_FILE = "watchdog.json"
# The watchdog acts this long after the deadline: by then a live supervisor has already stopped the
# run itself (SIGTERM, a 2 s grace, SIGKILL), so the two never both decide.
WATCHDOG_GRACE_S = 5.0
POLL_S = 0.05


def _entry(var: str, run_dir: Path) -> bytes:
    """The entry as /proc/<pid>/environ holds it: NUL-terminated, in the file system's encoding."""
    return var.encode() + b"=" + os.fsencode(run_dir) + b"\0"


def _carries(pid: int, entry: bytes) -> bool:
    try:
        with open(f"/proc/{pid}/environ", "rb") as f:
            environ = f.read()
    except OSError:  # gone, or another user's
        return False
    return environ.startswith(entry) or b"\0" + entry in environ


def processes(run_dir: Path, var: str = RUN_ENV) -> list[int]:
    """The live processes whose environment has ``var=<run_dir>`` (run_dir as the runner gave it)."""
    entry, me = _entry(var, run_dir), os.getpid()
    try:
        pids = [int(name) for name in os.listdir("/proc") if name.isdigit()]
    except OSError:  # no /proc: nothing can be found
        return []
    return [pid for pid in pids if pid != me and _carries(pid, entry)]


def _stat(pid: int) -> tuple[bytes, int] | None:
    """(state, start time in clock ticks since boot) of ``pid`` from /proc/<pid>/stat, or None."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            stat = f.read()
    except OSError:
        return None
    fields = stat[stat.rindex(b")") + 2 :].split()  # after "pid (comm) ": field 3 (state) on
    return fields[0], int(fields[19])  # fields 3 and 22


def start_time(pid: int) -> int | None:
    """The start time of ``pid`` in clock ticks since boot (/proc/<pid>/stat field 22), or None."""
    stat = _stat(pid)
    return None if stat is None else stat[1]


def _running(pid: int, started: int | None) -> bool:
    """Whether the process that started at ``started`` still runs: an exited one left unreaped (its
    parent died, and init may never reap it) is a zombie."""
    stat = _stat(pid)
    return stat is not None and stat[1] == started and stat[0] not in (b"Z", b"X")


def _pidfd(pid: int) -> int | None:
    try:
        return os.pidfd_open(pid)
    except (AttributeError, OSError):  # gone, or no pidfd (Linux < 5.3): the caller checks and kills
        return None


def _kill_checked(pid: int, entry: bytes) -> bool:
    """SIGKILL ``pid`` if its environment carries ``entry``; True when it was sent."""
    fd = _pidfd(pid)
    try:
        if not _carries(pid, entry):  # checked once the pidfd pins the process: never a recycled pid
            return False
        if fd is not None:
            signal.pidfd_send_signal(fd, signal.SIGKILL)
        else:
            os.kill(pid, signal.SIGKILL)
        return True
    except (ProcessLookupError, PermissionError):
        return False
    finally:
        if fd is not None:
            os.close(fd)


def kill_all(run_dir: Path, var: str = RUN_ENV, wait_s: float = 10.0) -> int:
    """SIGKILL every process of the run (``var``: its watchdog instead) until none is left, waiting
    up to ``wait_s`` for them to die; how many were killed."""
    entry, killed = _entry(var, run_dir), set()
    deadline = time.monotonic() + wait_s
    while True:
        alive = processes(run_dir, var)
        for pid in alive:  # a process may fork while we kill: scan again until none is left
            if pid not in killed and _kill_checked(pid, entry):
                killed.add(pid)
        if not alive or time.monotonic() > deadline:
            return len(killed)
        time.sleep(POLL_S)


def start_watchdog(
    run_dir: Path, pid: int, started: int | None, deadline: float, supervisor: int | None = None
) -> subprocess.Popen:
    """The watchdog of the run in ``run_dir`` whose first process is ``pid`` (started at ``started``
    ticks), due to end by ``deadline`` (time.time() seconds); with ``supervisor`` (a pid), the run
    dies with that process too."""
    watched = [str(supervisor), str(start_time(supervisor))] if supervisor is not None else []
    return subprocess.Popen(
        [
            sys.executable,
            "-I",
            "-S",
            __file__,
            str(run_dir),
            str(pid),
            str(started),
            repr(deadline),
            *watched,
        ],
        cwd="/",
        env={WATCHDOG_ENV: str(run_dir)},
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


def _wait_exit(watched: list[tuple[int, int | None]], deadline: float) -> bool:
    """Wait until ``deadline`` (time.time()) for any of ``watched`` (pid, start time) to end; True if
    one did."""
    fds = [fd for fd in (_pidfd(pid) for pid, _ in watched) if fd is not None]
    try:
        while all(_running(pid, started) for pid, started in watched):
            left = min(deadline - time.time(), 3600.0)  # in steps: select refuses an endless timeout
            if left <= 0:
                return False
            if len(fds) == len(watched):
                select.select(fds, [], [], left)  # a pidfd is readable once its process exits
            else:  # no pidfd: poll
                time.sleep(min(left, 0.5))
        return True
    finally:
        for fd in fds:
            os.close(fd)


def watch(
    run_dir: Path, pid: int, started: int | None, deadline: float, supervisor: tuple[int, int | None] | None
) -> None:
    """The watchdog: when ``pid`` (or the ``supervisor``) ends, kill what is left of the run; at
    deadline + grace, kill the run and say so in watchdog.json (read by a resume as a timeout)."""
    if _wait_exit([(pid, started), *([supervisor] if supervisor else [])], deadline + WATCHDOG_GRACE_S):
        kill_all(run_dir)
        return
    killed = kill_all(run_dir)
    record = {
        "time": time.time(),
        "killed": killed,
        "reason": f"still running {WATCHDOG_GRACE_S:g} s after its deadline, with no supervisor; "
        "its watchdog killed it",
    }
    tmp = run_dir / f".{WATCHDOG_FILE}.tmp"
    try:
        tmp.write_text(json.dumps(record) + "\n", encoding="utf-8")
        os.replace(tmp, run_dir / WATCHDOG_FILE)
    except OSError:  # the run directory is gone: nobody will ask
        pass


def _ticks(text: str) -> int | None:
    return None if text == "None" else int(text)


if __name__ == "__main__":
    _dir, _pid, _started, _deadline, *_supervisor = sys.argv[1:]
    _watched = (int(_supervisor[0]), _ticks(_supervisor[1])) if _supervisor else None
    watch(Path(_dir), int(_pid), _ticks(_started), float(_deadline), _watched)
