"""``autoresearch prune``: leave-one-out pruning of the promoted configuration."""

from __future__ import annotations

import argparse

from autoresearch.audit.commandline import positive_int, run_command
from autoresearch.audit.inputs import open_campaign
from autoresearch.audit.prune import prune
from autoresearch.campaign_lock import CampaignLock
from autoresearch.executors import add_executor_arguments


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "prune",
        help="find which edits of the promoted configuration carry the result",
        description="Revert each edited parameter of the promoted configuration alone to its family default "
        "and decide keep / drop / drop-dagger in seed-noise units (escalating from one probe seed to two), "
        "then re-verify the pruned recipe at fresh seeds and publish it only if it clears the same gate "
        "and keeps the target.",
        epilog="Example: autoresearch prune --campaign runs/docking-tpe-20250101-120000",
    )
    p.add_argument("--campaign", required=True, help="campaign directory (verified first)")
    p.add_argument(
        "--seeds", type=positive_int, help="re-verification seeds (default: as many as verify used)"
    )
    add_executor_arguments(p)
    return p


def print_prune(part: dict) -> None:
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
            print_prune(prune(open_campaign(args.campaign), executor, n_seeds=args.seeds))

    return run_command("prune", args, body)
