"""Runs on Ray: each training run is one Ray task; the driver (the loop or the audit) alone writes
the campaign.

- **The family travels with the task.** With ``files="ship"`` (the default) the family directory's
  files go to the object store (once per version) and each task writes them into its own private
  scratch directory (0700, removed when it ends), where the run happens too: no copy is shared
  between tasks or users, so none can be planted or half-deleted between runs. Links are followed,
  as a local run follows them (a dangling one is absent, as it is locally); a file that is not a
  regular file (a FIFO, a socket, a device) is refused in one line, and sizes are summed before
  anything is read. The run's files (the patched train.py, the stdout and stderr tails, the policy
  under ``out/``) stream back to the driver in chunks as the task's generator yields them (all-zero
  chunks as holes, so a sparse file stays sparse), then its runs.jsonl lines and its result, for the
  driver to write; a last runs.jsonl line without its newline goes to ``runs.jsonl.torn``, as a local
  run's next start would move it. No node needs the family's or the campaign's path.
  ``files="shared"`` has the task read the family and write the run where the driver would, for
  clusters whose nodes share one filesystem.
- **PROGRESS streams back while the run trains**, through one actor per executor: each point goes
  to the driver, whose early-stop pruner answers before train.py's next point is read, exactly as
  for a local run. The driver's wait loop feeds the live view.
- **Nothing outlives its task.** A run started by a task dies with the task's worker (its watchdog
  watches the worker: autoresearch.execution.tracking), and a cancelled task kills its run's process
  group (a KeyboardInterrupt in the task). A worker dies with its job, so kill -9 of the driver ends
  every run; ``--resume`` then re-runs them.
- **Many tasks** (``map``, the local executor's) run on driver threads, ``workers`` at a time: each
  is a function that may start runs through :meth:`RayExecutor.run`, so the audit's
  bookkeeping (what ran already, its logs) stays on the driver too; an interrupt cancels every
  run in flight before the threads are joined.
"""

from __future__ import annotations

import asyncio
import hashlib
import os
import shutil
import stat
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

from autoresearch.execution.executors import (
    CANCEL_GRACE_S,
    CANCEL_POLL_S,
    Executor,
    ExecutorError,
    keeping_signal_handlers,
)
from autoresearch.execution.result import RESULT_FILE, RunResult
from autoresearch.execution.runner import run_locally
from autoresearch.execution.spec import NO_HOOKS, RunHooks, RunSpec
from autoresearch.extras import require
from autoresearch.family import Family, own_file
from autoresearch.journal import append_line, keep_torn, write_json_atomic

FILE_MODES = ("ship", "shared")
# What of a family directory is not shipped: what its own runs leave there.
_NOT_SHIPPED_DIRS = {"__pycache__", "out"}
MAX_SHIPPED_BYTES = 64 * 2**20  # a family above this belongs on a shared filesystem (files="shared")
TAIL_BYTES = 256 * 2**10  # of stdout.txt and stderr.txt, brought back from the worker
CHUNK_BYTES = 4 * 2**20  # a run's files come back in pieces of this size: the driver holds one at a time
# Run files not sent back: about the worker's processes (nothing to adopt), and the result, which
# travels as the task's last item and is written last.
NOT_SENT_BACK = ("process.json", "watchdog.json", RESULT_FILE)
REMOTE_FILE = "remote.json"  # in the driver's run directory: the node, worker and directory of the run
DECISION_TIMEOUT_S = 120.0  # a worker waits this long for the driver's early-stop answer, then trains on


def family_files(family: Family) -> dict[str, bytes]:
    """The family directory's files (relative path -> bytes), without what runs leave there: links
    followed, sizes summed before anything is read, anything but a regular file refused (ExecutorError)."""
    found = list(_family_entries(family.path))
    size = sum(st_size for _, _, st_size in found)
    if size > MAX_SHIPPED_BYTES:
        raise ExecutorError(
            f"{family.path}: {size / 2**20:.0f} MB of files to send to every Ray worker; put the family on a "
            "filesystem every node sees and use --ray-files shared"
        )
    files = {}
    for rel, path, st_size in found:
        with open(path, "rb") as f:
            files[rel] = f.read(st_size)  # what was summed: a file growing meanwhile is not read past it
    return files


