"""``autoresearch report``: write a campaign's audit report (report.md and its figures)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from autoresearch.audit.inputs import AuditError
from autoresearch.audit.report import write_report
from autoresearch.campaign.check import trail_refusal
from autoresearch.campaign.lock import not_a_directory
from autoresearch.commands import SUMMARIES
from autoresearch.exits import error_exit
from autoresearch.family import FamilyError
from autoresearch.journal import JournalError


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "report",
        help=SUMMARIES["report"],
        description="Write the audit report of a campaign: the audit table (seed noise, random arms, "
        "single-seed best, reseeded mean with its margin and PASS/FAIL), the mean difference with its "
        "confidence interval, the pruning decisions, and the search and recipe figures.",
        epilog="Example: autoresearch report --campaign runs/docking-llm --arm runs/docking-tpe",
    )
    p.add_argument("--campaign", required=True, type=Path, help="campaign directory")
    p.add_argument("--arm", action="append", type=Path, default=[], help="another arm to plot (repeatable)")
    p.add_argument("--out", type=Path, help="output directory (default: the campaign directory)")
    return p


def _refusal(args: argparse.Namespace) -> str | None:
    """Why the report cannot be written from these inputs, or None."""
    campaign = args.campaign
    if not_a_directory(campaign):
        return not_a_directory(campaign)
    for arm in args.arm:
        if not arm.is_dir():
            return f"--arm {arm}: not a campaign directory"
    return trail_refusal(campaign)  # duplicated or missing iterations would skew every figure


def run(args: argparse.Namespace) -> int:
    refusal = _refusal(args)
    if refusal:
        print(f"autoresearch report: error: {refusal}", file=sys.stderr)
        return 2
    try:
        print(write_report(args.campaign, arms=args.arm, out_dir=args.out))
    except (AuditError, FamilyError, JournalError, OSError) as err:
        return error_exit("report", err)  # 3 when the disk is full, like every other command
    return 0
