"""The runs in flight of one campaign, and how each is supervised.

With one worker a run is executed in the calling thread; with more, each run has a supervising
thread of its own and reports back through a queue, so the loop can propose while runs train.
``cancel`` (set when the loop unwinds: Ctrl-C, SIGTERM, a bug) kills every run in flight, whoever
executes it (autoresearch.execution.runner kills its process group; a Ray task is cancelled).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterator

from autoresearch.campaign import Intent
from autoresearch.execution.result import RunResult

Outcome = tuple[Intent, RunResult]


class Scheduler:
    def __init__(self, workers: int, execute: Callable[[Intent], RunResult]):
        self.workers = workers
        self.execute = execute
        self.in_flight: dict[str, Intent] = {}  # run_id -> intent, in launch order
        self.cancel = threading.Event()
        self._done: queue.Queue[tuple[Intent, RunResult | BaseException]] = queue.Queue()
        self._threads: list[threading.Thread] = []

    @property
    def full(self) -> bool:
        return len(self.in_flight) >= self.workers

    def launch(self, intent: Intent) -> None:
        """Put the run in flight: in this thread with one worker, else on a thread of its own."""
        self.in_flight[intent.run_id] = intent
        if self.workers == 1:
            self._done.put((intent, self.execute(intent)))
            return
        self._threads = [t for t in self._threads if t.is_alive()]
        thread = threading.Thread(target=self._supervise, args=(intent,), name=intent.run_id, daemon=True)
        self._threads.append(thread)
        thread.start()

    def _supervise(self, intent: Intent) -> None:
        try:
            outcome: RunResult | BaseException = self.execute(intent)
        except BaseException as err:  # re-raised in the main thread
            outcome = err
        self._done.put((intent, outcome))

    def collect(self, block: bool) -> Outcome:
        """One finished run; raises queue.Empty when none has finished and not ``block``."""
        while True:
            try:
                intent, outcome = self._done.get(timeout=0.2) if block else self._done.get_nowait()
                break
            except queue.Empty:
                if not block:
                    raise
        del self.in_flight[intent.run_id]
        if isinstance(outcome, BaseException):
            raise outcome
        return intent, outcome

    def finished(self) -> Iterator[Outcome]:
        """Every run that has finished by now, without waiting."""
        try:
            while True:
                yield self.collect(block=False)
        except queue.Empty:
            return

    def drain(self) -> Iterator[Outcome]:
        """Every run in flight, as each finishes."""
        while self.in_flight:
            yield self.collect(block=True)

    def abort(self) -> None:
        """Kill every run in flight and wait for their supervisors."""
        self.cancel.set()
        for thread in self._threads:
            thread.join()
