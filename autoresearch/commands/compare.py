"""``autoresearch compare``: score arms over their repeated campaigns (autoresearch/compare/report.py)."""

from __future__ import annotations

import argparse
import sys
from datetime import datetime
from pathlib import Path

from autoresearch.commands import SUMMARIES
from autoresearch.commands.common import positive_int
from autoresearch.compare.inputs import CompareError, load_arms
from autoresearch.compare.report import write_comparison
from autoresearch.journal import JournalError


def _arm(text: str) -> tuple[str, list[Path]]:
    name, _, dirs = text.partition("=")
    paths = [Path(d) for d in dirs.split(",") if d]
    if not name or not paths:
        raise argparse.ArgumentTypeError(f"expected NAME=DIR[,DIR...], got {text!r}")
    return name, paths


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "compare",
        help=SUMMARIES["compare"],
        description="Score each arm over its repeats: best so far at every experiment budget as median and "
        "interquartile mean with 95% stratified-bootstrap intervals, the probability that one arm's final "
        "best beats another's, the fraction reaching the target and the experiments it took. A directory "
        "holding repeat-*/ campaigns is one arm; a single campaign directory is an arm of one repeat.",
        epilog="Example: autoresearch compare runs/dock-tpe runs/dock-random --arm claude=runs/c1,runs/c2 --budget 24",
    )
    p.add_argument(
        "dirs", nargs="*", type=Path, metavar="DIR", help="an arm: a group of repeats or a campaign"
    )
    p.add_argument(
        "--arm",
        action="append",
        type=_arm,
        default=[],
        metavar="NAME=DIR[,DIR...]",
        help="an arm made of these campaigns (or groups), named NAME",
    )
    p.add_argument(
        "--budget", type=positive_int, help="experiments considered (default: the longest campaign's)"
    )
    p.add_argument(
        "--sigma",
        type=_positive_float,
        help="seed-noise std for the noise units (default: the campaigns' measured seed_noise)",
    )
    p.add_argument(
        "--out", type=Path, help="output directory (default <first arm's parent>/compare-<timestamp>)"
    )
    return p


def run(args: argparse.Namespace) -> int:
    specs = [(Path(d).resolve().name, [d]) for d in args.dirs] + args.arm
    if not specs:
        print("autoresearch compare: error: give at least one arm (DIR or --arm NAME=DIR)", file=sys.stderr)
        return 2
    out = args.out or Path(specs[0][1][0]).resolve().parent / f"compare-{datetime.now():%Y%m%d-%H%M%S}"
    try:
        arms = load_arms(specs)
        report = write_comparison(arms, out, budget=args.budget, sigma=args.sigma)
    except (CompareError, JournalError, OSError) as err:  # OSError: an --out it cannot create
        print(f"autoresearch compare: error: {err}", file=sys.stderr)
        return 2
    text = report.read_text(encoding="utf-8")
    final = text[text.index("## Final best") : text.index("## Best so far by budget")]
    print(final.rstrip())
    print(f"\nwritten: {report} (with compare.json and figures in {out})")
    return 0
