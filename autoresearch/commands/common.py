"""What the commands share: the execution flags, and one error-to-exit-code policy."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from autoresearch.audit.inputs import AuditError, open_campaign, provenance_report
from autoresearch.campaign import CampaignError
from autoresearch.campaign.check import audit_problems
from autoresearch.execution.executors import Executor, LocalExecutor
from autoresearch.execution.processes import interruptible_runs
from autoresearch.exits import EXIT_ERROR, error_exit
from autoresearch.family import FamilyError
from autoresearch.journal import JournalError


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags every command that runs training runs shares."""
    group = parser.add_argument_group("execution")
    group.add_argument("--workers", type=int, default=1, help="runs in flight at once (default 1)")
    group.add_argument("--executor", choices=("local", "ray"), default="local", help="default local")
    group.add_argument("--ray-address", default=None, help="existing Ray cluster; default a local instance")
    group.add_argument("--cpus-per-task", type=float, default=1, help="Ray: CPUs one run reserves")
    group.add_argument(
        "--gpus-per-task", type=float, default=None, help="Ray: GPUs one run reserves (default 1 if any)"
    )
    group.add_argument(
        "--ray-files",
        choices=("ship", "shared"),
        default="ship",
        help="Ray: ship the family to the workers and the run's files back (default), or read and write "
        "them in place on a filesystem every node sees",
    )


def make_executor(args: argparse.Namespace, kind: str | None = None, workers: int | None = None) -> Executor:
    """The executor the flags choose (``kind`` and ``workers`` override theirs, e.g. as a campaign saved
    them); Ray is imported only when chosen."""
    kind, workers = kind or args.executor, workers or args.workers
    if kind != "ray":
        return LocalExecutor(workers)
    from autoresearch.execution.ray_executor import RayExecutor  # imports ray

    return RayExecutor(args.ray_address, workers, args.cpus_per_task, args.gpus_per_task, args.ray_files)


def add_audit_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags every audit step's command shares: provenance, then execution."""
    parser.add_argument(
        "--strict-provenance",
        action="store_true",
        help="refuse to run if the Python, a library version, the git commit or a family file differs from "
        "what campaign.json and the audit steps already done recorded (otherwise each difference is listed)",
    )
    add_executor_arguments(parser)


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


def _unreadable_audit(args: argparse.Namespace) -> str | None:
    """Why the campaign's audit.json cannot be read by the audit steps, or None."""
    for root in (getattr(args, "campaign", None), getattr(args, "budget_from", None)):
        problems = audit_problems(root, shape_only=True) if root and Path(root).is_dir() else []
        if problems:
            return f"{root}: audit.json: {problems[0].what}; see `autoresearch check --campaign {root}`"
    return None


def run_command(name: str, args: argparse.Namespace, body: Callable[[Executor], None]) -> int:
    """Run ``body`` with the executor the flags choose; errors become one line and exit code 2 (3 when
    the disk is full), and SIGINT / SIGTERM stop the runs in flight (they are retried when the command
    is run again)."""
    refusal = _unreadable_audit(args)
    if refusal:
        print(f"autoresearch {name}: error: {refusal}", file=sys.stderr)
        return EXIT_ERROR
    try:
        with interruptible_runs(), make_executor(args) as executor:
            body(executor)
    except KeyboardInterrupt:
        print(f"\nautoresearch {name}: interrupted; run the same command again to resume", file=sys.stderr)
        return 130
    except (AuditError, CampaignError, FamilyError, JournalError, RuntimeError, ValueError, OSError) as err:
        return error_exit(name, err)
    return 0