def _family_entries(root: Path) -> Iterator[tuple[str, Path, int]]:
    """(relative path, path, size) of each file to ship, links followed (a directory reached twice, as
    through a link cycle, is walked once); a dangling link is skipped, being absent for a local run too."""
    seen: set[str] = set()
    for dirpath, dirnames, filenames in os.walk(root, followlinks=True):
        real = os.path.realpath(dirpath)
        if real in seen:
            dirnames[:] = []
            continue
        seen.add(real)
        dirnames[:] = sorted(d for d in dirnames if d not in _NOT_SHIPPED_DIRS and not d.startswith("."))
        for name in sorted(filter(own_file, filenames)):
            path = Path(dirpath, name)
            try:
                mode = path.stat()  # follows a link
            except FileNotFoundError:
                continue
            if not stat.S_ISREG(mode.st_mode):
                raise ExecutorError(
                    f"{path}: not a regular file ({_kind(mode.st_mode)}), so it cannot be sent to Ray workers; "
                    "move it out of the family directory or use --ray-files shared"
                )
            yield path.relative_to(root).as_posix(), path, mode.st_size


def _kind(mode: int) -> str:
    kinds = {stat.S_ISFIFO: "a FIFO", stat.S_ISSOCK: "a socket", stat.S_ISCHR: "a character device"}
    return next((kind for test, kind in kinds.items() if test(mode)), "a device or special file")


def _digest(files: dict[str, bytes]) -> str:
    h = hashlib.sha256()
    for name in sorted(files):
        h.update(name.encode() + b"\0" + hashlib.sha256(files[name]).digest())
    return h.hexdigest()[:16]


def _materialize(files: dict[str, bytes], scratch: Path, name: str) -> Path:
    """The family written into the task's own scratch directory (its copy, for this run alone)."""
    target = scratch / "family" / name
    for rel, data in files.items():
        (target / rel).parent.mkdir(parents=True, exist_ok=True)
        (target / rel).write_bytes(data)
    return target


def _tail(path: Path) -> bytes:
    """The last TAIL_BYTES of a file, read from its end (a run may print gigabytes)."""
    with open(path, "rb") as f:
        size = f.seek(0, os.SEEK_END)
        if size <= TAIL_BYTES:
            f.seek(0)
            return f.read()
        f.seek(size - TAIL_BYTES)
        return b"...(truncated)\n" + f.read()


def _stream_back(run_dir: Path) -> Iterator[dict[str, Any]]:
    """The run's files for the driver, one chunk at a time: the stdout and stderr tails, the rest
    whole; an all-zero chunk is not sent (a hole), and each file's first chunk carries its size."""
    for path in sorted(p for p in run_dir.rglob("*") if p.is_file() and not p.is_symlink()):
        rel = path.relative_to(run_dir).as_posix()
        if rel in NOT_SENT_BACK:
            continue
        if rel in ("stdout.txt", "stderr.txt"):
            data = _tail(path)
            yield {"file": rel, "size": len(data), "offset": 0, "data": data}
            continue
        with open(path, "rb") as f:
            size = f.seek(0, os.SEEK_END)
            f.seek(0)
            yield {"file": rel, "size": size, "offset": 0, "data": b""}  # the file, even when all holes
            offset = 0
            while chunk := f.read(CHUNK_BYTES):
                if chunk.count(0) != len(chunk):
                    yield {"file": rel, "offset": offset, "data": chunk}
                offset += len(chunk)


def remote_run(
    spec: RunSpec, shipped: dict[str, bytes] | None, decide: bool, channel: Any
) -> Iterator[dict[str, Any]]:
    """One run, on a Ray worker (module-level, so Ray pickles it by reference); a generator, whose
    items stream back to the driver: the run's files (when the family was shipped), then its outcome.
    ``shipped`` is the family's files (an argument of its own, so that Ray resolves their object
    reference) when they travel with the task; ``decide``: the driver's early-stop pruner answers
    each PROGRESS point."""
    import ray  # on the worker: ray is there, since it runs this

    run_id = spec.run_id
    scratch = None
    if shipped is not None:
        scratch = Path(tempfile.mkdtemp(prefix=f"autoresearch-{run_id}-"))  # 0700: this task's alone
        family = Family.load(_materialize(shipped, scratch, spec.family.path.name))
        spec = replace(spec, family=family, run_dir=scratch / "run", runs_log=scratch / "runs.jsonl")

    where = {"node": ray.util.get_node_ip_address(), "worker_pid": os.getpid(), "run_dir": str(spec.run_dir)}
    channel.started.remote(run_id, where)

    def on_report(step: int, value: float) -> bool:  # the driver's early-stop pruner decides
        return bool(ray.get(channel.report.remote(run_id, step, value)))

    try:
        # no pruner: nothing to stream
        result = run_locally(
            spec, RunHooks(on_report=on_report if decide else None), die_with_supervisor=True
        )
        if scratch is None:
            yield {"result": result.to_json()}
            return
        yield from _stream_back(spec.run_dir)
        runs_log = spec.runs_log
        lines = runs_log.read_bytes().splitlines(keepends=True) if runs_log.exists() else []
        yield {"result": result.to_json(), "log_lines": lines}
    finally:
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)


