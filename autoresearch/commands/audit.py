"""``autoresearch audit``: the whole credibility audit of a campaign, step by step, then its report."""

from __future__ import annotations

import argparse
from pathlib import Path

from autoresearch.audit.inputs import gate_split, has_noise, open_campaign
from autoresearch.audit.noise import measure_noise, record_existing_noise, stale_noise
from autoresearch.audit.prune import prune
from autoresearch.audit.random_arm import run_random_arm
from autoresearch.audit.report import write_report
from autoresearch.audit.verify import verify
from autoresearch.campaign.lock import CampaignLock
from autoresearch.commands import SUMMARIES
from autoresearch.commands.common import (
    add_audit_arguments,
    describe_noise,
    opened,
    positive_int,
    run_command,
)
from autoresearch.commands.export import update_live_journal
from autoresearch.commands.prune import add_rule_arguments, print_prune, rule_of
from autoresearch.commands.random_arm import print_random
from autoresearch.commands.verify import add_gate_argument, add_gate_split_argument, print_verify
from autoresearch.splits import Split

# The gates in words, where the audit first names them (issue 59: "runaway gate" was never explained).
GATE_WORDS = {
    "runaway": "a candidate passes when its reseeded mean beats the baseline's by 2 seed-noise units, it is "
    "feasible on every reseed, and no reseed sends a start past the family's runaway bound",
    "paper": "a candidate passes when its reseeded mean beats the baseline's by 2 seed-noise units and it is "
    "feasible on every reseed (the paper's gate)",
}


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "audit",
        help=SUMMARIES["audit"],
        description="Run the credibility audit of a campaign in order: seed noise (only if the family has "
        "none on the splits it has, or with --force), reseeded verification, leave-one-out pruning, the "
        "random-search arm; then write report.md and its figures. Each step is resumable and writes its part "
        "of audit.json. For a family with a sealed test split, every reseed is scored on both splits and the "
        "gate uses the test split.",
        epilog="Example: autoresearch audit --campaign runs/docking-tpe-20250101-120000 --workers 4",
    )
    p.add_argument("--campaign", required=True, help="campaign directory")
    p.add_argument(
        "--force", action="store_true", help="re-measure the seed noise even if the family has one"
    )
    p.add_argument("--noise-seeds", type=positive_int, default=10, help="K for the seed noise (default 10)")
    p.add_argument("--top", type=positive_int, default=3, help="candidates to reseed (default 3)")
    p.add_argument("--seeds", type=positive_int, default=10, help="fresh seeds per verification (default 10)")
    p.add_argument("--count", type=positive_int, help="random-arm experiments (default: the campaign's)")
    p.add_argument("--matched-range", action="store_true", help="also run a matched-range random arm")
    p.add_argument("--arm", action="append", type=Path, default=[], help="another arm to plot (repeatable)")
    add_gate_split_argument(p)
    add_gate_argument(p)
    add_rule_arguments(p)
    add_audit_arguments(p)
    return p


def run(args: argparse.Namespace) -> int:
    def body(executor) -> None:
        with CampaignLock(args.campaign, "audit"):
            steps(executor)

    def steps(executor) -> None:
        # Each step re-opens the campaign: the previous one may have written the family's
        # seed_noise or best.
        campaign = opened(args.campaign, args)
        family = campaign.family
        split = gate_split(family, args.gate_split)
        measured = has_noise(family, Split.SEARCH) and (
            not family.has_test_split or has_noise(family, Split.TEST)
        )
        stale = stale_noise(family) if measured else []
        if measured and not args.force and not stale:
            noise = record_existing_noise(campaign)
            print(f"[noise] from the family's ledger: {describe_noise(noise)}")
        else:
            if stale and not args.force:
                print(
                    f"[noise] the family's seed noise was measured on another version of it ({'; '.join(stale)}): measuring again"
                )
            noise = measure_noise(family, executor, k=args.noise_seeds, campaign=campaign)
            print(f"[noise] measured: {describe_noise(noise)}")
        gate = GATE_WORDS.get(args.gate, f"the {args.gate} gate")
        print(f"[verify] gated on the {split} split: {gate}")
        campaign = open_campaign(args.campaign)
        print_verify(
            verify(campaign, executor, top=args.top, n_seeds=args.seeds, split=split, gate=args.gate)
        )
        print(f"[prune, {rule_of(args).name} rule]")
        print_prune(prune(open_campaign(args.campaign), executor, rule=rule_of(args)))
        for matched in (False, True) if args.matched_range else (False,):
            print("[random" + (", matched range]" if matched else "]"))
            print_random(
                run_random_arm(
                    open_campaign(args.campaign),
                    executor,
                    count=args.count,
                    matched_range=matched,
                    split=split,
                )
            )
        print(f"[report] {write_report(Path(args.campaign), arms=args.arm)}")
        journal = update_live_journal(Path(args.campaign))
        if journal:
            print(f"[optuna-journal] {journal}")

    return run_command("audit", args, body)
