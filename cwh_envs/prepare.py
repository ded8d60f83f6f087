"""What a family's prepare.py runs: build (--warm-cache) or verify (--check) every data set its
train.py can read.

The sets are the ones train.py loads for any configuration in its search space (the pool size,
data seed and evaluation size are read from train.py itself, so the two cannot disagree). They
live in the cwh_envs cache ($CWH_ENVS_CACHE, else ~/.cache/cwh_envs). A family's prepare.py is
``sys.exit(main(Path(__file__).parent, __doc__))``; its report.py reads train.py with
:func:`load_train`.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

from cwh_envs import datasets


def load_train(family_dir: str | Path):
    """The family's train.py as a module (its run is guarded by ``__main__``)."""
    family_dir = Path(family_dir).resolve()
    spec = importlib.util.spec_from_file_location(f"{family_dir.name}_train", family_dir / "train.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def required_sets(train) -> list[tuple[str, int, object]]:
    """(description, trajectories, loader) per set.

    A loader takes ``build`` (False: raise datasets.CacheMiss rather than build) and returns
    (starts, goals, demos or None).
    """
    task, problem = train.TASK, train.PROBLEM

    def pool(build):
        demos = datasets.demonstrations(
            task, train.POOL_DEMOS, seed=train.DATA_SEED, problem=problem, build=build
        )
        return demos.starts, demos.goals, demos

    def held_out(build):
        return (*datasets.evaluation_starts(task, train.N_EVAL, problem=problem, build=build), None)

    call = f"demonstrations(n={train.POOL_DEMOS}, seed={train.DATA_SEED})"
    sets = [
        (f"{task} training pool: {call}", train.POOL_DEMOS, pool),
        (f"{task} evaluation starts: evaluation_starts(n={train.N_EVAL})", train.N_EVAL, held_out),
    ]
    if hasattr(train, "POOL_RECOVERY"):  # families with a recovery-augmentation knob (docking)

        def recovery(build):
            demos = datasets.recovery_demonstrations(
                task, train.POOL_RECOVERY, seed=train.DATA_SEED, problem=problem, build=build
            )
            return demos.starts, demos.goals, demos

        call = f"recovery_demonstrations(n={train.POOL_RECOVERY}, seed={train.DATA_SEED})"
        sets.append((f"{task} recovery pool: {call}", train.POOL_RECOVERY, recovery))
    return sets


def inconsistency(train, expected: int, starts, goals, demos) -> str | None:
    """Why a loaded set does not match what train.py expects, or None."""
    if starts.shape != (expected, 6) or goals.shape != (expected, 3):
        return f"holds {len(starts)} starts, expected {expected}"
    if not (np.all(np.isfinite(starts)) and np.all(np.isfinite(goals))):
        return "non-finite starts or goals"
    if demos is None:
        return None
    if demos.observations.shape[1] != train.OBS_DIM or len(demos.actions) != len(demos.observations):
        return f"observations have shape {demos.observations.shape}, expected (M, {train.OBS_DIM})"
    finite = np.all(np.isfinite(demos.observations)) and np.all(np.isfinite(demos.actions))
    if not finite or np.abs(demos.actions).max() > train.PROBLEM.u_max * (1 + 1e-6):
        return "non-finite observations or thrust outside the box"
    if set(np.unique(demos.episode)) != set(range(expected)):
        return "episode indices do not cover every trajectory"
    return None


def check(train) -> int:
    failures, sets = [], required_sets(train)
    started = time.perf_counter()
    for description, expected, load in sets:
        try:
            reason = inconsistency(train, expected, *load(build=False))
        except datasets.CacheMiss:
            reason = "missing"
        if reason:
            failures.append(f"{description}: {reason}")
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


def warm(train) -> int:
    for description, _, load in required_sets(train):
        started = time.perf_counter()
        load(build=True)
        print(f"ready: {description} ({time.perf_counter() - started:.1f} s)", flush=True)
    return check(train)


def main(family_dir: str | Path, description: str) -> int:
    """The prepare.py command line for the family in ``family_dir``."""
    parser = argparse.ArgumentParser(description=description.splitlines()[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--warm-cache", action="store_true", help="build every set (slow, once)")
    mode.add_argument("--check", action="store_true", help="verify the cache without building (seconds)")
    args = parser.parse_args()
    train = load_train(family_dir)
    return warm(train) if args.warm_cache else check(train)
