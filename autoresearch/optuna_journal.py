"""A campaign as an Optuna study in a JournalStorage file, so that optuna-dashboard, Optuna's plots
and its parameter importances read it, after the fact (``autoresearch export``) or live (``loop
--optuna-journal``).

The campaign's files stay the record of truth: the journal is derived from its records (read
through the campaign store) and can be rebuilt at any time. One study per campaign, with the
family's direction, named after its directory; the study says which campaign it is (user attribute
``campaign``: family, proposer, creation time), so two campaigns of one name in one journal file
are two studies (the second named ``<dir> [<created>]``), never one merged study. Every iteration
that started a run is one trial, with the full configuration as its params (the family's
distributions):

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

from autoresearch.campaign import Campaign, CampaignError, Record, Status
from autoresearch.family import Family
from autoresearch.proposers.optuna_space import distributions

_STATES = {
    Status.RAN: TrialState.COMPLETE,
    Status.FAILED: TrialState.FAIL,
    Status.EARLY_STOPPED: TrialState.PRUNED,
}


CAMPAIGN_ATTR = "campaign"  # the study's user attribute naming the campaign it is


class OptunaJournal:
    """The study of one campaign in the journal file at ``path`` (created when missing)."""

    def __init__(self, path: str | Path, family: Family, campaign: Campaign):
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        self.family = family
        self.distributions = distributions(family.space)
        meta = campaign.meta()
        identity = f"{meta.family_name}, {meta.proposer}, created {meta.created}"
        try:
            self.storage = storage = JournalStorage(JournalFileBackend(str(Path(path))))
            name = _study_name(storage, path, campaign.root.name, meta.created, identity, family)
            self.study = optuna.create_study(
                storage=storage, study_name=name, direction=family.direction.study, load_if_exists=True
            )
            self.study.set_user_attr(CAMPAIGN_ATTR, identity)
            self.study.set_user_attr("metric", family.metric)
            with warnings.catch_warnings():  # experimental since Optuna 3.2, read by the dashboard's axes
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                self.study.set_metric_names([family.metric])
            self.study.set_user_attr("family", family.name)
        except (OSError, CampaignError):
            raise
        except Exception as err:  # whatever Optuna's replay of a file that is no journal raises
            raise CampaignError(
                f"{path}: not an Optuna journal file ({type(err).__name__}: {err}); give --optuna-journal a "
                "new file or one Optuna wrote"
            ) from None
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
            "verdict_noise": record.verdict_noise,
            "feasible": record.feasible,
            "reason": record.reason,
        }
        trial = optuna.trial.create_trial(
            state=_STATES[record.status],
            value=record.metric if record.ran else None,
            params=self.family.space.validate_full(self.family.completed(record.config)),
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

    def record_audit(self, outcome: dict[str, Any], runs: list[dict[str, Any]]) -> int:
        """The audit's outcome on the campaign's study, so the dashboard shows what was certified
        beside the one-seed trials: study user attributes ``audit_*`` (verdict, certified metric and
        its sd, n, split, margin in units of seed noise, configuration, the step that certified it);
        and every reseeded run (``runs``, autoresearch.audit.outcome.reseeded_runs) a trial of the
        study ``<study> (reseeded)``, its value the metric on the gated split. Idempotent; returns
        how many reseeded runs were added."""
        for key in ("verdict", "metric", "sigma_r", "n", "split", "margin_sigma", "config_id", "step"):
            self.study.set_user_attr(f"audit_{key}", outcome[key])
        name = f"{self.study.study_name} (reseeded)"
        reseeded = optuna.create_study(
            storage=self.storage, study_name=name, direction=self.family.direction.study, load_if_exists=True
        )
        reseeded.set_user_attr(CAMPAIGN_ATTR, self.study.user_attrs.get(CAMPAIGN_ATTR))
        reseeded.set_user_attr("metric", f"{self.family.metric} ({outcome['split']} split)")
        done = {trial.user_attrs.get("run_id") for trial in reseeded.get_trials(deepcopy=False)}
        added = 0
        for run in runs:
            if run["run_id"] in done:
                continue
            ran = run["status"] == "ok" and run["metric"] is not None
            attrs = {
                k: run[k] for k in ("step", "config_id", "promoted", "split", "seed", "run_id", "excluded")
            }
            reseeded.add_trial(
                optuna.trial.create_trial(
                    state=TrialState.COMPLETE if ran else TrialState.FAIL,
                    value=run["metric"] if ran else None,
                    params=self.family.space.validate_full(self.family.completed(run["config"])),
                    distributions=self.distributions,
                    user_attrs={k: v for k, v in attrs.items() if v is not None},
                )
            )
            added += 1
        return added


def _study_name(
    storage: JournalStorage, path: str | Path, base: str, created: str, identity: str, family: Family
) -> str:
    """The campaign's study in the journal: the directory's name, unless a study of that name is
    another campaign's (then ``<dir> [<created>]``). A study written before studies said whose they
    were is this campaign's when its family and direction are."""
    studies = {study.study_name: study for study in storage.get_all_studies()}
    for name in (base, f"{base} [{created}]"):
        study = studies.get(name)
        if study is None:
            return name
        owner = study.user_attrs.get(CAMPAIGN_ATTR)
        unmarked = owner is None and study.user_attrs.get("family") == family.name
        if owner == identity or (unmarked and study.direction.name.lower() == family.direction.study):
            return name
    raise CampaignError(
        f"{path}: the studies {base!r} and {base + f' [{created}]'!r} there are other campaigns'; "
        "write this campaign's to another journal file"
    )


def export_campaign(campaign_dir: str | Path, path: str | Path) -> tuple[OptunaJournal, int]:
    """Write (or bring up to date) the study of the campaign in ``campaign_dir`` in ``path``."""
    store = Campaign(campaign_dir)
    family = store.meta().open_family(store.root)
    journal = OptunaJournal(path, family, store)
    return journal, journal.sync(store.records())


class LiveFeed:
    """The loop's live feed: each record as it is written. A failing journal never stops the
    campaign (the journal is derived): the feed says so once and stops; ``autoresearch export``
    rebuilds it."""

    def __init__(self, path: str | Path, family: Family, campaign: Campaign):
        self.journal: OptunaJournal | None = OptunaJournal(path, family, campaign)
        self.journal.sync(campaign.records())

    def __call__(self, record: Record) -> None:
        if self.journal is None:
            return
        try:
            self.journal.add(record)
        except Exception as err:  # a derived view: whatever it hits, the campaign goes on
            self.journal = None
            print(f"[optuna-journal] stopped: {err}; rebuild it with `autoresearch export`", file=sys.stderr)
