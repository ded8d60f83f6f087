"""``autoresearch noise``: measure a family's seed noise (paper Eq. noisefloor)."""

from __future__ import annotations

import argparse
from pathlib import Path

from autoresearch.audit.inputs import open_campaign
from autoresearch.audit.noise import default_noise_dir, measure_noise
from autoresearch.campaign.lock import CampaignLock
from autoresearch.commands import SUMMARIES
from autoresearch.commands.common import add_executor_arguments, describe_noise, positive_int, run_command
from autoresearch.family import resolve_family
from autoresearch.ledger import LEDGER_FILE


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "noise",
        help=SUMMARIES["noise"],
        description="Run the family's baseline configuration at K fresh seeds and write the mean and the "
        "Bessel-corrected standard deviation of the metric into the family's ledger.json (seed_noise). "
        "Resumable: a re-run skips the seeds already measured.",
        epilog="Example: autoresearch noise --family docking --seeds 10 --workers 2",
    )
    p.add_argument("--family", required=True, help="family name (families/<name>) or family directory")
    p.add_argument("--seeds", type=positive_int, default=10, help="K, the number of seeds (>= 2, default 10)")
    p.add_argument("--campaign", help="also record the noise in this campaign's audit.json (runs go there)")
    p.add_argument("--out", type=Path, help="run directory without --campaign (default runs/noise-<family>)")
    p.add_argument(
        "--timeout-per-run", type=float, default=3600.0, help="without --campaign (default 3600 s)"
    )
    add_executor_arguments(p)
    return p


def run(args: argparse.Namespace) -> int:
    def body(executor) -> None:
        family = resolve_family(args.family)
        out = None if args.campaign else args.out or default_noise_dir(family)
        if out is not None:
            family.check_outside(out)
        # The runs go into the campaign, or into out, a directory of the same kind.
        with CampaignLock(args.campaign or out, "noise", create=out is not None):
            measure(executor, family, out)

    def measure(executor, family, out) -> None:
        campaign = open_campaign(args.campaign) if args.campaign else None
        if campaign is not None and campaign.family.path != family.path:
            raise ValueError(f"{args.campaign} is a campaign of {campaign.family.path}, not of {family.path}")
        noise = measure_noise(
            family,
            executor,
            k=args.seeds,
            campaign=campaign,
            out_dir=out,
            timeout=args.timeout_per_run,
        )
        print(
            f"seed noise of {family.name}: {family.metric} = {describe_noise(noise)}, seeds {noise['seeds']}; "
            f"written to {family.path / LEDGER_FILE}"
        )

    return run_command("noise", args, body)
