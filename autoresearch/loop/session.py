"""One session of one campaign: what ``autoresearch loop`` runs on a campaign directory, and what each
repeat of a group runs in a process of its own (:func:`resume`).

A campaign's settings live in its campaign.json (:data:`DEFAULTS`, the flags a resume may give
again); :func:`build_loop` makes its family, proposer and loop settings from them, and :func:`run`
runs the loop under the campaign's lock, says how it ended and returns the exit status.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from autoresearch import provenance
from autoresearch.campaign import (
    Campaign,
    CampaignError,
    CampaignMeta,
    CampaignPaths,
    CampaignState,
    portable_path,
)
from autoresearch.campaign.lock import CampaignLock
from autoresearch.campaign.meta import EVAL_ALLOWANCE
from autoresearch.execution.executors import Executor, ExecutorError, LocalExecutor
from autoresearch.exits import error_exit
from autoresearch.extras import require
from autoresearch.family import Family, FamilyError, resolve_family
from autoresearch.journal import JournalError
from autoresearch.loop.banner import closest_miss, start_banner
from autoresearch.loop.context import shown_registry
from autoresearch.loop.live import make_view
from autoresearch.loop.orchestrator import LoopSettings, Orchestrator
from autoresearch.loop.stopping import Budgets
from autoresearch.loop.warm_start import WarmStart
from autoresearch.proposers import DEFAULT_SPACE, KEY_FREE, make_proposer
from autoresearch.proposers.base import Proposer
from autoresearch.proposers.enqueued import EnqueuedProposer, full_queue
from autoresearch.proposers.llm_options import LLM_DEFAULTS, llm_kwargs
from autoresearch.verdicts import reaches_target

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
    "time_budget": None,  # training seconds each run is granted (AUTORESEARCH_TIME_BUDGET); None: none
    "eval_allowance": EVAL_ALLOWANCE,  # a budgeted run's hard limit is its budget plus this
    "stop_at_target": False,  # the paper's rule: reaching the family's target ends the campaign
    "random_arm": None,
    "warm_start": None,  # earlier campaigns of the family whose finished runs the proposer starts from
    "enqueue": None,
    "space": None,  # key-free proposers: None searches DEFAULT_SPACE[proposer]
    "off_at_zero": False,  # tpe and gp: a real range starting at 0 gets an off switch (optuna_space)
    "protocol": None,  # one of the family's declared protocols (Family.under_protocol); None: its whole space
    "workers": 1,
    "executor": "local",
    "early_stop": "none",
    "optuna_journal": None,  # also write each run to this Optuna journal file (optuna-dashboard)
    **LLM_DEFAULTS,
}
API_KEYS = {"anthropic": "ANTHROPIC_API_KEY", "openai": "OPENAI_API_KEY"}
# What a session refuses with one line and exit status 2 rather than a traceback.
REFUSED = (FamilyError, CampaignError, ValueError, ImportError, RuntimeError, OSError)


class UsageError(Exception):
    """Bad settings (flags, or campaign.json); the message is shown as is, exit code 2."""


def default_proposer() -> str:
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


def settings_of(given: dict[str, Any], saved: dict[str, Any]) -> dict[str, Any]:
    """A campaign's settings: the defaults, then what campaign.json saved, then the flags ``given``."""
    # A campaign saved before the target became a report line stopped at it: it resumes as it ran.
    legacy = {"stop_at_target": True} if saved and "stop_at_target" not in saved else {}
    settings = {**DEFAULTS, **legacy, **saved, **given}
    for path in ("random_arm", "optuna_journal"):
        if settings[path] is not None:
            settings[path] = portable_path(settings[path])
    if settings["warm_start"] is not None:
        settings["warm_start"] = [portable_path(p) for p in settings["warm_start"]]
    return settings


def resumed(
    root: Path,
    family: Family | None = None,
    given: dict[str, Any] | None = None,
    strict: bool = False,
    proposer: str | None = None,
) -> CampaignMeta:
    """campaign.json of the campaign in ``root`` continued by a new session: its proposer (``proposer``,
    when given, must be it), its family (``family``, where it is now, else where campaign.json says)
    checked to be the one it ran, every provenance difference listed on stderr (refused when
    ``strict``), the flags ``given`` over its settings."""
    if not CampaignPaths(root).campaign_json.exists():
        raise UsageError(f"{root}: no campaign.json; not a campaign directory")
    meta = CampaignMeta.read(root)
    if proposer and proposer != meta.proposer:
        raise UsageError(f"this campaign's proposer is {meta.proposer}; a campaign cannot change it")
    family = family or meta.open_family(root)
    meta.check_family(family, root)  # refused before any provenance is listed
    recorded = [("campaign.json, first session", meta.provenance)]
    for line in provenance.report(recorded, provenance.collect(family.path), strict):
        print(f"[provenance] {line}", file=sys.stderr)
    return meta.resumed(family, settings_of(given or {}, meta.settings))


