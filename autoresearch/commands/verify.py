"""``autoresearch verify``: reseeded verification of a campaign's best configurations."""

from __future__ import annotations

import argparse

from autoresearch.audit import tails
from autoresearch.audit.verify import verify
from autoresearch.campaign.lock import CampaignLock
from autoresearch.commands import SUMMARIES
from autoresearch.commands.common import add_audit_arguments, opened, positive_int, run_command
from autoresearch.splits import Split


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "verify",
        help=SUMMARIES["verify"],
        description="Rebuild the campaign's configurations from proposals.jsonl, rank them, re-run the top "
        "few at fresh seeds, gate each (margin m >= 2 seed-noise units and feasible on every seed) and "
        "promote the most reproducible passing one: the family's best in family.json, its numbers in ledger.json.",
        epilog="Example: autoresearch verify --campaign runs/docking-tpe-20250101-120000 --workers 2",
    )
    p.add_argument("--campaign", required=True, help="campaign directory")
    p.add_argument("--top", type=positive_int, default=3, help="candidates to reseed (default 3)")
    p.add_argument("--seeds", type=positive_int, default=10, help="fresh seeds per candidate (default 10)")
    add_gate_split_argument(p)
    add_gate_argument(p)
    add_audit_arguments(p)
    return p


def add_gate_split_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--gate-split",
        choices=[split.value for split in Split],
        help="the split the gate and the pruned recipe's re-verification use (default: the sealed test "
        "split where the family has one, else search; search is the paper's protocol). Which candidate is "
        "promoted and which edits are pruned is decided on the search split either way",
    )


def add_gate_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--gate",
        choices=tails.GATES,
        default=tails.RUNAWAY,
        help="runaway (default): the paper's gate, and no reseed with a start beyond the family's runaway "
        "bound (family.json tails.runaway_field); paper: the paper's gate alone (m >= 2 and feasible on "
        "every reseed). Every reseed's worst starts are reported either way",
    )


def print_verify(part: dict) -> None:
    split = Split(part.get("split", Split.SEARCH))
    for c in part["candidates"]:
        if "mu_r" in c:
            sd = "n/a" if c["sigma_r"] is None else f"{c['sigma_r']:.3g}"
            search = (c.get("by_split") or {}).get(Split.SEARCH.value)
            gap = f" (search split {search['mu_r']:.6g})" if split is Split.TEST and search else ""
            print(
                f"  {c['config_id']}: {split} split {c['mu_r']:.6g} +- {sd} (n={c['n']}){gap}, "
                f"m = {c['margin']:.2f}: {c['reason']}"
            )
        else:
            print(f"  {c['config_id']}: {c['reason']}")
        for far in (c.get("tails") or {}).get("outliers", ()):
            print(
                f"    seed {far['seed']} lies far outside the rest: {far['metric']:.6g} against a median of "
                f"{far['median_of_others']:.6g}"
            )
    print(f"  promoted: {part['promoted'] or 'none'} ({part['reason']})")


def run(args: argparse.Namespace) -> int:
    def body(executor) -> None:
        with CampaignLock(args.campaign, "verify"):
            campaign = opened(args.campaign, args)
            part = verify(
                campaign, executor, top=args.top, n_seeds=args.seeds, split=args.gate_split, gate=args.gate
            )
            print_verify(part)

    return run_command("verify", args, body)
