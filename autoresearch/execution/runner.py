"""Run one training run on this machine: patch a copy of train.py, execute it, parse its metric.

The family's own train.py is never written. The patched copy lives in the run's directory,
which is also the working directory of the subprocess; ``FAMILY_DIR`` tells the script where its
family's files are, and the family directory is put on ``PYTHONPATH`` so sibling modules import.
The subprocess runs without a shell in its own session (process group); a wall-clock timeout,
an interrupt of the caller, or leftover children after exit all end in ``os.killpg`` of that
group, and in the kill of every other process the run started, found by the run directory in its
``AUTORESEARCH_RUN`` wherever it moved (autoresearch.execution.tracking, which also gives each run a
watchdog that holds its deadline should the supervisor die). A run succeeds only if it exits 0
and prints exactly one valid ``FINAL_METRIC:`` line; stdout is read in bounded memory.

A run scored on the sealed test split (``RunSpec.split``: the audit, for a family that has one)
gets ``--eval-split test``: its FINAL_METRIC must then carry the search split's metrics of the same
training under ``splits`` too. A search run whose FINAL_METRIC says it saw the test split fails.

A train.py may also print ``PROGRESS: {"step": <int>, "<metric>": <number>}`` lines (family
contract, optional). They are read from the run's stdout file as they come, by the thread that
supervises the run, kept as the run's learning curve (thinned to at most ``protocol.MAX_POINTS``
points and the last), and each handed to ``on_report``; when it answers True the run is stopped
early (its process group killed) with status ``early_stopped``.
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from autoresearch import editable
from autoresearch.execution import tracking
from autoresearch.execution.processes import run_in_group
from autoresearch.execution.protocol import StdoutReader, check_final_metric, check_split, read_final_metric
from autoresearch.execution.result import RESULT_FIELDS, RESULT_FILE, RUN_STATUSES, RunResult, renamed
from autoresearch.execution.spec import NO_HOOKS, RunHooks, RunSpec
from autoresearch.family import Family
from autoresearch.journal import JournalError, read_json, read_jsonl, repair_torn_tail, write_json_atomic
from autoresearch.space import ValidationError, is_finite_number
from autoresearch.splits import Split

STDERR_TAIL = 600
# The family contract's variable: the training seconds a run is granted (docs/family-contract.md).
TIME_BUDGET_ENV = "AUTORESEARCH_TIME_BUDGET"


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


def run_env(spec: RunSpec) -> dict[str, str]:
    """The environment of the run of ``spec``: the family's, and its time budget when it has one (never
    one inherited from the caller's environment: a run without a budget trains as written)."""
    env = family_env(spec.family.path)
    env.pop(TIME_BUDGET_ENV, None)
    if spec.time_budget is not None:
        env[TIME_BUDGET_ENV] = repr(float(spec.time_budget))
    return env


