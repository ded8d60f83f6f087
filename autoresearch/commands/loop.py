"""``autoresearch loop``: run (or resume) one campaign of the agent loop on a family."""

from __future__ import annotations

import argparse
import os
import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from autoresearch import provenance
from autoresearch.campaign import Campaign, CampaignError, CampaignMeta, CampaignPaths, portable_path, session
from autoresearch.commands import SUMMARIES
from autoresearch.commands.common import add_executor_arguments, error_exit, make_executor
from autoresearch.execution.executors import Executor
from autoresearch.extras import require
from autoresearch.family import Family, FamilyError, resolve_family
from autoresearch.journal import JournalError, read_json
from autoresearch.loop import repeats
from autoresearch.loop.campaign_lock import LOCK_FILE, CampaignLock
from autoresearch.loop.context import shown_registry
from autoresearch.loop.dry_run import dry_run
from autoresearch.loop.early_stop import EARLY_STOP
from autoresearch.loop.live import make_view
from autoresearch.loop.orchestrator import LoopSettings, Orchestrator
from autoresearch.loop.stopping import Budgets
from autoresearch.proposers import DEFAULT_SPACE, KEY_FREE, PROPOSERS, make_proposer
from autoresearch.proposers.base import Proposer
from autoresearch.proposers.enqueued import EnqueuedProposer, full_queue, read_queue
from autoresearch.proposers.llm_options import LLM_DEFAULTS, add_llm_arguments, llm_kwargs
from autoresearch.space import SPACES

# Settings a campaign keeps in campaign.json; on --resume, flags given again override them.
DEFAULTS: dict[str, Any] = {
    "model": None,
    "base_url": None,
    "blind": False,
    "max_iters": 50,
    "max_runs": None,
    "max_seconds": None,
    "max_cost_usd": 10.0,
    "max_failures": 3,
    "plateau_window": 6,
    "plateau_kappa": 1.0,
    "seed": 0,
    "timeout_per_run": 3600.0,
    "random_arm": None,
    "enqueue": None,
    "space": None,  # key-free proposers: None searches DEFAULT_SPACE[proposer]
    "workers": 1,
    "executor": "local",
    "early_stop": "none",
    "optuna_journal": None,  # also write each run to this Optuna journal file (optuna-dashboard)
    **LLM_DEFAULTS,
}
API_KEYS = {"anthropic": "ANTHROPIC_API_KEY", "openai": "OPENAI_API_KEY"}


class UsageError(Exception):
    """Bad command-line input; the message is shown as is, exit code 2."""


def _positive(kind):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a positive {kind.__name__}, got {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"expected a positive {kind.__name__}, got {text!r}")
        return value

    return parse


