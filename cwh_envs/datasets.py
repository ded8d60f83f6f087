"""Expert demonstration sets and the held-out evaluation starts, deterministic and cached on disk.

Every builder is a pure function of (task, n, seed, every problem field, and the code that builds
the data); that tuple, hashed, names the cache file, so neither a changed constant nor a changed
sampler or expert can serve a stale set. Each file also holds the sha256 of its arrays, checked
whenever it is read: a file whose arrays were changed is rebuilt, with a line on stderr that says
so, never used. Files are written to a temporary name and renamed into place (atomic on POSIX), so
concurrent runs at worst build the same file twice. Cache directory: the ``cache_dir`` argument,
else ``$CWH_ENVS_CACHE``, else ``~/.cache/cwh_envs``.

The evaluation splits of the problems the families score on are not built here: their starts ship
with the package (:mod:`cwh_envs.splits`), and only the expert's trajectories from them are solved
on this machine, each checked against the energy shipped for its start. A problem of the user's own
(no shipped split) has its starts screened here as below, with a warning that says so.

Random streams (``np.random.SeedSequence(seed, spawn_key=(stream, task))``) are disjoint by
construction: training seeds use stream 0, recovery stream 1, the search split of the evaluation
starts stream 2 and the sealed test split stream 3 (both with entropy fixed at 0), so no training
seed can reproduce a held-out set. Both splits are screened by the same builder. When built, a
split is checked against the candidate streams of training seeds 0..EVAL_CHECK_SEEDS-1 (a superset
of every demonstration set of those seeds), and the test split also against the search split's
candidate stream; ``cwh_envs.prepare`` checks it against the recovery pool a family trains on.

The search split (128 starts by default) is what a research loop selects on; the test split (1024
by default) is for certifying what it selected, never for choosing (docs/audit.md).

:func:`start_pool` (stream 4, entropy 0) is a fixed set of screened starts the envs can draw their
resets from (``start_pool=`` of the env constructors): built once per (task, size, problem), cached
here and in memory.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import os
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from cwh_envs import constraints, dynamics, experts, observations, problems, sampling, socp, splits
from cwh_envs.experts import Infeasible, solve_docking, solve_rendezvous, solve_rendezvous_many
from cwh_envs.observations import docking_observation, rendezvous_observation
from cwh_envs.problems import DockingProblem, RendezvousProblem
from cwh_envs.rollout import control_effort
from cwh_envs.sampling import (
    docking_candidates,
    iter_docking_starts,
    rendezvous_candidates,
    screened_rendezvous,
)

FORMAT_VERSION = 2  # 2: every file holds the sha256 of its arrays
TASKS = ("rendezvous", "docking")
EVAL_CHECK_SEEDS = 32  # training seeds whose candidate streams the evaluation set is checked against
EVAL_CHECK_CANDIDATES = 16384  # candidates per seed checked: ~4x what 256 docking demos consume
DEFAULT_RECOVERY_NOISE = (1.0, 0.005)  # (m, m/s) std of the perturbation added to an expert state
_TRAIN_STREAM, _RECOVERY_STREAM = 0, 1
_POOL_STREAM = 4  # the envs' start pools (after the two evaluation splits' 2 and 3)
SPLITS = ("search", "test")  # the evaluation splits: selected on, and sealed for certification
_SPLIT_STREAM = {"search": 2, "test": 3}
DEFAULT_EVAL_SIZE = {"search": 128, "test": 1024}
_MAX_RECOVERY_TRIES = 8  # perturbations tried per source trajectory before moving on


@dataclass(frozen=True)
class Demonstrations:
    """State-action pairs of E expert trajectories, M pairs in all, in the env observation layout.

    ``observations`` (M, 7 or 10) float64; ``actions`` (M, 3) thrust [N]; ``episode`` (M,) int,
    the source trajectory of each pair (0..E-1, in order); ``starts`` (E, 6) [m, m/s], the state
    each trajectory starts from; ``goals`` (E, 3) [m], docking points (zeros for rendezvous).
    """

    observations: np.ndarray
    actions: np.ndarray
    episode: np.ndarray
    starts: np.ndarray
    goals: np.ndarray

    @property
    def n_episodes(self) -> int:
        return len(self.starts)

    @property
    def content_key(self) -> str:
        """sha256 (16 hex digits) of every array: names the data a run trained or was scored on."""
        return _checksum({name: getattr(self, name) for name in _FIELDS})[:16]

    @property
    def starts_key(self) -> str:
        """The identity of the starts and docking points alone (:func:`cwh_envs.splits.split_identity`):
        names the split a run was scored on, whatever the expert's floats on this machine."""
        return splits.split_identity(self.starts, self.goals)

    def trajectory_thrust(self) -> np.ndarray:
        """Thrust (E, H, 3) [N] of sets whose trajectories all cover the whole horizon (the evaluation splits)."""
        steps, rest = divmod(len(self.actions), self.n_episodes)
        if rest or not np.array_equal(self.episode, np.repeat(np.arange(self.n_episodes), steps)):
            raise ValueError("trajectory_thrust: the trajectories of this set differ in length")
        return self.actions.reshape(self.n_episodes, steps, 3)

    def take(self, n_episodes: int) -> Demonstrations:
        """The first ``n_episodes`` trajectories (all of them if fewer)."""
        if not (isinstance(n_episodes, int | np.integer) and n_episodes >= 1):
            raise ValueError(f"n_episodes must be an integer >= 1, got {n_episodes!r}")
        rows = self.episode < n_episodes
        return Demonstrations(
            self.observations[rows],
            self.actions[rows],
            self.episode[rows],
            self.starts[:n_episodes],
            self.goals[:n_episodes],
        )


