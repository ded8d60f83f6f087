"""``autoresearch loop``: run (or resume) one campaign of the agent loop on a family."""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from autoresearch.campaign import CampaignMeta, session
from autoresearch.campaign.group import GroupMeta, is_group, plan_group
from autoresearch.campaign.lock import LOCK_FILE, CampaignLock
from autoresearch.campaign.meta import EVAL_ALLOWANCE
from autoresearch.commands import SUMMARIES
from autoresearch.commands.common import add_executor_arguments, make_executor
from autoresearch.execution.executors import Executor
from autoresearch.exits import error_exit
from autoresearch.family import Family, resolve_family
from autoresearch.loop import repeats
from autoresearch.loop.dry_run import dry_run
from autoresearch.loop.early_stop import EARLY_STOP
from autoresearch.loop.session import (
    DEFAULTS,
    REFUSED,
    UsageError,
    build_loop,
    default_proposer,
    resumed,
    settings_of,
)
from autoresearch.loop.session import (
    run as run_session,
)
from autoresearch.proposers import DEFAULT_SPACE, PROPOSERS
from autoresearch.proposers.enqueued import read_queue
from autoresearch.proposers.llm_options import add_llm_arguments
from autoresearch.space import SPACES


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


def _budget(text: str) -> float:
    """--time-budget: seconds of training, 0 for none (a negative or non-finite budget is refused)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a number of seconds >= 0 (0: no budget), got {text!r}")
    return value


def _queue_file(path: str) -> list[dict[str, Any]]:
    try:
        return read_queue(path)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "loop",
        help=SUMMARIES["loop"],
        description="Run the agent loop on a family: propose a configuration, patch it into the editable\n"
        "block of the family's train.py, run it, record the result, until a stopping trigger fires.\n\n"
        "Each run trains for the family's time budget (family.json 'time_budget': 240-600 s for the\n"
        "shipped families) unless --time-budget says otherwise; before the first run the loop prints\n"
        "the budget, the caps and how long the campaign can last. The first iteration runs the\n"
        "family's baseline. Then `autoresearch audit --campaign DIR` reseeds the best runs on the\n"
        "sealed split, prunes their edits and runs a matched random arm.",
        epilog="Examples:\n"
        "  autoresearch loop --family rendezvous --proposer gp --max-runs 12 --workers 2\n"
        "  autoresearch loop --family docking --proposer tpe --max-seconds 3600\n"
        "  autoresearch loop --family docking --proposer anthropic        # ANTHROPIC_API_KEY set\n"
        "  autoresearch loop --resume --campaign runs/docking-gp-20261206-101500",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--family", help="family name (families/<name>) or family directory")
    p.add_argument("--proposer", choices=PROPOSERS, help="default: anthropic when ANTHROPIC_API_KEY is set")
    p.add_argument("--model", help="LLM model name (LLM proposers)")
    p.add_argument("--base-url", help="OpenAI-compatible endpoint (openai proposer)")
    p.add_argument(
        "--blind", action="store_true", default=None, help="blind mode: no target, baseline or best shown"
    )
    p.add_argument(
        "--max-iters",
        type=_positive(int),
        help=f"iteration cap, the baseline's included: 1 runs the baseline only (default {DEFAULTS['max_iters']})",
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
    p.add_argument(
        "--time-budget",
        type=_budget,
        metavar="SECONDS",
        help="training seconds each run is granted (AUTORESEARCH_TIME_BUDGET): a family that honours it "
        "stops training there and is scored as it stands; a run's hard limit is then the budget plus "
        "--eval-allowance. Default: the family's own (family.json 'time_budget'); 0: no budget, each run "
        "limited by --timeout-per-run alone; kept in campaign.json",
    )
    p.add_argument(
        "--eval-allowance",
        type=_positive(float),
        metavar="SECONDS",
        help=f"with --time-budget: seconds a run gets beyond its budget to start, load, score and save "
        f"(default {EVAL_ALLOWANCE:g})",
    )
    p.add_argument(
        "--stop-at-target",
        action="store_true",
        default=None,
        help="the paper's rule: end the campaign when its best reaches the family's target (default: the "
        "target is a report line and the budget is used whole); kept in campaign.json",
    )
    p.add_argument("--random-arm", help="a random-search campaign dir whose summary the proposer is shown")
    p.add_argument(
        "--warm-start",
        nargs="+",
        metavar="CAMPAIGN",
        help="earlier campaigns (or --repeats groups) of the same family: their finished runs are told to "
        "the tpe and gp samplers before the first turn (Optuna's add_trials; a run outside the space "
        "searched now is dropped and counted) and summarised for an LLM proposer; kept in campaign.json",
    )
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
        "--off-at-zero",
        action="store_true",
        default=None,
        help="tpe and gp: each real parameter whose range starts at 0 (dropout, weight decay) also gets an "
        "off switch the sampler models, so that it can propose exactly 0 (a density over a range puts "
        "no mass on its end); kept in campaign.json",
    )
    p.add_argument(
        "--protocol",
        metavar="NAME",
        help="search one of the protocols the family declares (family.json 'protocols'), e.g. 'paper': "
        "its excluded axes held at the baseline, its bounds in place of the declared ones, its limits "
        "(e.g. docking's 'fuel') part of what counts as feasible; kept in campaign.json",
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
        help="stop runs whose PROGRESS curve is worse than the finished runs' (Optuna's MedianPruner, "
        "SuccessiveHalvingPruner or HyperbandPruner: with --proposer tpe, the BOHB-style arm); default none",
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


def _given(args: argparse.Namespace, family: Family | None = None) -> dict[str, Any]:
    """The settings the flags give (None: not given, as saved), and for a new campaign of ``family``
    its default training budget unless the flags decide the run's limit (--time-budget, 0 for none,
    or --timeout-per-run)."""
    given = {k: getattr(args, k) for k in DEFAULTS if getattr(args, k) is not None}
    if given.get("time_budget") == 0:
        given["time_budget"] = None  # explicitly none: it overrides a saved budget on --resume too
    if given.get("time_budget") is not None and "timeout_per_run" in given:
        raise UsageError(
            "--timeout-per-run does not apply with --time-budget: a budgeted run's limit is its budget "
            "plus --eval-allowance"
        )
    if family is not None and family.time_budget and not {"time_budget", "timeout_per_run"} & set(given):
        given["time_budget"] = float(family.time_budget)
    if "eval_allowance" in given and not (given.get("time_budget") or args.resume):
        raise UsageError("--eval-allowance applies under a time budget only (--time-budget, or the family's)")
    return given


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
        # --family may point at the family where it is now; either way it must be the one that ran
        family = resolve_family(args.family) if args.family else None
        return root, resumed(root, family, _given(args), args.strict_provenance, args.proposer)
    if not args.family:
        raise UsageError("--family is required (a name under families/ or a directory)")
    family = resolve_family(args.family)
    proposer = args.proposer or default_proposer()
    root = _campaign_dir(args, family, proposer)
    if root.exists() and (not root.is_dir() or not _never_started(root)):
        raise UsageError(f"{root} already exists; continue it with --resume --campaign {root}")
    return root, CampaignMeta.new(family, proposer, settings_of(_given(args, family), {}))


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


def run(args: argparse.Namespace) -> int:
    if args.repeats is not None or (args.campaign and is_group(args.campaign)):
        return _run_repeats(args)
    try:
        root, meta = _plan(args)
        if args.dry_run:
            return dry_run(meta)
    except (UsageError, *REFUSED) as err:
        return error_exit("loop", err)
    return run_session(root, meta, args.plain, lambda s: make_executor(args, s["executor"], s["workers"]))


def _run_repeats(args: argparse.Namespace) -> int:
    """--repeats N: N campaigns of one arm in sub-directories of --campaign (autoresearch/loop/repeats.py)."""
    try:
        if args.resume and not args.campaign:
            raise UsageError("--resume needs --campaign DIR")
        saved = GroupMeta.read(args.campaign) if args.campaign and is_group(args.campaign) else None
        if not (args.family or saved):
            raise UsageError("--family is required (a name under families/ or a directory)")
        family = resolve_family(args.family) if args.family else saved.open_family(args.campaign)
        proposer = args.proposer or (saved and saved.proposer) or default_proposer()
        root = _campaign_dir(args, family, proposer)
        # The group's --workers run whole campaigns side by side, each loop on this machine running one
        # run at a time: here, or with --executor ray as a task on the cluster the group connects to.
        given = _given(args, None if saved else family)  # a new group gets the family's budget
        settings = {**settings_of(given, saved.settings if saved else {}), "workers": 1}
        args.workers, args.executor = args.workers or 1, settings["executor"]
        group = plan_group(
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
    except (UsageError, *REFUSED) as err:
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
    print(f"group: {root} ({proposer}, {len(outcomes)} repeats, seeds {group.meta.seeds})")
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
