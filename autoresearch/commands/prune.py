"""``autoresearch prune``: leave-one-out pruning of the promoted configuration."""

from __future__ import annotations

import argparse

from autoresearch.audit.prune import NOISE_AT, Rule, prune
from autoresearch.campaign.lock import CampaignLock
from autoresearch.commands import SUMMARIES
from autoresearch.commands.common import add_audit_arguments, opened, positive_int, run_command


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "prune",
        help=SUMMARIES["prune"],
        description="Revert each edited parameter of the promoted configuration alone to its family default "
        "and decide keep / drop / drop-dagger in seed-noise units (escalating from one probe seed to two), "
        "then re-verify the pruned recipe at fresh seeds and publish it only if it clears the same gate "
        "and keeps the target. --paired and --noise-at candidate sharpen the rule (docs/audit.md); each rule's "
        "result is kept under its own audit.json key, and the one run last decides.",
        epilog="Example: autoresearch prune --campaign runs/docking-tpe-20250101-120000 --paired",
    )
    p.add_argument("--campaign", required=True, help="campaign directory (verified first)")
    p.add_argument(
        "--seeds", type=positive_int, help="re-verification seeds (default: as many as verify used)"
    )
    add_rule_arguments(p)
    add_audit_arguments(p)
    return p


def add_rule_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--paired",
        action="store_true",
        help="probe each edit at its own seeds with the full configuration at the same seeds, "
        "and decide on the paired differences (default: the paper's shared probe seeds)",
    )
    p.add_argument(
        "--noise-at",
        choices=NOISE_AT,
        default="baseline",
        help="the noise unit: the baseline's seed noise (the paper's, default) or the spread of the "
        "candidate's own reseeds (sigma_R from verification)",
    )


def rule_of(args: argparse.Namespace) -> Rule:
    return Rule(paired=args.paired, noise_at=args.noise_at)


def print_prune(part: dict) -> None:
    if "unit" in part:
        print(
            f"  rule: {part['rule']}; unit sigma = {part['unit']['sigma']:.4g} (at the {part['unit']['at']})"
        )
    for d in part.get("decisions", []):
        deltas = ", ".join(f"{k[:6]} = {d[k]:+.2f} sigma" for k in ("delta1_sigma", "delta2_sigma") if k in d)
        print(
            f"  {d['param']}: {d['decision']}"
            + (f" ({deltas})" if deltas else "")
            + (f"; {d['note']}" if d["note"] else "")
        )
    print(f"  {part['reason']}")


def run(args: argparse.Namespace) -> int:
    def body(executor) -> None:
        with CampaignLock(args.campaign, "prune"):
            print_prune(prune(opened(args.campaign, args), executor, n_seeds=args.seeds, rule=rule_of(args)))

    return run_command("prune", args, body)
