"""One interface for running training runs and the tasks that start them: serially, on a local
pool, or on Ray (autoresearch.ray_executor, imported only when chosen).

Every audit task is one training run, i.e. one subprocess, so the local pool is a thread pool
driving subprocesses: no pickling, no fork of the parent, and results come back in the parent,
where the caller logs them (through the journal's file lock, so appends never interleave). A task
starts its run through :meth:`Executor.run_experiment`: here, a subprocess of this machine; on Ray,
a remote task whose files come back to this process. Results are returned in task order, so for
the same seeds they are identical to a serial run's.
"""

from __future__ import annotations

import argparse
import signal
import threading
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from contextlib import contextmanager
from typing import Any, TypeVar

from autoresearch.loop.runner import RunResult, run_experiment

# A Ray task's cancellation is checked this often; a cancelled task has this long to kill its run
# (the runner's SIGTERM grace, and then some) before its worker is killed.
CANCEL_POLL_S = 0.2
CANCEL_GRACE_S = 10.0
T = TypeVar("T")
R = TypeVar("R")
OnResult = Callable[[int, Any], None]


class Executor(ABC):
    """Runs ``fn`` over tasks; ``on_result(index, result)`` fires in the caller as each finishes.

    ``cancel``, set by another thread, stops the tasks in flight and raises KeyboardInterrupt. Local
    tasks run in this process and take such an event themselves (runner.run_experiment); Ray's run
    elsewhere, so the Ray executor cancels them.
    """

    name = "executor"
    workers = 1

    @abstractmethod
    def map(
        self,
        fn: Callable[[T], R],
        tasks: Sequence[T],
        on_result: OnResult | None = None,
        cancel: threading.Event | None = None,
    ) -> list[R]: ...

    def run_experiment(self, *args: Any, **kwargs: Any) -> RunResult:
        """One training run (autoresearch.loop.runner.run_experiment's arguments and result), on
        this machine; the Ray executor runs it as a task."""
        return run_experiment(*args, **kwargs)

    def close(self) -> None:  # noqa: B027  (a no-op unless the executor started something)
        """Release what the executor started."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LocalExecutor(Executor):
    """``workers`` tasks at a time on threads; ``workers=1`` is plain serial execution."""

    name = "local"

    def __init__(self, workers: int = 1):
        if workers < 1:
            raise ValueError(f"--workers must be >= 1 (got {workers})")
        self.workers = workers

    def map(
        self,
        fn: Callable[[T], R],
        tasks: Sequence[T],
        on_result: OnResult | None = None,
        cancel: threading.Event | None = None,
    ) -> list[R]:
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

    def abort(self) -> None:
        """Stop the runs in flight of the tasks' threads, so that joining them does not wait for
        their training: a local run is stopped by its own supervisor (runner.run_experiment)."""


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


def _apply(fn: Callable[[T], R], task: T) -> R:
    # ray.remote wants a plain function; fn may be a partial or a closure.
    return fn(task)


def add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags every audit command shares."""
    group = parser.add_argument_group("execution")
    group.add_argument("--workers", type=int, default=1, help="runs in flight at once (default 1)")
    group.add_argument("--executor", choices=("local", "ray"), default="local", help="default local")
    group.add_argument("--ray-address", default=None, help="existing Ray cluster; default a local instance")
    group.add_argument("--cpus-per-task", type=float, default=1, help="Ray: CPUs one run reserves")
    group.add_argument(
        "--gpus-per-task", type=float, default=None, help="Ray: GPUs one run reserves (default 1 if any)"
    )
    group.add_argument(
        "--ray-files",
        choices=("ship", "shared"),
        default="ship",
        help="Ray: ship the family to the workers and the run's files back (default), or read and write "
        "them in place on a filesystem every node sees",
    )


def make_executor(args: argparse.Namespace) -> Executor:
    if args.executor == "ray":
        return ray_executor(args, args.workers)
    return LocalExecutor(args.workers)


def ray_executor(args: argparse.Namespace, workers: int) -> Executor:
    from autoresearch.ray_executor import RayExecutor  # imports ray

    return RayExecutor(args.ray_address, workers, args.cpus_per_task, args.gpus_per_task, args.ray_files)
