"""``autoresearch check``: validate a campaign's files and say how to repair each problem."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from autoresearch.loop import repeats
from autoresearch.loop.campaign_check import check_campaign
from autoresearch.loop.campaign_lock import holder, not_a_directory


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "check",
        help="validate a campaign's files (duplicates, gaps, torn lines) and say how to repair them",
        description="Check a campaign directory (or each campaign of a --repeats group): campaign.json and "
        "family.json readable; proposals.jsonl with iterations 1, 2, ... once each, whole lines, every "
        "recorded run with its run directory; runs.jsonl with whole lines, each run once and started by "
        "this campaign. Prints each problem with its repair. Exit 0 when clean, 1 with problems.",
        epilog="Example: autoresearch check --campaign runs/docking-tpe-20250101-120000",
    )
    p.add_argument("--campaign", required=True, type=Path, help="campaign (or repeats group) directory")
    return p


def _check_one(root: Path) -> bool:
    result = check_campaign(root)
    busy = holder(root)
    note = f"; in use by {busy}, so its files may change as you read them" if busy else ""
    if not result.problems:
        print(f"{root}: clean ({result.iterations} iterations){note}")
        return True
    print(f"{root}: {len(result.problems)} problem(s), {result.iterations} iterations readable{note}")
    for problem in result.problems:
        print(f"  {problem}")
    return False


def run(args: argparse.Namespace) -> int:
    root = args.campaign
    problem = not_a_directory(root)
    if problem:
        print(f"autoresearch check: error: {problem}", file=sys.stderr)
        return 2
    roots = repeats.repeat_dirs(root) if repeats.is_group(root) else [root]
    try:
        clean = [_check_one(r) for r in roots]
    except OSError as err:  # a file it may not read
        print(f"autoresearch check: error: {err}", file=sys.stderr)
        return 2
    return 0 if all(clean) else 1
