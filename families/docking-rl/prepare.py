"""Build (--warm-cache) or verify (--check) every data set this family's train.py can read.

    python prepare.py --warm-cache   # once: the expert solves of the two splits, and the start pool
    python prepare.py --check        # seconds: exit 1 naming whatever is missing or inconsistent

PPO learns from no demonstrations: a run reads the docking family's search and sealed test splits
(the starts it is scored on, with the expert's thrust the fuel is measured against) and the pool of
screened starts its training envs reset from. They are stated here from train.py's own constants
(so the two cannot disagree) and built by cwh_envs.datasets into its cache.
"""

import argparse
import sys
import time

import numpy as np

try:
    import train  # this directory's train.py: its constants (its run is guarded by __main__)
except ModuleNotFoundError as err:  # the base install has neither: say which extras bring them
    if err.name not in ("torch", "stable_baselines3"):
        raise
    sys.exit(
        "this family trains with torch and stable-baselines3, which are not both installed: "
        "pip install 'cwh-autoresearch[families,sb3]'"
    )

from cwh_envs import datasets
from cwh_envs.prepare import shared_starts


def required_sets() -> list[tuple[str, int, object]]:
    """(description, starts, loader) per set; a loader takes ``build`` (False: raise
    datasets.CacheMiss rather than build) and returns the set's starts (N, 6) and goals (N, 3)."""

    def split(name: str, n: int):
        def load(build: bool):
            held_out = datasets.evaluation_set(train.TASK, n, problem=train.PROBLEM, split=name, build=build)
            return held_out.starts, held_out.goals

        return f"{train.TASK} {name} split: evaluation_set(n={n}, split={name!r})", n, load

    def pool(build: bool):
        starts = datasets.start_pool(train.TASK, train.START_POOL, train.PROBLEM, build=build)
        return starts.starts, starts.goals

    return [
        split("search", train.N_EVAL),
        split("test", train.N_TEST),
        (f"{train.TASK} start pool: start_pool(n={train.START_POOL})", train.START_POOL, pool),
    ]


def check() -> int:
    """Exit status 0 when every set is in the cache, whole and finite, and the sealed split shares no
    start with the others; else 1, one line per problem on stderr. Builds nothing."""
    failures, loaded = [], {}
    started = time.perf_counter()
    sets = required_sets()
    for description, expected, load in sets:
        try:
            starts, goals = load(build=False)
        except datasets.CacheMismatch as err:  # present, but it fails its checks: rebuilt by --warm-cache
            failures.append(f"{description}: fails its checks ({err})")
            continue
        except datasets.CacheMiss:
            failures.append(f"{description}: missing")
            continue
        if starts.shape != (expected, 6) or goals.shape != (expected, 3):
            failures.append(f"{description}: holds {len(starts)} starts, expected {expected}")
        elif not (np.isfinite(starts).all() and np.isfinite(goals).all()):
            failures.append(f"{description}: non-finite starts or goals")
        loaded[description] = starts
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


def warm() -> int:
    """Build every missing set, saying up front which, then check them all."""
    sets = required_sets()
    missing = []
    for description, _, load in sets:
        try:
            load(build=False)
        except datasets.CacheMiss:
            missing.append(description)
    if missing:
        print(f"to build: {len(missing)} of {len(sets)} data sets:", flush=True)
        for description in missing:
            print(f"  - {description}", flush=True)
    for description, _, load in sets:
        started = time.perf_counter()
        load(build=True)
        print(f"ready: {description} ({time.perf_counter() - started:.1f} s)", flush=True)
    return check()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--warm-cache", action="store_true", help="build every set (slow, once)")
    mode.add_argument("--check", action="store_true", help="verify the cache without building (seconds)")
    args = parser.parse_args()
    return warm() if args.warm_cache else check()


if __name__ == "__main__":
    sys.exit(main())