@dataclass(frozen=True)
class StartPool:
    """A fixed set of screened starts: ``starts`` (n, 6) [m, m/s] and ``goals`` (n, 3) [m] (zeros for
    rendezvous), read-only arrays shared by every env that draws from it."""

    starts: np.ndarray
    goals: np.ndarray

    def __len__(self) -> int:
        return len(self.starts)


class CacheMiss(LookupError):
    """A set asked for with ``build=False`` is not in the cache."""


class CacheMismatch(CacheMiss):
    """A set asked for with ``build=False`` is in the cache, but its file fails its checks (its
    arrays' checksum, or what it must hold): it would be rebuilt, never used."""


def demonstrations(
    task: str, n: int, seed: int = 0, problem=None, cache_dir=None, *, build: bool = True
) -> Demonstrations:
    """``n`` screened expert demonstrations for ``task`` ("rendezvous" or "docking"), seed ``seed``.

    Sets are nested: the first k trajectories of a seed's set do not depend on n. With
    ``build=False`` (every builder here takes it) a set missing from the cache raises
    :class:`CacheMiss` instead of being built: the fast check of ``prepare.py --check``.
    """
    problem = _problem(task, problem)
    _check_count("n", n)
    _check_seed(seed)
    key = _cache_key("demonstrations", task, problem, n=n, seed=seed)
    return _cached(
        cache_dir,
        key,
        lambda: _build_demonstrations(task, n, _rng(_TRAIN_STREAM, task, seed), problem),
        build,
    )


