"""``autoresearch check``: validate a campaign's files and say how to repair each problem."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from autoresearch.audit.inputs import AuditError, open_campaign, provenance_report
from autoresearch.campaign import CampaignError
from autoresearch.campaign.check import check_campaign
from autoresearch.campaign.group import is_group, repeat_dirs
from autoresearch.campaign.lock import holder, not_a_directory
from autoresearch.campaign.scored_on import family_campaigns, off_split_runs
from autoresearch.commands import SUMMARIES
from autoresearch.execution.runner import run_prepare_check
from autoresearch.family import Family, FamilyError, family_problems, find_family_dir
from autoresearch.journal import JournalError


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "check",
        help=SUMMARIES["check"],
        description="With --family: check a family directory against the contract (docs/family-contract.md): "
        "its files, family.json field by field, train.py's editable region against the search space and "
        "the baseline, and prepare.py --check. With --campaign: check a campaign directory (or each "
        "campaign of a --repeats group): campaign.json and "
        "family.json readable; proposals.jsonl with iterations 1, 2, ... once each, whole lines, every "
        "recorded run with its run directory; runs.jsonl with whole lines, each run once and started by "
        "this campaign, every run recorded as ran logged there; audit.json, if any, a JSON object whose "
        "step parts are objects with a known status. Prints each problem in one line (with its repair, for "
        "a campaign). Exit 0 when clean, 1 with problems.",
        epilog="Examples: autoresearch check --family my-family; "
        "autoresearch check --campaign runs/docking-tpe-20250101-120000",
    )
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--campaign", type=Path, help="campaign (or repeats group) directory")
    which.add_argument("--family", help="family directory (or the name of one under families/)")
    p.add_argument(
        "--campaigns",
        type=Path,
        nargs="+",
        default=None,
        metavar="DIR",
        help="with --family: the directories whose campaigns of the family are checked for runs scored on "
        "data other than family.json's split_ids pin (default: results and runs in the working directory)",
    )
    p.add_argument(
        "--strict-provenance",
        action="store_true",
        help="count a difference between the environment now and the recorded one as a problem",
    )
    return p


def _provenance(root: Path) -> list[str]:
    """The provenance differences of a campaign whose files open (else the problems say why)."""
    try:
        return provenance_report(open_campaign(root, read_only=True), strict=False)
    except (AuditError, CampaignError, FamilyError, JournalError, OSError):
        return []


def _check_one(root: Path, strict: bool) -> bool:
    result = check_campaign(root)
    busy = holder(root)
    note = f"; in use by {busy}, so its files may change as you read them" if busy else ""
    differences = _provenance(root)
    if not result.problems and not (strict and differences):
        print(f"{root}: clean ({result.iterations} iterations){note}")
    else:
        count = len(result.problems) + (len(differences) if strict else 0)
        print(f"{root}: {count} problem(s), {result.iterations} iterations readable{note}")
    for note in result.notes:
        print(f"  note: {note}")
    for problem in result.problems:
        print(f"  {problem}")
    for line in differences:  # listed always; problems only with --strict-provenance
        print(f"  provenance: {line}")
    return not result.problems and not (strict and differences)


def _scored_elsewhere(path: Path, under: list[Path]) -> None:
    """Print each campaign of the family under ``under`` some of whose runs were scored on data other
    than the family pins: its numbers are not the family's (another build of a split, or older)."""
    try:
        family = Family.load(path)
    except FamilyError:
        return  # the contract problems above say why
    if not family.split_ids:
        return
    campaigns = family_campaigns(family, under)
    if not campaigns:
        return
    elsewhere = {root: reasons for root in campaigns if (reasons := off_split_runs(root, family))}
    where = ", ".join(str(d) for d in under)
    print(
        f"{path}: {len(elsewhere)} of {len(campaigns)} campaign(s) under {where} hold runs scored on data "
        "other than family.json's split_ids pin" + (":" if elsewhere else "")
    )
    for root, reasons in elsewhere.items():
        said = "; ".join(f"{count} run(s): {reason}" for reason, count in sorted(reasons.items()))
        print(f"  {root}: {said}")


def _check_family(given: str, under: list[Path] | None = None) -> int:
    try:
        path = find_family_dir(given)
    except FamilyError as err:
        print(f"autoresearch check: error: {err}", file=sys.stderr)
        return 2
    problems = family_problems(path)
    if (path / "prepare.py").is_file():
        failed = run_prepare_check(path.resolve())
        problems += [failed] if failed else []
    print(f"{path}: clean" if not problems else f"{path}: {len(problems)} problem(s)")
    for problem in problems:  # prepare.py's own output may name its problems a line each
        print("  " + problem.replace("\n", "\n    "))
    _scored_elsewhere(path, under if under is not None else [Path("results"), Path("runs")])
    return 1 if problems else 0


def run(args: argparse.Namespace) -> int:
    if args.family is not None:
        return _check_family(args.family, args.campaigns)
    root = args.campaign
    problem = not_a_directory(root)
    if problem:
        print(f"autoresearch check: error: {problem}", file=sys.stderr)
        return 2
    roots = repeat_dirs(root) if is_group(root) else [root]
    try:
        clean = [_check_one(r, args.strict_provenance) for r in roots]
    except OSError as err:  # a file it may not read
        print(f"autoresearch check: error: {err}", file=sys.stderr)
        return 2
    return 0 if all(clean) else 1
