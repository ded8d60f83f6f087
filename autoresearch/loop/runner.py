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
the same run under ``splits``. A search run whose record says it saw the test split fails.

A train.py may also print ``PROGRESS: {"step": <int>, "<metric>": <number>}`` lines (family
contract, optional). They are read from the run's stdout file as they come, by the thread that
supervises the run, kept as the run's learning curve, and handed to ``on_report``; when it answers
True the run is stopped early (its process group killed) with status ``early_stopped``.
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Literal

from autoresearch import editable
from autoresearch.family import SEARCH, TEST, Family
from autoresearch.journal import read_json, read_jsonl, repair_torn_tail, write_json_atomic
from autoresearch.loop import tracking
from autoresearch.loop.processes import run_in_group
from autoresearch.loop.protocol import StdoutReader, check_record, check_split, final_metric
from autoresearch.space import ValidationError

STDERR_TAIL = 600

RunStatus = Literal["ok", "failed", "timeout", "early_stopped"]


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


def family_env(family_dir: Path) -> dict[str, str]:
    """The environment of every family subprocess (train.py, prepare.py)."""
    env = dict(os.environ)
    env["FAMILY_DIR"] = str(family_dir)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(family_dir), env.get("PYTHONPATH")) if p)
    env["PYTHONDONTWRITEBYTECODE"] = "1"  # imports must not leave __pycache__ in the family dir
    env["PYTHONUNBUFFERED"] = "1"
    return env


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
    die_with_supervisor: bool = False,
) -> RunResult:
    """Train ``config`` at ``seed`` in ``run_dir``; the result is also saved as run_dir/result.json.

    ``on_report(step, value)`` hears each PROGRESS point; True stops the run early. Setting
    ``cancel`` (another thread) kills the run and raises KeyboardInterrupt, leaving no result.
    ``eval_split="test"`` scores the run on the family's sealed test split (the audit only).
    ``die_with_supervisor`` (a Ray task): the run is killed when this process dies, instead of
    outliving it to be adopted by a resume.
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
            supervisor = os.getpid() if die_with_supervisor else None
            watchdog = tracking.start_watchdog(tracked, pid, born, deadline, supervisor)

    try:
        with open(run_dir / "stdout.txt", "wb") as out, open(run_dir / "stderr.txt", "wb") as err:
            returncode, timed_out = run_in_group(
                cmd,
                cwd=run_dir,
                env={**family_env(family.path), tracking.RUN_ENV: str(tracked)},
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


def run_prepare_check(family_dir: Path, timeout: float = 300.0) -> str | None:
    """None when ``prepare.py --check`` passes in the family directory, else its message."""
    with tempfile.TemporaryFile() as out:
        returncode, timed_out = run_in_group(
            [sys.executable, "prepare.py", "--check"],
            cwd=family_dir,
            env=family_env(family_dir),
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