def _append_lines(runs_log: Path, lines: list[bytes]) -> None:
    """A shipped run's runs.jsonl lines appended to the driver's; a last one without its newline
    moved aside as torn, as a local run's next start moves it (autoresearch.journal)."""
    for line in lines:
        if line.endswith(b"\n"):
            append_line(runs_log, line)
        else:
            keep_torn(runs_log, line)


class _Channel:
    """The actor between the tasks and the driver: PROGRESS points go up, early-stop answers down."""

    def __init__(self) -> None:
        self.points: dict[str, list[tuple[int, float]]] = {}
        self.where: dict[str, dict[str, Any]] = {}
        self.answers: dict[tuple[str, int], asyncio.Future] = {}

    async def started(self, run_id: str, where: dict[str, Any]) -> None:
        self.where[run_id] = where

    async def report(self, run_id: str, step: int, value: float) -> bool:
        self.points.setdefault(run_id, []).append((step, value))
        answer = asyncio.get_running_loop().create_future()
        self.answers[(run_id, step)] = answer
        try:
            return await asyncio.wait_for(answer, DECISION_TIMEOUT_S)
        except asyncio.TimeoutError:  # the driver is gone or stuck: train on
            return False
        finally:
            self.answers.pop((run_id, step), None)

    async def take(self, run_id: str) -> tuple[dict[str, Any] | None, list[tuple[int, float]]]:
        """Where the run started (once), and its PROGRESS points since the last call."""
        return self.where.pop(run_id, None), self.points.pop(run_id, [])

    async def answer(self, run_id: str, step: int, stop: bool) -> None:
        future = self.answers.get((run_id, step))
        if future is not None and not future.done():
            future.set_result(stop)


