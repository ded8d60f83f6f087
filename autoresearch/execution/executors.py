"""One interface for running training runs and the tasks that start them: serially, on a local
pool, or on Ray (autoresearch.execution.ray_executor, imported only when chosen).

Every run goes through :meth:`Executor.run`, given its :class:`RunSpec`: here, a subprocess of this
machine; on Ray, a remote task whose files come back to this process. The loop hands each of its
experiments to it; the audit and a group of repeats hand it tasks through :meth:`Executor.map`.
Every audit task is one training run, i.e. one subprocess, so the local pool is a thread pool
driving subprocesses: no pickling, no fork of the parent, and results come back in the parent,
where the caller logs them (through the journal's file lock, so appends never interleave). Results
are returned in task order, so for the same seeds they are identical to a serial run's.
"""

from __future__ import annotations

import signal
import threading
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from contextlib import contextmanager
from typing import Any, TypeVar

from autoresearch.execution.result import RunResult
from autoresearch.execution.runner import run_locally
from autoresearch.execution.spec import NO_HOOKS, RunHooks, RunSpec

# A Ray task's cancellation is checked this often; a cancelled task has this long to kill its run
# (the runner's SIGTERM grace, and then some) before its worker is killed.
CANCEL_POLL_S = 0.2
CANCEL_GRACE_S = 10.0
T = TypeVar("T")
R = TypeVar("R")
OnResult = Callable[[int, Any], None]


class ExecutorError(RuntimeError):
    """An executor cannot run what it was given (a family Ray cannot ship); the message says why."""


class Executor(ABC):
    """Runs training runs (:meth:`run`), and ``fn`` over tasks, ``workers`` at a time on threads of
    this process (:meth:`map`, serial with one worker); ``on_result(index, result)`` fires in the
    caller as each task finishes."""

    name = "executor"

    def __init__(self, workers: int = 1):
        if workers < 1:
            raise ValueError(f"--workers must be >= 1 (got {workers})")
        self.workers = workers

    @abstractmethod
    def run(self, spec: RunSpec, hooks: RunHooks = NO_HOOKS) -> RunResult:
        """One training run, supervised from the calling thread (autoresearch.execution.runner's
        contract: ``hooks.cancel`` kills it and raises KeyboardInterrupt)."""

    def map(self, fn: Callable[[T], R], tasks: Sequence[T], on_result: OnResult | None = None) -> list[R]:
        results: list[Any] = [None] * len(tasks)
        pool = ThreadPoolExecutor(max_workers=self.workers) if self.workers > 1 else None
        try:
            if pool is None:
                for i, task in enumerate(tasks):
                    results[i] = fn(task)
                    if on_result:
                        on_result(i, results[i])
            else:
                futures = {pool.submit(fn, task): i for i, task in enumerate(tasks)}
                for future in as_completed(futures):
                    i = futures[future]
                    results[i] = future.result()
                    if on_result:
                        on_result(i, results[i])
        except BaseException:  # an error, Ctrl-C or SIGTERM: the runs in flight stop before the join
            self.abort()
            raise
        finally:
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)
        return results

    def abort(self) -> None:  # noqa: B027  (nothing to do where each run's supervisor stops it)
        """Stop the runs in flight of the tasks' threads, so that joining them does not wait for
        their training: a local run is stopped by its own supervisor (runner.run_locally)."""

    def close(self) -> None:  # noqa: B027  (a no-op unless the executor started something)
        """Release what the executor started."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LocalExecutor(Executor):
    """Each run a subprocess of this machine."""

    name = "local"

    def run(self, spec: RunSpec, hooks: RunHooks = NO_HOOKS) -> RunResult:
        return run_locally(spec, hooks)


@contextmanager
def keeping_signal_handlers() -> Iterator[None]:
    """Restore the SIGINT/SIGTERM handlers after the block: ray.init installs its own SIGTERM handler
    (exit status 15), which would replace ours (processes.interruptible_runs: stop the runs, exit 130)."""
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        if threading.current_thread() is threading.main_thread():
            for sig, handler in saved.items():
                if handler is not None:
                    signal.signal(sig, handler)
