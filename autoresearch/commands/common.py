"""What the audit commands share: the execution flags and one error-to-exit-code policy."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from autoresearch.audit.inputs import AuditError, open_campaign, provenance_report
from autoresearch.executors import Executor, make_executor
from autoresearch.family import FamilyError
from autoresearch.journal import JournalError
from autoresearch.loop.campaign import CampaignError
from autoresearch.loop.runner import interruptible_runs


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def add_provenance_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--strict-provenance",
        action="store_true",
        help="refuse to run if the Python, a library version, the git commit or a family file differs from "
        "what campaign.json and the audit steps already done recorded (otherwise each difference is listed)",
    )


def opened(campaign_dir, args: argparse.Namespace):
    """The campaign, once every provenance difference is listed on stderr (or refused, strict)."""
    campaign = open_campaign(campaign_dir)
    for line in provenance_report(campaign, args.strict_provenance):
        print(f"[provenance] {line}", file=sys.stderr)
    return campaign


def describe_noise(noise: dict) -> str:
    """A family's seed noise in one line, the sealed split's beside the search split's."""
    text = f"{noise['mean']:.6g} +- {noise['std']:.3g} (K={noise['k']})"
    test = noise.get("test")
    return text + (f"; on the test split {test['mean']:.6g} +- {test['std']:.3g}" if test else "")


def run_command(name: str, args: argparse.Namespace, body: Callable[[Executor], None]) -> int:
    """Run ``body`` with the executor the flags choose; errors become one line and exit code 2, and
    SIGINT / SIGTERM stop the runs in flight (they are retried when the command is run again)."""
    try:
        with interruptible_runs(), make_executor(args) as executor:
            body(executor)
    except KeyboardInterrupt:
        print(f"\nautoresearch {name}: interrupted; run the same command again to resume", file=sys.stderr)
        return 130
    except (AuditError, CampaignError, FamilyError, JournalError, RuntimeError, ValueError, OSError) as err:
        print(f"autoresearch {name}: error: {err}", file=sys.stderr)
        return 2
    return 0
