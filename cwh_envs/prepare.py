"""What a family's prepare.py runs: build (--warm-cache) or verify (--check) every data set its
train.py can read.

The family states those sets itself, as a :class:`DataNeeds` built from its own train.py constants
(so the two cannot disagree; :func:`import_train` imports it, naming a missing extra), and passes it
to :func:`main`: this library never reads a family's files. The sets live in the cwh_envs cache
($CWH_ENVS_CACHE, else ~/.cache/cwh_envs). A family's report.py loads its own train.py with
:func:`load_train`, and says what a saved run scored, split by split, with :func:`scored_per_split`.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import textwrap
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from cwh_envs import datasets, splits


def import_train(needs: dict[str, str], extras: str):
    """A family's prepare.py's own train.py (``import train``: the script's directory is first on
    sys.path). Where a module it trains with is missing (``needs``: module -> what it is called), the
    script exits naming the extras that bring it, rather than with a traceback."""
    try:
        return importlib.import_module("train")
    except ModuleNotFoundError as err:
        if err.name not in needs:
            raise
        names = " and ".join(needs.values())
        missing = "which is not installed" if len(needs) == 1 else "which are not both installed"
        sys.exit(f"this family trains with {names}, {missing}: pip install 'cwh-autoresearch[{extras}]'")


def load_train(family_dir: str | Path):
    """A family's own train.py as a module, for its report.py (its run is guarded by ``__main__``)."""
    family_dir = Path(family_dir).resolve()
    spec = importlib.util.spec_from_file_location(f"{family_dir.name}_train", family_dir / "train.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


SPLIT_WORDS = {"search": "search-split", "test": "sealed test-split"}


def scored_per_split(record: dict, train, words: str) -> str:
    """What a saved run scored on each split its FINAL_METRIC object holds, each named with its
    number of starts (``train.N_EVAL``, ``train.N_TEST``): a figure must never print one split's
    number beside the other's count. ``words`` formats one split's metrics (``str.format_map``); a
    record without ``splits`` is its own split's."""
    splits = record.get("splits") or {record.get("eval_split", "search"): record}
    counts = {"search": train.N_EVAL, "test": getattr(train, "N_TEST", None)}
    return "; ".join(
        f"{words.format_map(splits[name])} on the {counts[name]} {SPLIT_WORDS[name]} starts"
        for name in SPLIT_WORDS
        if name in splits
    )


TITLE_WIDTH = 110  # characters a report figure's title is wrapped at, so that no line is cut


def policy_title(task: str, record: dict, train, words: str) -> str:
    """A report figure's title: what the promoted policy scored on each split (:func:`scored_per_split`),
    wrapped to whole lines; no run id (an internal name the reader cannot look up)."""
    return textwrap.fill(
        f"{task}, the promoted policy: " + scored_per_split(record, train, words), TITLE_WIDTH
    )


def legend_starts(ax, starts: np.ndarray, final: np.ndarray, colors, where: str = "upper right") -> None:
    """A legend naming each start flown (its colour, how far out it began, where the policy ended)
    and the two line styles: the policy solid, the expert dashed."""
    from matplotlib.lines import Line2D

    handles = [
        Line2D(
            [],
            [],
            color=color,
            lw=1.6,
            label=f"start {i + 1}: {np.linalg.norm(x0[:3]):.0f} m out, ended {d:.2g} m off",
        )
        for i, (x0, d, color) in enumerate(zip(starts, final, colors, strict=False))
    ]
    handles += [
        Line2D([], [], color="gray", lw=1.6, label="policy (solid)"),
        Line2D([], [], color="gray", lw=1.0, ls="--", label="expert (dashed)"),
    ]
    ax.legend(handles=handles, fontsize=7, loc=where)


@dataclass(frozen=True)
class DataNeeds:
    """Every data set a family's train.py can read, for any configuration of its search space."""

    task: str  # "rendezvous" or "docking"
    problem: object  # the family's RendezvousProblem / DockingProblem
    n_eval: int  # held-out evaluation starts: the search split
    pool_demos: int | None = None  # the training pool: the N_DEMOS upper bound (None: no demonstrations)
    data_seed: int = 0  # the demonstration pools' seed
    obs_dim: int | None = None  # the observation width the demonstrations must have (None: unread)
    pool_recovery: int | None = None  # the recovery pool (docking's augmentation knob), if any
    n_test: int | None = None  # the sealed test split (train.py --eval-split test), if any
    # docking: other keep-out standoffs the demonstrations may keep (a family's EXPERT_MARGIN); each
    # adds a training pool and a recovery pool built with the problem at that margin
    expert_margins: tuple[float, ...] = ()
    start_pool: int | None = None  # screened starts an RL family's training envs reset from, if any


class DataSet(NamedTuple):
    """One set of :func:`required_sets`: ``load(build)`` returns (starts, goals, demos or None); False
    raises datasets.CacheMiss rather than build. ``seconds`` is a rough build time."""

    description: str
    size: int
    load: Callable[[bool], tuple]
    seconds: float


def split_ids(needs: DataNeeds) -> dict[str, str]:
    """What the family's family.json pins as ``split_ids``: the identity of the first ``n_eval`` (and
    ``n_test``) starts of the shipped splits of its problem (cwh_envs.splits). A problem with no
    shipped split has none to pin: a ValueError says so."""
    sizes = {"search": needs.n_eval, **({"test": needs.n_test} if needs.n_test is not None else {})}
    ids = {}
    for split, n in sizes.items():
        shipped = splits.shipped_split(needs.task, needs.problem, split)
        if shipped is None:
            raise ValueError(f"no {split} split ships for this family's {needs.task} problem")
        ids[split] = splits.split_identity(*shipped.first(n))
    return ids


def required_sets(needs: DataNeeds) -> list[DataSet]:
    """Every set ``needs`` names: the demonstration pools, the splits, the recovery pools, the start pool."""
    task, problem, seed = needs.task, needs.problem, needs.data_seed
    solve = build_estimate(needs)

    def split(name, n):
        def held_out(build):
            demos = datasets.evaluation_set(task, n, problem=problem, split=name, build=build)
            return demos.starts, demos.goals, demos

        return DataSet(f"{task} {name} split: evaluation_set(n={n}, split={name!r})", n, held_out, n * solve)

    margins = [m for m in needs.expert_margins if m != problem.margin]
    experts = [("", problem), *((f" (expert margin {m} m)", problem.replace(margin=m)) for m in margins)]
    if needs.pool_demos is None:  # a learner without demonstrations (an RL family): no pools
        experts = []
    pools, recoveries = [], []
    for where, expert in experts:

        def pool(build, expert=expert):
            demos = datasets.demonstrations(task, needs.pool_demos, seed=seed, problem=expert, build=build)
            return demos.starts, demos.goals, demos

        def recovery(build, expert=expert):
            demos = datasets.recovery_demonstrations(
                task, needs.pool_recovery, seed=seed, problem=expert, build=build
            )
            return demos.starts, demos.goals, demos

        call = f"demonstrations(n={needs.pool_demos}, seed={seed})"
        pools.append(
            DataSet(f"{task} training pool{where}: {call}", needs.pool_demos, pool, needs.pool_demos * solve)
        )
        if needs.pool_recovery is not None:
            call = f"recovery_demonstrations(n={needs.pool_recovery}, seed={seed})"
            n = needs.pool_recovery
            recoveries.append(DataSet(f"{task} recovery pool{where}: {call}", n, recovery, n * solve))
    sets = [*pools, split("search", needs.n_eval)]
    if needs.n_test is not None:
        sets.append(split("test", needs.n_test))
    if needs.start_pool is not None:

        def starts(build):
            pool = datasets.start_pool(task, needs.start_pool, problem, build=build)
            return pool.starts, pool.goals, None

        n = needs.start_pool
        sets.append(
            DataSet(f"{task} start pool: start_pool(n={n})", n, starts, n * SECONDS_PER_SCREENED_START)
        )
    return [*sets, *recoveries]


def inconsistency(needs: DataNeeds, expected: int, starts, goals, demos) -> str | None:
    """Why a loaded set does not match what the family expects, or None (``demos`` None: a start pool)."""
    if starts.shape != (expected, 6) or goals.shape != (expected, 3):
        return f"holds {len(starts)} starts, expected {expected}"
    if not (np.all(np.isfinite(starts)) and np.all(np.isfinite(goals))):
        return "non-finite starts or goals"
    if demos is None:
        return None
    width = demos.observations.shape[1] if needs.obs_dim is None else needs.obs_dim  # None: any width
    if demos.observations.shape[1] != width or len(demos.actions) != len(demos.observations):
        return f"observations have shape {demos.observations.shape}, expected (M, {width})"
    finite = np.all(np.isfinite(demos.observations)) and np.all(np.isfinite(demos.actions))
    if not finite or np.abs(demos.actions).max() > needs.problem.u_max * (1 + 1e-6):
        return "non-finite observations or thrust outside the box"
    if set(np.unique(demos.episode)) != set(range(expected)):
        return "episode indices do not cover every trajectory"
    return None


def shared_starts(sealed: np.ndarray, other: np.ndarray) -> int:
    """How many starts (rows of (N, 6)) of ``sealed`` also occur, bit for bit, in ``other``."""
    seen = {row.tobytes() for row in np.ascontiguousarray(other, dtype=np.float64)}
    return sum(row.tobytes() in seen for row in np.ascontiguousarray(sealed, dtype=np.float64))


def check(needs: DataNeeds) -> int:
    failures, sets, loaded = [], required_sets(needs), {}
    started = time.perf_counter()
    for description, expected, load, _ in sets:
        try:
            starts, goals, demos = load(build=False)
            reason = inconsistency(needs, expected, starts, goals, demos)
            loaded[description] = starts
        except datasets.CacheMismatch as err:  # present, but it fails its checks: rebuilt by --warm-cache
            reason = f"fails its checks ({err})"
        except datasets.CacheMiss:
            reason = "missing"
        if reason:
            failures.append(f"{description}: {reason}")
    # The sealed split must share no start with anything a run trains or selects on.
    sealed = [d for d in loaded if " test split" in d]
    for description in sealed:
        for other, starts in loaded.items():
            shared = other != description and shared_starts(loaded[description], starts)
            if shared:
                failures.append(f"{description}: shares {shared} start(s) with the {other}")
    where = datasets.cache_directory()
    if failures:
        print(f"prepare.py --check: the cache in {where} is incomplete:", file=sys.stderr)
        for failure in failures:
            print(f"  - {failure}", file=sys.stderr)
        print("run `python prepare.py --warm-cache` to build it", file=sys.stderr)
        return 1
    elapsed = time.perf_counter() - started
    print(f"prepare.py --check: all {len(sets)} sets present in {where} ({elapsed:.1f} s)")
    return 0


# Seconds of expert solving per trajectory of a set, measured on this project's 2-core machine with
# one build running (the constrained expert's SCP solves a second-order-cone program per iteration).
SECONDS_PER_TRAJECTORY = {"rendezvous": 3e-4, "docking": 5e-3, "docking, path-constrained": 1.5}


# Seconds to screen one start of a start pool (no expert solve): 65,536 docking starts took 2.5 s here.
SECONDS_PER_SCREENED_START = 4e-5


def build_estimate(needs: DataNeeds) -> float:
    """Rough seconds to build one expert trajectory for ``needs`` (screening included)."""
    kind = needs.task
    if getattr(needs.problem, "speed_limit", None) is not None or getattr(
        needs.problem, "approach_cone", None
    ):
        kind = "docking, path-constrained"
    return SECONDS_PER_TRAJECTORY[kind]


def warm(needs: DataNeeds) -> int:
    """Build every missing set, saying up front what will be built and about how long it takes."""
    sets = required_sets(needs)
    missing = []
    for data in sets:
        try:
            data.load(build=False)
        except datasets.CacheMiss:
            missing.append(data)
    if missing:
        total = sum(data.seconds for data in missing)
        print(
            f"to build: {len(missing)} of {len(sets)} data sets, about {_duration(total)} in all:", flush=True
        )
        for data in missing:
            print(f"  - {data.description}: about {_duration(data.seconds)}", flush=True)
    for data in sets:
        started = time.perf_counter()
        data.load(build=True)
        print(f"ready: {data.description} ({time.perf_counter() - started:.1f} s)", flush=True)
    return check(needs)


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min"


def main(needs: DataNeeds, description: str) -> int:
    """The prepare.py command line for a family that needs ``needs``."""
    parser = argparse.ArgumentParser(description=description.splitlines()[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--warm-cache", action="store_true", help="build every set (slow, once)")
    mode.add_argument("--check", action="store_true", help="verify the cache without building (seconds)")
    args = parser.parse_args()
    return warm(needs) if args.warm_cache else check(needs)