def build_loop(meta: CampaignMeta) -> tuple[Family, Proposer, LoopSettings]:
    """What a campaign.json runs: its family, its proposer and the loop's settings."""
    settings = meta.settings
    _check_key(meta.proposer, settings)
    family = resolve_family(meta.family).under_protocol(settings["protocol"])
    warm = _warm_start(meta.proposer, settings, family)
    proposer = make_proposer(
        meta.proposer,
        shown_registry(family.search_registry(), settings["blind"]),
        seed=settings["seed"],
        model=settings["model"],
        base_url=settings["base_url"],
        space=settings["space"],
        off_at_zero=settings["off_at_zero"],
        prior=warm.outcomes if warm and meta.proposer in KEY_FREE else (),
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
            stop_at_target=settings["stop_at_target"],
        ),
        blind=settings["blind"],
        timeout_per_run=meta.run_timeout,
        random_arm=Path(settings["random_arm"]) if settings["random_arm"] else None,
        workers=settings["workers"],
        early_stop=settings["early_stop"],
        time_budget=meta.time_budget,
        warm_start=warm,
    )
    return family, proposer, loop


def _warm_start(proposer: str, settings: dict[str, Any], family: Family) -> WarmStart | None:
    """The earlier runs of ``--warm-start``, matched against the space the proposer searches."""
    if not settings["warm_start"]:
        return None
    if proposer == "random":
        raise UsageError("--warm-start: the random proposer draws independently of every earlier run")
    space = family.space
    if proposer in KEY_FREE:
        space = space.searched(settings["space"] or DEFAULT_SPACE[proposer])
    return WarmStart.load(settings["warm_start"], family, space)


def executor_of(settings: dict[str, Any]) -> Executor:
    """The executor a campaign's settings choose, with Ray's defaults (the cluster in RAY_ADDRESS, else
    a local instance)."""
    if settings["executor"] != "ray":
        return LocalExecutor(settings["workers"])
    from autoresearch.execution.ray_executor import RayExecutor  # imports ray

    return RayExecutor(workers=settings["workers"])


def _on_sigterm(signum, frame):
    raise KeyboardInterrupt  # unwinds through the runner, which kills the training process group


def _feed(settings: dict[str, Any], family: Family, root: Path):
    """The live Optuna journal of --optuna-journal (optuna imported only then), or None."""
    if not settings["optuna_journal"]:
        return None
    from autoresearch.optuna_journal import LiveFeed

    return LiveFeed(settings["optuna_journal"], family, Campaign(root))


def run(
    root: Path,
    meta: CampaignMeta,
    plain: bool,
    make_executor: Callable[[dict[str, Any]], Executor] = executor_of,
) -> int:
    """Run the loop of the campaign in ``root`` as ``meta`` (written there first) says, one process at a
    time; print how it ended and return the exit status (0, 1 for a failed prepare.py --check, 130 when
    interrupted, 2 or 3 with one line on stderr)."""
    executor = None
    try:
        family, proposer, loop = build_loop(meta)
        family.check_outside(root)
        lock = CampaignLock(root, "loop", create=True).acquire()  # one process per campaign
        if loop.warm_start is not None:  # what this session started from: the campaigns may grow
            meta = meta.noted("warm_start", loop.warm_start.to_json())
        meta.write(root)
        executor = make_executor(meta.settings)
        feed = _feed(meta.settings, family, root)
    except (UsageError, *REFUSED) as err:
        return error_exit("loop", err)
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    resume_hint = f"autoresearch loop --resume --campaign {root}"
    print("\n".join(start_banner(meta, family, loop)), flush=True)
    try:
        view = make_view(family.metric, plain, meta.proposer not in KEY_FREE, meta.run_timeout)
        outcome = Orchestrator(
            family, proposer, root, loop, view=view, executor=executor, on_record=feed
        ).run()
    except KeyboardInterrupt:
        print(f"\ninterrupted; campaign: {root}\nresume with: {resume_hint}", file=sys.stderr)
        return 130
    except (CampaignError, JournalError, ExecutorError, OSError) as err:  # OSError: e.g. the disk is full
        return error_exit("loop", err, resume_hint)
    finally:
        signal.signal(signal.SIGTERM, previous)
        executor.close()
        lock.release()
    best = outcome.best
    state = Campaign(root).state(family)
    best_text = (
        f"{best.metric:.6g} ({best.run_id})" if best else f"none: no feasible run; {closest_miss(state)}"
    )
    print(f"campaign: {root}")
    print(
        f"  ended: {outcome.status}"
        + (f" ({outcome.trigger})" if outcome.trigger else "")
        + f": {outcome.reason}"
    )
    print(
        f"  iterations: {outcome.iterations}, successful runs: {outcome.n_runs_ok}, best {family.metric}: {best_text}"
    )
    if family.target is not None:
        print(f"  target {family.target:g}: {_target_report(state)}")
    if outcome.status == "prepare_failed":
        print(f"  fix the family, then: {resume_hint}")
        return 1
    return 0


def _target_report(state: CampaignState) -> str:
    """Whether, and when, the campaign's best reached the family's target: a report line, not a stop
    (unless ``--stop-at-target``)."""
    family = state.family
    reached = [
        r for r in state.records if r.ran and reaches_target(r.best_so_far, family.target, family.direction)
    ]
    if not reached:
        return "not reached"
    return f"first reached at iteration {reached[0].iteration} ({reached[0].run_id})"


def resume(root: str | Path) -> int:
    """Continue the campaign in ``root`` as it was started (``autoresearch loop --resume --campaign
    ROOT --plain``): what each repeat of a group runs, in a process of its own."""
    root = Path(root)
    try:
        meta = resumed(root)
    except (UsageError, *REFUSED) as err:
        return error_exit("loop", err)
    return run(root, meta, plain=True)
