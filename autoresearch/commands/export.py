"""``autoresearch export``: a campaign as an Optuna study in a JournalStorage file (optuna-dashboard)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from autoresearch.audit.outcome import certified, reseeded_runs
from autoresearch.campaign import Campaign, CampaignError
from autoresearch.campaign.audit_log import read_audit
from autoresearch.commands import SUMMARIES
from autoresearch.exits import error_exit
from autoresearch.family import FamilyError
from autoresearch.journal import JournalError


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "export",
        help=SUMMARIES["export"],
        description="Write (or bring up to date) the campaign as one Optuna study in a JournalStorage "
        "file: every run a trial with the family's distributions, its value or failure, PROGRESS as "
        "intermediate values, early-stopped runs pruned, graded constraints, and hypothesis, axes, verdict "
        "and run id as user attributes; after an audit, its outcome (verdict, certified metric, split, margin) "
        "as study user attributes and its reseeded runs as trials of the study '<study> (reseeded)'. The "
        "campaign files stay the record of truth; run it again any time.",
        epilog="Example: autoresearch export --campaign runs/dock-tpe --optuna-journal dock.log && "
        "optuna-dashboard dock.log",
    )
    p.add_argument("--campaign", required=True, type=Path, help="campaign directory")
    p.add_argument("--optuna-journal", required=True, type=Path, help="the journal file (created if missing)")
    return p


def carry_audit(journal, campaign_dir: Path) -> str | None:
    """The campaign's audit outcome written into its study (OptunaJournal.record_audit), in a line
    for the console; None when the campaign has no reseeded configuration yet."""
    audit = read_audit(campaign_dir)
    outcome = certified(audit)
    if outcome is None:
        return None
    added = journal.record_audit(outcome, reseeded_runs(audit))
    return (
        f"audit: {outcome['verdict']}, {outcome['config_id']} certified at {outcome['metric']:.4g} on the "
        f"{outcome['split']} split, m = {outcome['margin_sigma']:.1f} sigma (study user attributes audit_*); "
        f"its reseeded runs in study {journal.study.study_name + ' (reseeded)'!r} ({added} added)"
    )


def update_live_journal(campaign_dir: Path) -> str | None:
    """After an audit: its outcome carried into the campaign's own ``--optuna-journal`` (kept in
    campaign.json), when it has one and it is found from here; a line saying what happened. A
    journal is derived: whatever goes wrong is said, and the audit stands."""
    from autoresearch.optuna_journal import OptunaJournal  # optuna only for a campaign that has a journal

    store = Campaign(campaign_dir)
    meta = store.meta()
    path = meta.settings.get("optuna_journal")
    if not path:
        return None
    again = f"autoresearch export --campaign {campaign_dir} --optuna-journal {path}"
    if not Path(path).is_file():
        return f"{path} is not found from here: `{again}` writes the audit's outcome into it"
    try:
        return carry_audit(OptunaJournal(path, meta.open_family(store.root), store), campaign_dir)
    except Exception as err:  # a derived view: whatever it hits, the audit stands
        return f"{path}: the audit's outcome was not written ({err}); `{again}` writes it"


def run(args: argparse.Namespace) -> int:
    from autoresearch.optuna_journal import export_campaign  # optuna only when exporting

    try:
        journal, added = export_campaign(args.campaign, args.optuna_journal)
        audited = carry_audit(journal, args.campaign)
    except (CampaignError, FamilyError, JournalError, OSError) as err:
        return error_exit("export", err)
    study = journal.study
    print(
        f"{args.optuna_journal}: study {study.study_name!r}, {len(study.trials)} trials "
        f"({added} added); view it with: optuna-dashboard {args.optuna_journal}",
        file=sys.stdout,
    )
    if audited:
        print(audited)
    return 0
