"""``autoresearch export``: a campaign as an Optuna study in a JournalStorage file (optuna-dashboard)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from autoresearch.campaign import CampaignError
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
        "and run id as user attributes. The campaign files stay the record of truth; run it again any time.",
        epilog="Example: autoresearch export --campaign runs/dock-tpe --optuna-journal dock.log && "
        "optuna-dashboard dock.log",
    )
    p.add_argument("--campaign", required=True, type=Path, help="campaign directory")
    p.add_argument("--optuna-journal", required=True, type=Path, help="the journal file (created if missing)")
    return p


def run(args: argparse.Namespace) -> int:
    from autoresearch.optuna_journal import export_campaign  # optuna only when exporting

    try:
        journal, added = export_campaign(args.campaign, args.optuna_journal)
    except (CampaignError, FamilyError, JournalError, OSError) as err:
        return error_exit("export", err)
    study = journal.study
    print(
        f"{args.optuna_journal}: study {study.study_name!r}, {len(study.trials)} trials "
        f"({added} added); view it with: optuna-dashboard {args.optuna_journal}",
        file=sys.stdout,
    )
    return 0