class RayExecutor(Executor):
    """Training runs as Ray tasks (module docstring).

    address: an existing cluster ("auto", "host:port" or "ray://host:port"); None connects to the
    cluster in ``RAY_ADDRESS`` if set, else starts a local instance with ``workers * cpus_per_task``
    CPUs. gpus_per_task None: one GPU per task when the cluster has GPUs, none otherwise.
    """

    name = "ray"

    def __init__(
        self,
        address: str | None = None,
        workers: int = 1,
        cpus_per_task: float = 1,
        gpus_per_task: float | None = None,
        files: str = "ship",
    ):
        ray = require("ray", "ray", "--executor ray")
        super().__init__(workers)
        if files not in FILE_MODES:
            raise ValueError(f"--ray-files must be one of {', '.join(FILE_MODES)} (got {files!r})")
        self._ray = ray
        self.files = files
        self._started = False
        address = address or os.environ.get("RAY_ADDRESS") or None
        if not ray.is_initialized():
            with keeping_signal_handlers():
                if address:
                    ray.init(address=address, log_to_driver=False)
                else:  # "local": a new instance, never one a `ray start` on this machine left behind
                    ray.init(
                        address="local",
                        num_cpus=workers * cpus_per_task,
                        include_dashboard=False,
                        log_to_driver=False,
                    )
            self._started = True
        if gpus_per_task is None:
            gpus_per_task = 1 if ray.cluster_resources().get("GPU", 0) > 0 else 0
        self.options = {"num_cpus": cpus_per_task, "num_gpus": gpus_per_task}
        # No automatic retry: a run whose worker died is re-run by a resume, once, under a new run id.
        self._remote = ray.remote(max_retries=0, **self.options)(remote_run)
        self._channel = ray.remote(num_cpus=0)(_Channel).remote()
        self._shipped: dict[str, Any] = {}  # digest -> object ref of the family's files
        self._lock = threading.Lock()
        self._in_flight: set[Any] = set()
        self._aborting = threading.Event()

    @property
    def address(self) -> str:
        """The cluster's address, for processes that should run their tasks on it too."""
        return self._ray.get_runtime_context().gcs_address

    def abort(self) -> None:
        """Cancel every run in flight; the threads waiting on them raise KeyboardInterrupt."""
        self._aborting.set()
        with self._lock:
            refs = list(self._in_flight)
        self._cancel(refs)

    def _cancel(self, refs: list[Any]) -> None:
        """Cancel ``refs``: a KeyboardInterrupt in each task (the runner then kills its training
        process group), then the worker killed if it lingers (the run's watchdog ends the run)."""
        ray = self._ray
        for ref in refs:
            ray.cancel(ref)
        lingering = ray.wait(refs, num_returns=len(refs), timeout=CANCEL_GRACE_S)[1] if refs else []
        for ref in lingering:
            ray.cancel(ref, force=True)

    def _ship(self, family: Family) -> Any:
        files = family_files(family)
        digest = _digest(files)
        with self._lock:
            if digest not in self._shipped:
                self._shipped[digest] = self._ray.put(files)
            return self._shipped[digest]

    def run(self, spec: RunSpec, hooks: RunHooks = NO_HOOKS) -> RunResult:
        """One run as a Ray task, supervised from this thread; the same contract as
        :func:`autoresearch.execution.runner.run_locally`."""
        on_report, on_progress, cancel = hooks.on_report, hooks.on_progress, hooks.cancel
        ray, run_id, run_dir = self._ray, spec.run_id, spec.run_dir
        if self.files == "ship":
            shipped, task_spec = self._ship(spec.family), spec
        else:  # the task reads and writes where the driver would
            shipped = None
            task_spec = replace(spec, run_dir=run_dir.resolve(), runs_log=spec.runs_log.resolve())
        run_dir.mkdir(parents=True, exist_ok=True)
        ref = self._remote.remote(task_spec, shipped, on_report is not None, self._channel)
        with self._lock:
            self._in_flight.add(ref)
        started = time.monotonic()
        try:
            while True:
                done, _ = ray.wait([ref], timeout=CANCEL_POLL_S)  # the first item: the run has ended
                where, points = ray.get(self._channel.take.remote(run_id))
                if where is not None:  # where the run trains, for whoever looks at the run directory
                    write_json_atomic(run_dir / REMOTE_FILE, {**where, "files": self.files})
                for step, value in points:  # only a run with a pruner sends them
                    self._channel.answer.remote(run_id, step, bool(on_report(step, value)))
                if on_progress is not None:
                    on_progress(time.monotonic() - started)
                if done:
                    break
                if (cancel is not None and cancel.is_set()) or self._aborting.is_set():
                    self._cancel([ref])
                    raise KeyboardInterrupt
            try:
                outcome = self._receive(ref, run_dir)
            except ray.exceptions.TaskCancelledError:
                raise KeyboardInterrupt from None
            except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError) as err:
                # The run died with its worker (its watchdog saw to that): a failed run, as a local
                # run killed from outside is; its files stayed on the worker.
                reason = f"its Ray worker died ({type(err).__name__}); the run was killed with it"
                result = RunResult("failed", run_id, None, reason, time.monotonic() - started, None)
                write_json_atomic(run_dir / RESULT_FILE, result.to_json())
                return result
        finally:
            with self._lock:
                self._in_flight.discard(ref)
        if "log_lines" in outcome:  # a shipped run: its log lines and result are the driver's to write
            _append_lines(spec.runs_log, outcome["log_lines"])
            write_json_atomic(run_dir / RESULT_FILE, outcome["result"])  # last: a resume reads it as finished
        return RunResult.from_json(outcome["result"])

    def _receive(self, items: Any, run_dir: Path) -> dict[str, Any]:
        """The task's items as they come: each chunk of a shipped run's files written where a local run
        leaves it (one chunk in memory at a time), until the last item, the outcome, returned."""
        name, out = None, None
        try:
            for ref in items:
                item = self._ray.get(ref)
                if "file" not in item:
                    return item
                if item["file"] != name:
                    if out is not None:
                        out.close()
                    name = item["file"]
                    (run_dir / name).parent.mkdir(parents=True, exist_ok=True)
                    out = open(run_dir / name, "wb")  # open across the chunks of one file
                    out.truncate(item["size"])  # holes stay holes
                out.seek(item["offset"])
                out.write(item["data"])
        finally:
            if out is not None:
                out.close()
        raise RuntimeError(f"the Ray task of {run_dir.name} ended without its result")

    def close(self) -> None:
        if self._started:
            with keeping_signal_handlers():
                self._ray.shutdown()
            self._started = False