def run_locally(spec: RunSpec, hooks: RunHooks = NO_HOOKS, die_with_supervisor: bool = False) -> RunResult:
    """Run ``spec`` on this machine, heard and stopped through ``hooks``; the result is also saved as
    run_dir/result.json. ``die_with_supervisor`` (a Ray task): the run is killed when this process
    dies, instead of outliving it to be adopted by a resume."""
    family, run_dir = spec.family, spec.run_dir
    if spec.split is Split.TEST and not family.has_test_split:
        raise ValueError(f"split {spec.split.value!r}: family {family.name!r} has no such split")
    run_dir.mkdir(parents=True, exist_ok=True)
    write_train_copy(family, spec.config, run_dir)
    repair_torn_tail(spec.runs_log)  # a run killed mid-append must not glue its fragment to this record
    cmd = [
        sys.executable,
        "train.py",
        "--seed",
        str(spec.seed),
        "--run-id",
        spec.run_id,
        "--runs-log",
        str(Path(spec.runs_log).resolve()),
        "--out",
        str((run_dir / "out").resolve()),
        *(["--eval-split", Split.TEST.value] if spec.split is Split.TEST else []),
    ]
    started = time.monotonic()
    reader = StdoutReader(run_dir / "stdout.txt", family.metric, hooks.on_report)
    tracked = run_dir.resolve()  # what every process of the run carries in RUN_ENV
    watchdog: subprocess.Popen | None = None

    def on_start(pid: int) -> None:
        nonlocal watchdog
        deadline, born = time.time() + spec.timeout, tracking.start_time(pid)
        info = {"pid": pid, "start_time": born, "deadline": deadline, "timeout": spec.timeout, "cmd": cmd}
        write_json_atomic(run_dir / "process.json", info)
        if born is not None:  # None: no /proc, so nothing to watch with
            supervisor = os.getpid() if die_with_supervisor else None
            watchdog = tracking.start_watchdog(tracked, pid, born, deadline, supervisor)

    try:
        with open(run_dir / "stdout.txt", "wb") as out, open(run_dir / "stderr.txt", "wb") as err:
            returncode, timed_out = run_in_group(
                cmd,
                cwd=run_dir,
                env={**run_env(spec), tracking.RUN_ENV: str(tracked)},
                stdout=out,
                stderr=err,
                timeout=spec.timeout,
                on_start=on_start,
                on_progress=hooks.on_progress,
                should_stop=reader.poll,
                cancel=hooks.cancel,
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
        last = reader.last
        reason = f"stopped early at step {last['step']} ({family.metric} {last['value']:.6g} then)"
        result = RunResult("early_stopped", spec.run_id, None, reason, wall, returncode)
    else:
        reader.finish()
        result = _result(spec, reader, returncode, wall, timed_out)
    result = replace(result, progress=reader.curve or None)
    write_json_atomic(run_dir / RESULT_FILE, result.to_json())
    return result


def _result(spec: RunSpec, reader: StdoutReader, returncode: int, wall: float, timed_out: bool) -> RunResult:
    run_id, metric = spec.run_id, spec.family.metric
    if timed_out:
        reason = f"exceeded the {spec.timeout:g} s wall-clock limit; its process group was killed"
        return RunResult("timeout", run_id, None, reason, wall, returncode)
    if returncode != 0:
        tail = _tail(spec.run_dir / "stderr.txt")
        reason = f"train.py exited with code {returncode}" + (f": {tail}" if tail else "")
        return RunResult("failed", run_id, None, reason, wall, returncode)
    final_metric, value, reason = read_final_metric(reader.finals, reader.n_finals, metric, run_id)
    if reason is None:
        reason = check_split(final_metric, metric, spec.split)
    if reason is not None:
        return RunResult("failed", run_id, None, reason, wall, returncode)
    return RunResult("ok", run_id, final_metric, None, wall, returncode, value)


def logged_run(spec: RunSpec) -> RunResult | None:
    """The outcome of the run of ``spec`` from its line in the runs log (train.py appends it as it
    ends), for a run whose supervisor died before saving its result; None without such a line. A
    line counts only with the spec's configuration and seed: a forged or foreign line is never adopted."""
    family, run_id = spec.family, spec.run_id
    for line in read_jsonl(spec.runs_log):
        if not isinstance(line, dict) or line.get("run_id") != run_id or line.get("seed") != spec.seed:
            continue
        try:
            if family.space.validate_full(line.get("config")) != spec.config:
                continue
        except ValidationError:
            continue
        value, reason = check_final_metric(line, family.metric, run_id)
        reason = reason or check_split(line, family.metric, spec.split)
        if reason is not None:
            return RunResult("failed", run_id, None, reason, None, None)
        return RunResult("ok", run_id, line, None, None, None, value)
    return None


def saved_run(spec: RunSpec) -> RunResult | None:
    """The result the runner saved for the run of ``spec`` (run_dir/result.json), for a run whose
    supervisor died after saving it; None without one. The file lies in the run's working directory,
    where train.py could have written it too, so it is read as untrusted input: only a result of this
    run in the runner's own shape, whose FINAL_METRIC object passes the checks a printed one must
    pass, counts; anything else is a lost result (None), and the run is adopted from its runs log
    line or run again, as when there is no file at all."""
    try:
        data = read_json(spec.run_dir / RESULT_FILE)
    except FileNotFoundError:
        return None
    except (JournalError, OSError, UnicodeDecodeError):
        return None
    data = renamed(data) if isinstance(data, dict) else {}
    if not set(data) <= set(RESULT_FIELDS) or data.get("run_id") != spec.run_id:
        return None
    status, final_metric = data.get("status"), data.get("final_metric")
    reason, wall, returncode = data.get("reason"), data.get("wall_seconds"), data.get("returncode")
    progress = data.get("progress")
    if (
        status not in RUN_STATUSES
        or not (reason is None or isinstance(reason, str))
        or not (wall is None or is_finite_number(wall))
        or not (returncode is None or (isinstance(returncode, int) and not isinstance(returncode, bool)))
        or not (progress is None or (isinstance(progress, list) and all(map(_is_point, progress))))
    ):
        return None
    value = None
    if status == "ok":
        value, problem = check_final_metric(final_metric, spec.family.metric, spec.run_id)
        if (
            problem
            or check_split(final_metric, spec.family.metric, spec.split)
            or data.get("metric") != value
        ):
            return None
    elif final_metric is not None or data.get("metric") is not None:
        return None
    return RunResult(status, spec.run_id, final_metric, reason, wall, returncode, value, progress)


def _is_point(point: Any) -> bool:
    """Whether ``point`` is a PROGRESS point as the runner keeps it: {"step": int, "value": finite}."""
    return (
        isinstance(point, dict)
        and set(point) == {"step", "value"}
        and isinstance(point["step"], int)
        and is_finite_number(point["step"])
        and is_finite_number(point["value"])
    )


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