def _queue_file(path: str) -> list[dict[str, Any]]:
    try:
        return read_queue(path)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "loop",
        help=SUMMARIES["loop"],
        description="Run the agent loop on a family: propose, patch, run, record, until a stopping trigger fires.",
        epilog="Example: autoresearch loop --family docking --proposer tpe --max-iters 30",
    )
    p.add_argument("--family", help="family name (families/<name>) or family directory")
    p.add_argument("--proposer", choices=PROPOSERS, help="default: anthropic when ANTHROPIC_API_KEY is set")
    p.add_argument("--model", help="LLM model name (LLM proposers)")
    p.add_argument("--base-url", help="OpenAI-compatible endpoint (openai proposer)")
    p.add_argument(
        "--blind", action="store_true", default=None, help="blind mode: no target, baseline or best shown"
    )
    p.add_argument(
        "--max-iters", type=_positive(int), help=f"iteration cap (default {DEFAULTS['max_iters']})"
    )
    p.add_argument("--max-runs", type=_positive(int), help="cap on successful runs")
    p.add_argument("--max-seconds", type=_positive(float), help="wall-clock budget of the loop")
    p.add_argument(
        "--max-cost-usd", type=_positive(float), help=f"LLM spend cap (default {DEFAULTS['max_cost_usd']})"
    )
    p.add_argument(
        "--max-failures", type=_positive(int), help="consecutive failed/invalid iterations (default 3)"
    )
    p.add_argument(
        "--plateau-window", type=_positive(int), help="plateau window in successful runs (default 6)"
    )
    p.add_argument("--plateau-kappa", type=_positive(float), help="plateau margin in noise units (default 1)")
    p.add_argument("--seed", type=int, help="seed of the proposer (runs train at the family's default_seed)")
    p.add_argument(
        "--timeout-per-run", type=_positive(float), help="wall-clock limit of one run, s (default 3600)"
    )
    p.add_argument("--random-arm", help="a random-search campaign dir whose summary the proposer is shown")
    p.add_argument(
        "--enqueue",
        type=_queue_file,
        metavar="FILE",
        help="JSON object or list of {NAME: value} maps (applied to the baseline) to run first, "
        "like Optuna's enqueue_trial; kept in campaign.json",
    )
    p.add_argument(
        "--space",
        choices=SPACES,
        help="what a key-free proposer searches: every parameter's bounds, or its random_range where "
        "declared (default: "
        + ", ".join(f"{space} for {name}" for name, space in DEFAULT_SPACE.items())
        + "); kept in campaign.json",
    )
    p.add_argument(
        "--campaign", help="campaign directory (default runs/<family>-<proposer>-<YYYYmmdd-HHMMSS>)"
    )
    p.add_argument("--resume", action="store_true", help="continue the campaign in --campaign")
    p.add_argument(
        "--strict-provenance",
        action="store_true",
        help="with --resume: refuse to go on if the Python, a library version, the git commit or a family "
        "file differs from the campaign's first session (otherwise each difference is listed)",
    )
    p.add_argument(
        "--early-stop",
        choices=EARLY_STOP,
        help="stop runs whose PROGRESS curve is worse than the finished runs' (Optuna's MedianPruner or "
        "SuccessiveHalvingPruner); default none",
    )
    p.add_argument(
        "--optuna-journal",
        metavar="PATH",
        help="also write every run, as it is recorded, to this Optuna JournalStorage file, so that "
        "`optuna-dashboard PATH` is a live view of the campaign; kept in campaign.json",
    )
    p.add_argument("--plain", action="store_true", help="one line per iteration even on a terminal")
    p.add_argument(
        "--repeats",
        type=_positive(int),
        help="run N independent campaigns of this arm (proposer seeds seed, seed+1, ...) in "
        "--campaign/repeat-NN/; the execution flags below then apply to the campaigns, each running "
        "one experiment at a time",
    )
    add_executor_arguments(p)
    # One campaign: --workers experiments in flight; kept in campaign.json, so None means "as saved".
    p.set_defaults(workers=None, executor=None)
    add_llm_arguments(p)
    return p


def _default_proposer() -> str:
    if os.environ.get(API_KEYS["anthropic"]):
        return "anthropic"
    raise UsageError(
        "no proposer chosen and ANTHROPIC_API_KEY is not set. Set ANTHROPIC_API_KEY for the anthropic "
        f"proposer, or choose a key-free one: --proposer {' or --proposer '.join(KEY_FREE)}"
    )


def _check_key(proposer: str, settings: dict[str, Any]) -> None:
    key = API_KEYS.get(proposer)
    if key:  # the SDK first: a key is no use without it
        require(proposer, "llm", f"--proposer {proposer}")
    if key and not os.environ.get(key) and not (proposer == "openai" and settings["base_url"]):
        raise UsageError(
            f"--proposer {proposer} needs {key} in the environment; the key-free proposers are {', '.join(KEY_FREE)}"
        )


def _settings(args: argparse.Namespace, saved: dict[str, Any]) -> dict[str, Any]:
    given = {k: getattr(args, k) for k in DEFAULTS if getattr(args, k) is not None}
    settings = {**DEFAULTS, **saved, **given}
    for path in ("random_arm", "optuna_journal"):
        if settings[path] is not None:
            settings[path] = portable_path(settings[path])
    return settings


def _campaign_dir(args: argparse.Namespace, family: Family, proposer: str) -> Path:
    """--campaign, else runs/<family>-<proposer>-<local time>."""
    stamp = datetime.now(timezone.utc).astimezone()
    return Path(args.campaign or f"runs/{family.name}-{proposer}-{stamp:%Y%m%d-%H%M%S}")


def _never_started(root: Path) -> bool:
    """True when ``root`` holds nothing a campaign wrote: empty, or only the lock file (and a
    campaign.json temporary) of a loop killed between taking the lock and writing campaign.json."""
    return all(p.name == LOCK_FILE or p.name.startswith(".campaign.json.") for p in root.iterdir())


