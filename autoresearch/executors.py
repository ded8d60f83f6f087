"""One interface for running independent tasks: serially, on a local pool, or on Ray.

Every audit task is one training run, i.e. one subprocess, so the local pool is a thread pool
driving subprocesses: no pickling, no fork of the parent, and results come back in the parent,
where the caller logs them (through the journal's file lock, so appends never interleave).
Ray runs the same function as remote tasks, each reserving the CPUs (and GPU) one run needs;
ray is imported only when chosen. Results are returned in task order, so for the same seeds
they are identical to a serial run's.
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

from autoresearch.extras import require

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
        if self.workers == 1:
            for i, task in enumerate(tasks):
                results[i] = fn(task)
                if on_result:
                    on_result(i, results[i])
            return results
        with ThreadPoolExecutor(max_workers=self.workers) as pool:
            futures = {pool.submit(fn, task): i for i, task in enumerate(tasks)}
            for future in as_completed(futures):
                i = futures[future]
                results[i] = future.result()
                if on_result:
                    on_result(i, results[i])
        return results


class RayExecutor(Executor):
    """The same tasks as Ray remote tasks.

    address: an existing cluster ("auto" or "ray://host:port"); None starts a local instance
    with ``workers * cpus_per_task`` CPUs. On a cluster, the family directory and the campaign
    directory must be on a filesystem every node sees, and autoresearch installed on each node.
    gpus_per_task None: one GPU per task when the cluster has GPUs, none otherwise.
    """

    name = "ray"

    def __init__(
        self,
        address: str | None = None,
        workers: int = 1,
        cpus_per_task: float = 1,
        gpus_per_task: float | None = None,
    ):
        ray = require("ray", "ray", "--executor ray")
        if workers < 1:
            raise ValueError(f"--workers must be >= 1 (got {workers})")
        self._ray = ray
        self.workers = workers
        self._started = False
        if not ray.is_initialized():
            with keeping_signal_handlers():
                if address:
                    ray.init(address=address, log_to_driver=False)
                else:
                    ray.init(num_cpus=workers * cpus_per_task, include_dashboard=False, log_to_driver=False)
            self._started = True
        if gpus_per_task is None:
            gpus_per_task = 1 if ray.cluster_resources().get("GPU", 0) > 0 else 0
        self.options = {"num_cpus": cpus_per_task, "num_gpus": gpus_per_task}

    def map(
        self,
        fn: Callable[[T], R],
        tasks: Sequence[T],
        on_result: OnResult | None = None,
        cancel: threading.Event | None = None,
    ) -> list[R]:
        ray = self._ray
        remote = ray.remote(**self.options)(_apply)
        fn_ref = ray.put(fn)  # shipped once, not once per task
        index = {remote.remote(fn_ref, task): i for i, task in enumerate(tasks)}
        results: list[Any] = [None] * len(tasks)
        pending = list(index)
        try:
            while pending:
                if cancel is not None and cancel.is_set():
                    raise KeyboardInterrupt
                done, pending = ray.wait(pending, num_returns=1, timeout=CANCEL_POLL_S)
                if done:
                    i = index[done[0]]
                    results[i] = ray.get(done[0])
                    if on_result:
                        on_result(i, results[i])
        except BaseException:  # SIGTERM, Ctrl-C, cancel or an error: the runs in flight stop too
            self._cancel(pending)
            raise
        return results

    def _cancel(self, refs: list[Any]) -> None:
        """Cancel ``refs``: a KeyboardInterrupt in each task (the runner then kills its training
        process group and whatever else the run started), then the worker killed if it lingers."""
        ray = self._ray
        for ref in refs:
            ray.cancel(ref)
        lingering = ray.wait(refs, num_returns=len(refs), timeout=CANCEL_GRACE_S)[1] if refs else []
        for ref in lingering:
            ray.cancel(ref, force=True)

    def close(self) -> None:
        if self._started:
            with keeping_signal_handlers():
                self._ray.shutdown()
            self._started = False


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


def make_executor(args: argparse.Namespace) -> Executor:
    if args.executor == "ray":
        return RayExecutor(args.ray_address, args.workers, args.cpus_per_task, args.gpus_per_task)
    return LocalExecutor(args.workers)
