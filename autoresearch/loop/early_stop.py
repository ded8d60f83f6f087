"""Early stopping of hopeless runs (``loop --early-stop``): Optuna's pruners judge the PROGRESS curves.

One in-memory study per campaign, one trial per run: each PROGRESS point of a run in flight is
``trial.report(value, step)``, and ``trial.should_prune()`` decides whether to stop it. Finished
runs are told as complete trials (pruned ones as pruned), so a run is compared with the curves of
the runs before it at the same step. On ``--resume`` the study is rebuilt from the records' curves,
each replayed through the pruner. ``hyperband`` is Optuna's HyperbandPruner (successive halving in
brackets of different aggressiveness); with the TPE proposer it is the BOHB-style arm.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TYPE_CHECKING

from autoresearch.campaign import Record, Status
from autoresearch.direction import Direction

if TYPE_CHECKING:
    import optuna

# optuna is imported only when early stopping is on: it costs the CLI a second of start-up.
EARLY_STOP = ("none", "median", "asha", "hyperband")
# Hyperband assigns a run to a bracket by hashing the study's name and the trial's number: a fixed
# name makes the assignment a function of the run's place in the campaign.
STUDY_NAME = "early-stop"


def make_pruner(name: str) -> optuna.pruners.BasePruner:
    import optuna

    if name == "median":
        return optuna.pruners.MedianPruner()
    if name == "asha":
        return optuna.pruners.SuccessiveHalvingPruner()
    if name == "hyperband":
        # Optuna's defaults: reduction factor 3, rungs from step 1 to the longest finished curve.
        return optuna.pruners.HyperbandPruner()
    raise ValueError(f"--early-stop must be one of {', '.join(EARLY_STOP)}, got {name!r}")


def curve_of(record: Record) -> dict[int, float]:
    """A run's PROGRESS curve as Optuna's intermediate values, {step: value}."""
    return {point["step"]: point["value"] for point in record.progress or ()}


class EarlyStopper:
    """Thread-safe: runs in flight report from their own supervising threads."""

    def __init__(self, name: str, direction: Direction, records: list[Record] = ()):
        import optuna

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        self.name = name
        self.study = optuna.create_study(
            study_name=STUDY_NAME, direction=direction.study, pruner=make_pruner(name)
        )
        self._lock = threading.Lock()
        self._trials: dict[str, optuna.Trial] = {}
        for record in records:
            self._add_finished(record)

    def _add_finished(self, record: Record) -> None:
        """A finished run's curve, replayed through the pruner as it was heard live: the successive-halving
        pruners keep each run's rung values in its trial's system attributes, set only as they judge it."""
        curve = curve_of(record)
        if not curve or record.status not in (Status.RAN, Status.EARLY_STOPPED):
            return  # a failed run's curve says nothing about the metric it would have reached
        from optuna.trial import TrialState

        trial = self.study.ask()
        for step, value in sorted(curve.items()):
            trial.report(value, step)
            trial.should_prune()
        if record.ran:
            self.study.tell(trial, record.metric)
        else:
            self.study.tell(trial, state=TrialState.PRUNED)

    def start(self, run_id: str) -> Callable[[int, float], bool]:
        """The ``on_report`` of one run: True when the pruner says to stop it."""
        with self._lock:
            trial = self._trials[run_id] = self.study.ask()

        def report(step: int, value: float) -> bool:
            with self._lock:
                trial.report(value, step)
                return trial.should_prune()

        return report

    def finish(self, record: Record) -> None:
        """Tell the study how a run ended (a run adopted on resume had no trial: it is added)."""
        from optuna.trial import TrialState

        with self._lock:
            trial = self._trials.pop(record.run_id, None)
            if trial is None:
                self._add_finished(record)
            elif record.ran:
                self.study.tell(trial, record.metric)
            else:
                stopped = record.status is Status.EARLY_STOPPED
                self.study.tell(trial, state=TrialState.PRUNED if stopped else TrialState.FAIL)