def evaluation_starts(
    task: str,
    n: int | None = None,
    problem=None,
    cache_dir=None,
    *,
    split: str = "search",
    build: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Held-out evaluation starts (n, 6) and goals (n, 3) (zeros for rendezvous), all expert-solvable.

    ``split="search"`` (n defaults to 128) is the set a search selects on; ``split="test"`` (n
    defaults to 1024) is the sealed set its winners are certified on. Splits are nested in n.
    """
    held_out = evaluation_set(task, n, problem, cache_dir, split=split, build=build)
    return held_out.starts, held_out.goals


def evaluation_set(
    task: str,
    n: int | None = None,
    problem=None,
    cache_dir=None,
    *,
    split: str = "search",
    build: bool = True,
) -> Demonstrations:
    """The evaluation starts of :func:`evaluation_starts` with the expert's trajectories from them
    (e.g. the expert's control effort, the reference a policy's fuel use is measured against)."""
    problem = _problem(task, problem)
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    n = DEFAULT_EVAL_SIZE[split] if n is None else n
    _check_count("n", n)
    shipped = splits.shipped_split(task, problem, split)
    if shipped is not None:
        return _shipped_set(task, n, problem, shipped, cache_dir, build)
    _warn_unshipped(task, problem, split)
    key = _cache_key("evaluation", task, problem, n=n, split=split)

    return _cached(cache_dir, key, lambda: screen_split(task, n, problem, split=split), build)


def screen_split(
    task: str, n: int, problem=None, *, split: str = "search", check: bool = True
) -> Demonstrations:
    """Draw a split's starts from its own stream and keep those the expert solves, with the expert's
    trajectories (not cached). This made the shipped splits (scripts/make_splits.py); a problem with
    no shipped split gets its splits this way. ``check`` asserts the starts are none of the candidates
    of training seeds 0..EVAL_CHECK_SEEDS-1 (and, for the test split, of the search split)."""
    problem = _problem(task, problem)
    _check_count("n", n)
    held_out = _build_demonstrations(
        task, n, _rng(_SPLIT_STREAM[split], task, 0), problem, f"{task} {split} split"
    )
    if check:
        streams = {f"training seed {seed}": (_TRAIN_STREAM, seed) for seed in range(EVAL_CHECK_SEEDS)}
        if split == "test":
            streams["the search split"] = (_SPLIT_STREAM["search"], 0)
        _check_disjoint(task, held_out.starts, problem, streams)
    return held_out


def shipped_split_label(task: str, n: int, problem=None, *, split: str = "search") -> str | None:
    """The name of the shipped split a family scoring on the first ``n`` starts of ``split`` uses (e.g.
    ``"docking/test-v0, first 1024"``), or None when none ships for ``problem``."""
    shipped = splits.shipped_split(task, _problem(task, problem), split)
    if shipped is None:
        return None
    return shipped.label + ("" if n == len(shipped) else f", first {n}")


def _shipped_set(task, n, problem, shipped: splits.ShippedSplit, cache_dir, build) -> Demonstrations:
    """The first ``n`` starts of a shipped split with the expert's trajectories from them, solved here
    once (and cached), each start's energy checked against the shipped one."""
    starts, goals = (np.array(part) for part in shipped.first(n))  # the caller's own, writable
    key = _cache_key(
        "evaluation", task, problem, n=n, split=shipped.split, starts=splits.split_identity(starts, goals)
    )

    def mismatch(held: Demonstrations) -> str | None:
        if not (np.array_equal(held.starts, starts) and np.array_equal(held.goals, goals)):
            return f"its starts are not those of the shipped split {shipped.label}"
        return shipped.energy_mismatch(control_effort(held.trajectory_thrust(), problem)[0])

    def solve_shipped() -> Demonstrations:
        held = _solve_starts(
            task, starts, goals, problem, f"{task} {shipped.split} split (expert, {shipped.label})"
        )
        why = mismatch(held)
        if why is not None:
            raise splits.SplitError(why)
        return held

    return _cached(cache_dir, key, solve_shipped, build, check=mismatch)


def _solve_starts(task, starts, goals, problem, label) -> Demonstrations:
    """The expert's trajectories from given starts, in order; a start it cannot solve is an error.
    Rendezvous is solved in slices of 8, as the screen solves its candidates (the batched solve's
    floats depend on the batch's size), so a shipped split gets the trajectories its screen kept."""
    n = len(starts)
    progress = _Progress(label, n)
    states, controls, unsolved = [], [], []
    if task == "rendezvous":
        for first in range(0, n, 8):
            block_states, block_controls, solved = solve_rendezvous_many(starts[first : first + 8], problem)
            states.extend(block_states)
            controls.extend(block_controls)
            unsolved.extend((first + i, "the reach tolerance is not met") for i in np.flatnonzero(~solved))
            progress.update(min(first + 8, n))
    else:
        for i, (x0, goal) in enumerate(zip(starts, goals, strict=True)):
            try:
                trajectory, thrust = solve_docking(x0, goal, problem)
            except Infeasible as err:
                unsolved.append((i, str(err)))
                break
            states.append(trajectory)
            controls.append(thrust)
            progress.update(i + 1)
    if unsolved:
        i, why = unsolved[0]
        raise splits.SplitError(
            f"{label}: the expert cannot solve start {i} ({splits.describe_start(starts[i])}) on this "
            f"machine ({why}), though it did when the split was made"
        )
    progress.close()
    return _pack(task, problem, starts, goals, states, controls, np.zeros(n, dtype=int))


_WARNED: set[str] = set()


def _warn_unshipped(task: str, problem, split: str) -> None:
    key = json.dumps([task, split, splits.problem_fields(problem)], sort_keys=True)
    if key not in _WARNED:
        _WARNED.add(key)
        warnings.warn(
            f"no {split} split ships for this {task} problem (cwh_envs/data/manifest.json lists those "
            "that do): its starts are screened on this machine, and numbers scored on them are not the "
            "benchmark's",
            stacklevel=3,
        )


def recovery_demonstrations(
    task: str,
    n: int,
    seed: int = 0,
    problem=None,
    cache_dir=None,
    noise=DEFAULT_RECOVERY_NOISE,
    *,
    build: bool = True,
) -> Demonstrations:
    """``n`` expert trajectories from states perturbed off the seed's training trajectories.

    For training trajectory i (cycling through ``demonstrations(task, n, seed)``) a step k is drawn
    uniformly from 1..H - H//8 and the state there perturbed by Gaussian noise
    ``(position std [m], velocity std [m/s]) = noise``; the expert is re-solved over the remaining
    H - k steps (to the origin, or to the same docking point). Its pairs carry tau = (H - j) / H
    for j = k..H-1, exactly what the env shows at those steps. Perturbations the expert cannot
    solve (e.g. inside the keep-out) are redrawn. ``starts`` holds the perturbed states.
    """
    problem = _problem(task, problem)
    _check_count("n", n)
    _check_seed(seed)
    noise = tuple(float(v) for v in noise)
    if len(noise) != 2 or not all(np.isfinite(v) and v >= 0 for v in noise):
        raise ValueError(f"noise must be (position_std, velocity_std) >= 0, got {noise!r}")
    key = _cache_key("recovery", task, problem, n=n, seed=seed, noise=noise)

    def build_recovery() -> Demonstrations:
        sources = demonstrations(task, n, seed, problem, cache_dir)
        return _build_recovery(task, n, sources, _rng(_RECOVERY_STREAM, task, seed), problem, noise)

    return _cached(cache_dir, key, build_recovery, build)


def start_pool(task: str, n: int, problem=None, cache_dir=None, *, build: bool = True) -> StartPool:
    """``n`` screened starts for ``task``, drawn once from a fixed stream (the sampler the envs reset
    with), cached on disk and in memory.

    Resetting from a pool replaces fresh i.i.d. screened draws by draws with replacement from these
    ``n`` (one i.i.d. sample of the same screened distribution): resets cost an index draw instead of
    a screen. Pools are nested in ``n`` (the first k starts do not depend on n) and come from their
    own random stream, so they are disjoint from the training, recovery and evaluation streams by
    construction.
    """
    problem = _problem(task, problem)
    n = check_pool_size(n)
    key = _cache_key("start_pool", task, problem, n=n)
    memo = (json.dumps(key, sort_keys=True), str(cache_directory(cache_dir)))
    if memo not in _POOLS:

        def build_pool() -> StartPool:
            rng = _rng(_POOL_STREAM, task, 0)
            progress = _Progress(f"{task} start pool", n)
            if task == "rendezvous":  # the starts of sample_rendezvous_starts, without keeping n trajectories
                drawn = itertools.islice(sampling.iter_rendezvous(rng, problem), n)
                starts, goals = np.array([start for start, _, _ in drawn]), np.zeros((n, 3))
            else:
                starts, goals = sampling.sample_docking_starts(rng, n, problem)
            progress.update(n)
            progress.close()
            return StartPool(starts, goals)

        pool = _cached(cache_dir, key, build_pool, build, StartPool)
        for array in (pool.starts, pool.goals):
            array.setflags(write=False)  # shared by every env drawing from it
        while len(_POOLS) >= _POOLS_KEPT:
            del _POOLS[next(iter(_POOLS))]  # the oldest
        _POOLS[memo] = pool
    return _POOLS[memo]


_POOLS: dict[tuple[str, str], StartPool] = {}  # (cache key, cache directory) -> the pool, per process
_POOLS_KEPT = 8


MAX_POOL = 1 << 20  # ~1M starts: 48 MB of states and minutes to screen; 10**12 would never finish


def check_pool_size(n) -> int:
    """``n`` as the size of a start pool, or a ``ValueError`` that says what a size must be."""
    if not (isinstance(n, int | np.integer) and not isinstance(n, bool) and 1 <= n <= MAX_POOL):
        raise ValueError(
            "start_pool must be None or an integer from 1 to "
            f"{MAX_POOL} (the number of pooled starts), got {n!r}"
        )
    return int(n)


def cache_directory(cache_dir=None) -> Path:
    """The directory the cached sets live in (argument, else $CWH_ENVS_CACHE, else ~/.cache/cwh_envs)."""
    if cache_dir is not None:
        return Path(cache_dir)
    return Path(os.environ.get("CWH_ENVS_CACHE") or Path.home() / ".cache" / "cwh_envs")


# ------------------------------------------------------------------------------------- builders


def _build_demonstrations(
    task: str, n: int, rng: np.random.Generator, problem, label: str | None = None
) -> Demonstrations:
    progress = _Progress(label or f"{task} demonstrations", n)
    if task == "rendezvous":
        starts, states, controls = screened_rendezvous(rng, n, problem)
        goals = np.zeros((n, 3))
        progress.update(n)
    else:
        starts, goals, states, controls = [], [], [], []
        for x0, goal in iter_docking_starts(rng, problem):
            try:
                trajectory, thrust = solve_docking(x0, goal, problem)
            except Infeasible:
                continue  # the fast screen does not run the SCP; keep only solved demos
            starts.append(x0)
            goals.append(goal)
            states.append(trajectory)
            controls.append(thrust)
            progress.update(len(starts))
            if len(starts) == n:
                break
        starts, goals = np.array(starts), np.array(goals)
    progress.close()
    first_steps = np.zeros(n, dtype=int)
    return _pack(task, problem, starts, goals, list(states), list(controls), first_steps)


def _build_recovery(task, n, sources: Demonstrations, rng, problem, noise) -> Demonstrations:
    horizon = problem.horizon
    scale = np.repeat(noise, 3)
    progress = _Progress(f"{task} recovery demonstrations", n)
    starts, goals, states, controls, first_steps = [], [], [], [], []
    source = 0
    while len(starts) < n:
        episode = source % sources.n_episodes
        goal = sources.goals[episode]
        nominal = sources.observations[sources.episode == episode, :6]  # states at steps 0..H-1
        for _ in range(_MAX_RECOVERY_TRIES):
            step = int(rng.integers(1, horizon - horizon // 8 + 1))
            perturbed = nominal[step] + rng.normal(size=6) * scale
            try:
                trajectory, thrust = _solve(task, perturbed, goal, problem.replace(horizon=horizon - step))
            except Infeasible:
                continue
            starts.append(perturbed)
            goals.append(goal)
            states.append(trajectory)
            controls.append(thrust)
            first_steps.append(step)
            progress.update(len(starts))
            break
        source += 1
    progress.close()
    return _pack(task, problem, np.array(starts), np.array(goals), states, controls, np.array(first_steps))


def _solve(task: str, x0, goal, problem):
    if task == "rendezvous":
        return solve_rendezvous(x0, problem)
    return solve_docking(x0, goal, problem)


def _pack(task, problem, starts, goals, states, controls, first_steps) -> Demonstrations:
    """Flatten trajectories into pairs; trajectory i covers steps first_steps[i]..H-1 of the episode."""
    observations, actions, episode = [], [], []
    for i, (trajectory, thrust, first) in enumerate(zip(states, controls, first_steps, strict=True)):
        steps = first + np.arange(len(thrust))
        if task == "rendezvous":
            observations.append(
                rendezvous_observation(trajectory[:-1], steps, problem.horizon, dtype=np.float64)
            )
        else:
            observations.append(
                docking_observation(trajectory[:-1], goals[i], steps, problem.horizon, dtype=np.float64)
            )
        actions.append(thrust)
        episode.append(np.full(len(thrust), i))
    return Demonstrations(
        np.concatenate(observations), np.concatenate(actions), np.concatenate(episode), starts, goals
    )


def _check_disjoint(task: str, held_out: np.ndarray, problem, streams: dict[str, tuple[int, int]]) -> None:
    """Assert no held-out start is a candidate of the given (stream, seed) draws (each a superset of
    the starts that stream's sets keep), over the first EVAL_CHECK_CANDIDATES candidates of each."""
    held = {row.tobytes() for row in held_out}
    for name, (stream, seed) in streams.items():
        rng = _rng(stream, task, seed)
        drawn = 0
        while drawn < EVAL_CHECK_CANDIDATES:
            if task == "rendezvous":
                candidates = rendezvous_candidates(rng, problem)
            else:
                candidates = docking_candidates(rng, problem)[0]
            if any(row.tobytes() in held for row in candidates):
                raise AssertionError(f"evaluation start found among the candidates of {name}")
            drawn += len(candidates)


# ---------------------------------------------------------------------------------------- cache


def _cached(cache_dir, key: dict, build, build_missing: bool, kind: type = Demonstrations, check=None):
    """``kind`` (a dataclass of arrays) from the cache file named by ``key``, else built and stored.

    A file is used only if its arrays hash to the checksum stored beside them and ``check`` (when
    given) finds nothing wrong with what they hold; otherwise it is rebuilt (with a line on stderr
    saying why) or, under ``build_missing=False``, reported as a :class:`CacheMiss` that says why.
    """
    text = json.dumps(key, sort_keys=True)
    digest = hashlib.sha256(text.encode()).hexdigest()[:20]
    path = cache_directory(cache_dir) / f"{key['kind']}-{key['task']}-{digest}.npz"
    names = [field.name for field in dataclasses.fields(kind)]
    loaded, why = _load(path, text, kind, names)
    if loaded is not None and check is not None:
        why = check(loaded)
        loaded = None if why else loaded
    if loaded is not None:
        return loaded
    what = f"{key['kind']} set for {key['task']} (n={key.get('n')})"
    if not build_missing:
        if why:
            raise CacheMismatch(f"{what}: {path} {why}")
        raise CacheMiss(f"{what} is not in {path.parent}")
    if why:
        sys.stderr.write(f"cwh_envs: the cache file {path} {why}: building it again\n")
    result = build()
    arrays = {name: getattr(result, name) for name in names}
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(
        dir=path.parent, prefix=path.stem, suffix=".tmp", delete=False
    ) as handle:
        np.savez(handle, key=np.array(text), checksum=np.array(_checksum(arrays)), **arrays)
    os.replace(handle.name, path)
    return result


_FIELDS = tuple(field.name for field in dataclasses.fields(Demonstrations))


def _checksum(arrays: dict[str, np.ndarray]) -> str:
    """sha256 of named arrays: dtype, shape and bytes of each, in order."""
    digest = hashlib.sha256()
    for name, array in arrays.items():
        array = np.ascontiguousarray(array)
        digest.update(f"{name}:{array.dtype.str}:{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def _load(path: Path, text: str, kind: type, names: list[str]):
    """(the cached set, None), or (None, why it cannot be used: None when there is no such file)."""
    if not path.exists():
        return None, None
    try:
        with np.load(path, allow_pickle=False) as stored:
            if str(stored["key"]) != text:
                return None, "was written for another set"
            arrays = {name: stored[name] for name in names}
            checksum = str(stored["checksum"]) if "checksum" in stored.files else None
    except (OSError, ValueError, KeyError) as err:
        return None, f"cannot be read ({type(err).__name__}: {err})"
    if checksum != _checksum(arrays):
        return None, "does not match the checksum of its arrays (changed or damaged)"
    return kind(**arrays), None


def _cache_key(kind: str, task: str, problem, **arguments) -> dict:
    return {
        "format": FORMAT_VERSION,
        "code": _builder_source_digest(),
        "kind": kind,
        "task": task,
        "problem": splits.problem_fields(problem),  # as the shipped splits' manifest writes it
        **{name: list(v) if isinstance(v, tuple) else v for name, v in arguments.items()},
    }


@lru_cache(maxsize=1)
def _builder_source_digest() -> str:
    """Hash of the modules whose code decides what a builder returns.

    A version number had to be bumped by hand and once was not: a new docking sampler kept serving
    the old pools under the old key. Hashing the source makes any such change a new key.
    """
    digest = hashlib.sha256()
    for module in (
        splits,
        dynamics,
        problems,
        sampling,
        constraints,
        experts,
        socp,
        observations,
        sys.modules[__name__],
    ):
        digest.update(Path(module.__file__).read_bytes())
    return digest.hexdigest()[:16]


# ------------------------------------------------------------------------------------- helpers


def _problem(task: str, problem):
    if task not in TASKS:
        raise ValueError(f"task must be one of {TASKS}, got {task!r}")
    kind = RendezvousProblem if task == "rendezvous" else DockingProblem
    if problem is None:
        return kind()
    if not isinstance(problem, kind):
        raise ValueError(f"task {task!r} needs a {kind.__name__}, got {type(problem).__name__}")
    return problem


def _rng(stream: int, task: str, seed: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(stream, TASKS.index(task))))


def _check_count(name: str, n) -> None:
    if not (isinstance(n, int | np.integer) and n >= 1):
        raise ValueError(f"{name} must be an integer >= 1, got {n!r}")


def _check_seed(seed) -> None:
    if not (isinstance(seed, int | np.integer) and seed >= 0):
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")


class _Progress:
    """A compact progress bar on stderr: redrawn in place on a terminal; off one (a log file), a line
    every ``LINE_EVERY`` seconds with the count and the time left at the rate so far, so that a long
    build is seen to move."""

    LINE_EVERY = 30.0

    def __init__(self, label: str, total: int):
        self.label, self.total, self.started = label, total, time.perf_counter()
        self.live = sys.stderr.isatty()
        self.drawn = 0.0 if self.live else self.started

    def update(self, done: int) -> None:
        now = time.perf_counter()
        if self.live and (now - self.drawn > 0.1 or done == self.total):
            filled = int(24 * done / self.total)
            sys.stderr.write(f"\r{self.label} [{'#' * filled}{'.' * (24 - filled)}] {done}/{self.total}")
            sys.stderr.flush()
            self.drawn = now
        elif not self.live and 0 < done < self.total and now - self.drawn >= self.LINE_EVERY:
            left = (now - self.started) * (self.total - done) / done
            sys.stderr.write(f"{self.label}: {done}/{self.total} built, about {left:.0f} s left\n")
            sys.stderr.flush()
            self.drawn = now

    def close(self) -> None:
        elapsed = time.perf_counter() - self.started
        sys.stderr.write(
            ("\r" if self.live else "") + f"{self.label}: {self.total} built in {elapsed:.1f} s\n"
        )
        sys.stderr.flush()