def _plan(args: argparse.Namespace) -> tuple[Path, CampaignMeta]:
    """(campaign dir, its campaign.json) for a new or resumed campaign."""
    if args.resume:
        if not args.campaign:
            raise UsageError("--resume needs --campaign DIR")
        root = Path(args.campaign)
        if not CampaignPaths(root).campaign_json.exists():
            raise UsageError(f"{root}: no campaign.json; not a campaign directory")
        meta = CampaignMeta.read(root)
        if args.proposer and args.proposer != meta.proposer:
            raise UsageError(f"this campaign's proposer is {meta.proposer}; a campaign cannot change it")
        # --family may point at the family where it is now; either way it must be the one that ran
        family = resolve_family(args.family) if args.family else meta.open_family(root)
        meta.check_family(family)  # refused before any provenance is listed
        recorded = [("campaign.json, first session", meta.provenance)]
        for line in provenance.report(recorded, provenance.collect(family.path), args.strict_provenance):
            print(f"[provenance] {line}", file=sys.stderr)
        return root, meta.resumed(family, _settings(args, meta.settings))
    if not args.family:
        raise UsageError("--family is required (a name under families/ or a directory)")
    family = resolve_family(args.family)
    proposer = args.proposer or _default_proposer()
    root = _campaign_dir(args, family, proposer)
    if root.exists() and (not root.is_dir() or not _never_started(root)):
        raise UsageError(f"{root} already exists; continue it with --resume --campaign {root}")
    return root, CampaignMeta.new(family, proposer, _settings(args, {}))


def _on_sigterm(signum, frame):
    raise KeyboardInterrupt  # unwinds through the runner, which kills the training process group


def build_loop(meta: CampaignMeta) -> tuple[Family, Proposer, LoopSettings]:
    """What a campaign.json runs: its family, its proposer and the loop's settings."""
    settings = meta.settings
    _check_key(meta.proposer, settings)
    family = resolve_family(meta.family)
    proposer = make_proposer(
        meta.proposer,
        shown_registry(family.registry, settings["blind"]),
        seed=settings["seed"],
        model=settings["model"],
        base_url=settings["base_url"],
        space=settings["space"],
        **llm_kwargs(meta.proposer, settings),
    )
    if settings["enqueue"]:
        queue = full_queue(family.space, family.baseline_config, settings["enqueue"])
        proposer = EnqueuedProposer(queue, proposer, family.space)
    if settings["random_arm"] and not Path(settings["random_arm"]).is_dir():
        raise UsageError(f"--random-arm {settings['random_arm']}: not a directory")
    if settings["workers"] < 1:
        raise UsageError(f"--workers must be >= 1 (got {settings['workers']})")
    loop = LoopSettings(
        proposer_name=meta.proposer,
        budgets=Budgets(
            max_seconds=settings["max_seconds"],
            max_runs=settings["max_runs"],
            max_iters=settings["max_iters"],
            max_failures=settings["max_failures"],
            max_cost_usd=settings["max_cost_usd"],
            plateau_window=settings["plateau_window"],
            plateau_kappa=settings["plateau_kappa"],
        ),
        blind=settings["blind"],
        timeout_per_run=settings["timeout_per_run"],
        random_arm=Path(settings["random_arm"]) if settings["random_arm"] else None,
        workers=settings["workers"],
        early_stop=settings["early_stop"],
    )
    return family, proposer, loop


@contextmanager
def _cluster_for_repeats(executor: Executor) -> Iterator[None]:
    """Under Ray, each repeat's loop (a process of its own) runs its tasks on the group's cluster:
    its address goes to them in RAY_ADDRESS, Ray's own variable, for as long as the group runs."""
    if executor.name != "ray":
        yield
        return
    before = os.environ.get("RAY_ADDRESS")
    os.environ["RAY_ADDRESS"] = executor.address
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("RAY_ADDRESS", None)
        else:
            os.environ["RAY_ADDRESS"] = before


def _feed(settings: dict[str, Any], family: Family, root: Path):
    """The live Optuna journal of --optuna-journal (optuna imported only then), or None."""
    if not settings["optuna_journal"]:
        return None
    from autoresearch.optuna_journal import LiveFeed

    return LiveFeed(settings["optuna_journal"], family, Campaign(root))


