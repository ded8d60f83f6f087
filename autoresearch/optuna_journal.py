"""A campaign as an Optuna study in a JournalStorage file, so that optuna-dashboard, Optuna's plots
and its parameter importances read it, after the fact (``autoresearch export``) or live (``loop
--optuna-journal``).

The campaign's files stay the record of truth: the journal is derived from its records (read
through the campaign store) and can be rebuilt at any time. One study per campaign, named after
its directory, with the family's direction. Every iteration that started a run is one trial, with
the full configuration as its params (the family's distributions):

- a run that ran is COMPLETE with its metric; a failed one is FAIL; one stopped by the early stopper
  is PRUNED, its PROGRESS points the trial's intermediate values;
- a family's graded constraints (``constraints_field``) are the trial's constraints, so the
  dashboard marks infeasible trials as Optuna's own samplers see them;
- user attributes: iteration, run id, proposer, hypothesis, axes, verdict, feasible, the reason of a
  failure, and the test split is never among them (a campaign holds none).

Iterations that ran nothing (a refused proposal, a stop request, the loop's stop) are not trials.
Adding is idempotent (keyed by the iteration), so a resumed loop fills any gap a crash left.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path
from typing import Any

import optuna
from optuna.storages import JournalStorage
from optuna.storages.journal import JournalFileBackend
from optuna.trial import TrialState

from autoresearch.campaign import Campaign, Record, Status
from autoresearch.family import Family
from autoresearch.proposers.optuna_space import distributions

_STATES = {
    Status.RAN: TrialState.COMPLETE,
    Status.FAILED: TrialState.FAIL,
    Status.EARLY_STOPPED: TrialState.PRUNED,
}


class OptunaJournal:
    """The study of one campaign in the journal file at ``path`` (created when missing)."""

    def __init__(self, path: str | Path, family: Family, study_name: str):
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        self.family = family
        self.distributions = distributions(family.space)
        storage = JournalStorage(JournalFileBackend(str(Path(path))))
        self.study = optuna.create_study(
            storage=storage, study_name=study_name, direction=family.direction.study, load_if_exists=True
        )
        self.study.set_user_attr("metric", family.metric)
        with warnings.catch_warnings():  # experimental since Optuna 3.2, read by the dashboard's axes
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            self.study.set_metric_names([family.metric])
        self.study.set_user_attr("family", family.name)
        self.added = {trial.user_attrs.get("iteration") for trial in self.study.get_trials(deepcopy=False)}

    def add(self, record: Record) -> bool:
        """Add the trial of ``record``; False when it ran nothing or is already in the study."""
        if not record.status.started_a_run or record.iteration in self.added:
            return False
        annotation = (record.proposal or {}).get("annotation") or {}
        attrs: dict[str, Any] = {
            "iteration": record.iteration,
            "run_id": record.run_id,
            "proposer": record.proposer,
            "hypothesis": record.hypothesis,
            "axes": annotation.get("axes"),
            "verdict": record.verdict,
            "feasible": record.feasible,
            "reason": record.reason,
        }
        trial = optuna.trial.create_trial(
            state=_STATES[record.status],
            value=record.metric if record.ran else None,
            params=self.family.space.validate_full(record.config),
            distributions=self.distributions,
            user_attrs={k: v for k, v in attrs.items() if v is not None},
            intermediate_values={point["step"]: point["value"] for point in record.progress or ()},
            constraints=self._constraints(record),
        )
        self.study.add_trial(trial)
        self.added.add(record.iteration)
        return True

    def _constraints(self, record: Record) -> dict[str, float] | None:
        """The family's graded constraints (<= 0 met), else its gate as 0/1, else none."""
        if not record.ran or self.family.feasibility_field is None:
            return None
        return self.family.constraints(record.final_metric) or {"feasible": 0.0 if record.feasible else 1.0}

    def sync(self, records: list[Record]) -> int:
        """Add every record not yet in the study; how many were added."""
        return sum(self.add(record) for record in sorted(records, key=lambda r: r.iteration))


def export_campaign(campaign_dir: str | Path, path: str | Path) -> tuple[OptunaJournal, int]:
    """Write (or bring up to date) the study of the campaign in ``campaign_dir`` in ``path``."""
    store = Campaign(campaign_dir)
    family = store.meta().open_family(store.root)
    journal = OptunaJournal(path, family, store.root.name)
    return journal, journal.sync(store.records())


class LiveFeed:
    """The loop's live feed: each record as it is written. A failing journal never stops the
    campaign (the journal is derived): the feed says so once and stops; ``autoresearch export``
    rebuilds it."""

    def __init__(self, path: str | Path, family: Family, campaign: Campaign):
        self.journal: OptunaJournal | None = OptunaJournal(path, family, campaign.root.name)
        self.journal.sync(campaign.records())

    def __call__(self, record: Record) -> None:
        if self.journal is None:
            return
        try:
            self.journal.add(record)
        except Exception as err:  # a derived view: whatever it hits, the campaign goes on
            self.journal = None
            print(f"[optuna-journal] stopped: {err}; rebuild it with `autoresearch export`", file=sys.stderr)
