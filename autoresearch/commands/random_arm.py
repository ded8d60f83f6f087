"""``autoresearch random``: the random-search arm matched to a campaign (module named so as not to
shadow the standard library's random)."""

from __future__ import annotations

import argparse
from pathlib import Path

from autoresearch.audit.random_arm import default_arm_dir, run_random_arm
from autoresearch.campaign.lock import CampaignLock
from autoresearch.commands import SUMMARIES
from autoresearch.commands.common import add_audit_arguments, opened, positive_int, run_command
from autoresearch.family import resolve_family
from autoresearch.space import SPACES


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "random",
        help=SUMMARIES["random"],
        description="Random search over the family's editable surface from the same first experiment (the "
        "baseline), with the campaign's per-experiment timeout and experiment count, written as a campaign "
        "directory; then the verdict of paper Eq. verdict in seed-noise units.",
        epilog="Example: autoresearch random --family docking --budget-from runs/docking-tpe-20250101-120000",
    )
    p.add_argument("--family", help="family name or directory (default: the campaign's family)")
    p.add_argument("--budget-from", required=True, help="the campaign whose budget and count are matched")
    p.add_argument("--count", type=positive_int, help="experiments (default: as many as the campaign ran)")
    p.add_argument(
        "--matched-range",
        action="store_true",
        help="sample the training-budget axis over the campaign's range",
    )
    p.add_argument(
        "--space",
        choices=SPACES,
        help="sample every parameter's bounds, or its random_range where declared (default: the space "
        "the campaign's key-free proposer searched, else random-range)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the random proposer (default 0)")
    p.add_argument("--out", type=Path, help="arm directory (default <campaign>-random[-matched] beside it)")
    add_audit_arguments(p)
    return p


def _number(value: float | None) -> str:
    """A metric at the precision the other lines print it, not Python's 17 digits."""
    return "n/a" if value is None else f"{value:.6g}"


def draws(part: dict) -> str:
    """``4 draws, 1 did not finish``: a draw that failed or timed out is counted, not hidden."""
    missing = part["count"] - part["n_ran"]
    return f"{part['count']} draws" + (f", {missing} did not finish" if missing else "")


def print_random(part: dict) -> None:
    best = part["best"]
    best_text = f"{best['metric']:.6g} ({best['run_id']})" if best else "none feasible"
    print(
        f"random arm {part['dir']} ({part.get('space', 'random-range')} space): {draws(part)}: best "
        f"{best_text}; feasible {part['n_feasible']} of the {part['n_ran']} that finished"
    )
    units = f" ({part['units']:+.2f} sigma)" if part["units"] is not None else ""
    on = f" on the {part['split']} split" if part.get("split") == "test" else ""
    print(f"  verdict{on}: {part['verdict'] or part.get('verdict_note')}{units}")
    for side, judged in (part.get("judged") or {}).items():
        print(
            f"  {side} best {judged['config_id']} re-run at the default seed: test split "
            f"{_number(judged['test_metric'])}, search split {_number(judged['search_metric'])} (recorded "
            f"{_number(judged['recorded_search_metric'])}, "
            f"{'reproduced' if judged['reproduced'] else 'NOT reproduced'})"
        )


def run(args: argparse.Namespace) -> int:
    def body(executor) -> None:
        with CampaignLock(args.budget_from, "random"):
            campaign = opened(args.budget_from, args)
            out = args.out or default_arm_dir(campaign, args.matched_range)
            campaign.family.check_outside(out)
            with CampaignLock(out, "random", create=True):
                run_arm(executor, campaign, out)

    def run_arm(executor, campaign, out) -> None:
        if args.family and resolve_family(args.family).path != campaign.family.path:
            raise ValueError(
                f"{args.budget_from} is a campaign of {campaign.family.path}, not of {args.family}"
            )
        part = run_random_arm(
            campaign,
            executor,
            count=args.count,
            matched_range=args.matched_range,
            seed=args.seed,
            out=out,
            space=args.space,
        )
        print_random(part)

    return run_command("random", args, body)