def run(args: argparse.Namespace) -> int:
    if args.repeats is not None or (args.campaign and repeats.is_group(args.campaign)):
        return _run_repeats(args)
    executor = None
    try:
        root, meta = _plan(args)
        if args.dry_run:
            return dry_run(meta)
        family, proposer, loop = build_loop(meta)
        family.check_outside(root)
        lock = CampaignLock(root, "loop", create=True).acquire()  # one process per campaign
        meta.write(root)
        executor = make_executor(args, meta.settings["executor"], meta.settings["workers"])
        feed = _feed(meta.settings, family, root)
    except (UsageError, FamilyError, CampaignError, ValueError, ImportError, RuntimeError, OSError) as err:
        return error_exit("loop", err)
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    resume_hint = f"autoresearch loop --resume --campaign {root}"
    try:
        view = make_view(family.metric, args.plain)
        outcome = Orchestrator(
            family, proposer, root, loop, view=view, executor=executor, on_record=feed
        ).run()
    except KeyboardInterrupt:
        print(f"\ninterrupted; campaign: {root}\nresume with: {resume_hint}", file=sys.stderr)
        return 130
    except (CampaignError, JournalError, OSError) as err:  # OSError: e.g. the disk is full
        return error_exit("loop", err, resume_hint)
    finally:
        signal.signal(signal.SIGTERM, previous)
        if executor is not None:
            executor.close()
        lock.release()
    best = outcome.best
    best_text = f"{best.metric:.6g} ({best.run_id})" if best else "none (no feasible run)"
    print(f"campaign: {root}")
    print(
        f"  ended: {outcome.status}"
        + (f" ({outcome.trigger})" if outcome.trigger else "")
        + f": {outcome.reason}"
    )
    print(
        f"  iterations: {outcome.iterations}, successful runs: {outcome.n_runs_ok}, best {family.metric}: {best_text}"
    )
    if outcome.status == "prepare_failed":
        print(f"  fix the family, then: {resume_hint}")
        return 1
    return 0


def _run_repeats(args: argparse.Namespace) -> int:
    """--repeats N: N campaigns of one arm in sub-directories of --campaign (autoresearch/loop/repeats.py)."""
    try:
        if args.resume and not args.campaign:
            raise UsageError("--resume needs --campaign DIR")
        saved = (
            read_json(Path(args.campaign) / repeats.GROUP_FILE)
            if args.campaign and repeats.is_group(args.campaign)
            else {}
        )
        if not (args.family or saved):
            raise UsageError("--family is required (a name under families/ or a directory)")
        family = resolve_family(args.family or saved["family"])
        proposer = args.proposer or saved.get("proposer") or _default_proposer()
        root = _campaign_dir(args, family, proposer)
        # The group's --workers run whole campaigns side by side, each loop on this machine running one
        # run at a time: here, or with --executor ray as a task on the cluster the group connects to.
        settings = {**_settings(args, saved.get("settings", {})), "workers": 1}
        args.workers, args.executor = args.workers or 1, settings["executor"]
        group = repeats.plan_group(
            root,
            family=family,
            proposer=proposer,
            settings=settings,
            repeats=args.repeats,
            session=session(family),
        )
        build_loop(group.tasks[0].meta)  # refuse bad settings before anything runs
        family.check_outside(root)
        lock = CampaignLock(root, "loop", create=True).acquire()
        group.write()
    except (UsageError, FamilyError, CampaignError, ValueError, ImportError, OSError) as err:
        return error_exit("loop", err)
    resume_hint = f"autoresearch loop --resume --campaign {root}"
    try:
        with make_executor(args) as executor, _cluster_for_repeats(executor):
            outcomes = repeats.run_group(group, executor)
    except KeyboardInterrupt:
        print(f"\ninterrupted; group: {root}\nresume with: {resume_hint}", file=sys.stderr)
        return 130
    except (RuntimeError, ValueError, OSError) as err:
        return error_exit("loop", err, resume_hint)
    finally:
        lock.release()
    print(f"group: {root} ({proposer}, {len(outcomes)} repeats, seeds {group.meta['seeds']})")
    for outcome in outcomes:
        print("  " + repeats.describe(outcome, family.metric))
    statuses = {o["status"] for o in outcomes}
    if "error" in statuses:
        return 2
    if "interrupted" in statuses:
        print(f"  resume with: {resume_hint}")
        return 130
    if "prepare_failed" in statuses:
        print(f"  fix the family, then: {resume_hint}")
        return 1
    print(f"  compare with: autoresearch compare {root} <other arms>")
    return 0
