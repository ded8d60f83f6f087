"""Demonstration sets: layout, determinism, the content-addressed cache, the held-out set, recovery."""

from __future__ import annotations

import numpy as np
import pytest

from cwh_envs.datasets import (
    DEFAULT_EVAL_SIZE,
    CacheMiss,
    Demonstrations,
    cache_directory,
    demonstrations,
    evaluation_set,
    evaluation_starts,
    recovery_demonstrations,
)
from cwh_envs.prepare import shared_starts
from cwh_envs.problems import DockingProblem, RendezvousProblem

FIELDS = ("observations", "actions", "episode", "starts", "goals")


def assert_same(first: Demonstrations, second: Demonstrations) -> None:
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(first, name), getattr(second, name))


def replay(demos: Demonstrations, problem, first_steps=None):
    """Check every trajectory obeys the shared model and the observation layout; returns final states."""
    a, b = problem.matrices()
    horizon = problem.horizon
    finals = []
    for episode in range(demos.n_episodes):
        rows = demos.episode == episode
        observations, actions = demos.observations[rows], demos.actions[rows]
        states = observations[:, :6]
        np.testing.assert_array_equal(states[0], demos.starts[episode])
        np.testing.assert_allclose(states[1:], states[:-1] @ a.T + actions[:-1] @ b.T, atol=1e-9)
        first = horizon - len(actions)
        np.testing.assert_allclose(observations[:, -1], (horizon - first - np.arange(len(actions))) / horizon)
        if observations.shape[1] == 10:
            np.testing.assert_array_equal(
                observations[:, 6:9], np.broadcast_to(demos.goals[episode], (len(actions), 3))
            )
        finals.append(states[-1] @ a.T + actions[-1] @ b.T)
    return np.array(finals)


def test_rendezvous_demonstrations_layout_and_expert_quality(tmp_path):
    demos = demonstrations("rendezvous", 12, seed=0, cache_dir=tmp_path)
    horizon = RendezvousProblem().horizon
    assert demos.n_episodes == 12 and demos.observations.shape == (12 * horizon, 7)
    assert demos.observations.dtype == np.float64 and demos.actions.shape == (12 * horizon, 3)
    np.testing.assert_array_equal(demos.episode, np.repeat(np.arange(12), horizon))
    np.testing.assert_array_equal(demos.goals, 0.0)
    finals = replay(demos, RendezvousProblem())
    assert np.abs(finals).max() <= 1e-6
    assert np.abs(demos.actions).max() <= RendezvousProblem().u_max + 1e-9


def test_docking_demonstrations_are_feasible_and_bind(tmp_path):
    problem = DockingProblem()
    demos = demonstrations("docking", 6, seed=0, cache_dir=tmp_path)
    assert demos.observations.shape == (6 * problem.horizon, 10)
    finals = replay(demos, problem)
    np.testing.assert_allclose(finals[:, :3], demos.goals, atol=1e-6)
    clearance = np.linalg.norm(demos.observations[:, :3], axis=1)
    assert clearance.min() >= problem.koz_radius + problem.margin - 1e-6
    per_episode = [clearance[demos.episode == e].min() for e in range(6)]
    assert np.all(np.array(per_episode) <= problem.koz_radius + problem.margin + 1e-3)  # hugs the sphere


def test_second_call_loads_the_cache_and_sets_are_nested(tmp_path):
    first = demonstrations("rendezvous", 10, seed=3, cache_dir=tmp_path)
    files = list(tmp_path.iterdir())
    assert len(files) == 1 and files[0].suffix == ".npz"
    stamp = files[0].stat().st_mtime_ns
    second = demonstrations("rendezvous", 10, seed=3, cache_dir=tmp_path)
    assert files[0].stat().st_mtime_ns == stamp  # loaded, not rebuilt
    assert_same(first, second)
    assert_same(first.take(4), demonstrations("rendezvous", 4, seed=3, cache_dir=tmp_path))
    assert first.take(4).n_episodes == 4 and not any(p.suffix == ".tmp" for p in tmp_path.iterdir())
    other_seed = demonstrations("rendezvous", 10, seed=4, cache_dir=tmp_path)
    assert not np.array_equal(other_seed.starts, first.starts)


def test_cache_key_covers_every_problem_field(tmp_path):
    demonstrations("rendezvous", 3, cache_dir=tmp_path)
    demonstrations("rendezvous", 3, problem=RendezvousProblem(reach_tolerance=2e-6), cache_dir=tmp_path)
    demonstrations("rendezvous", 3, problem=RendezvousProblem(discretization="exact"), cache_dir=tmp_path)
    assert len(list(tmp_path.glob("*.npz"))) == 3


def test_corrupt_cache_file_is_rebuilt(tmp_path):
    first = demonstrations("rendezvous", 3, cache_dir=tmp_path)
    (path,) = tmp_path.glob("*.npz")
    path.write_bytes(b"not an npz")
    assert_same(first, demonstrations("rendezvous", 3, cache_dir=tmp_path))


def test_cache_directory_resolution(tmp_path, monkeypatch):
    monkeypatch.setenv("CWH_ENVS_CACHE", str(tmp_path / "env"))
    assert cache_directory() == tmp_path / "env"
    assert cache_directory(tmp_path / "arg") == tmp_path / "arg"
    demonstrations("rendezvous", 2)
    assert len(list((tmp_path / "env").glob("*.npz"))) == 1


@pytest.mark.parametrize("task", ["rendezvous", "docking"])
def test_evaluation_set_is_disjoint_from_the_training_pool(task, tmp_path):
    starts, goals = evaluation_starts(task, n=8, cache_dir=tmp_path)
    assert starts.shape == (8, 6) and goals.shape == (8, 3)
    again = evaluation_starts(task, n=8, cache_dir=tmp_path)
    np.testing.assert_array_equal(starts, again[0])
    held_out = {row.tobytes() for row in starts}
    for seed in range(3):
        training = demonstrations(task, 8, seed=seed, cache_dir=tmp_path)
        assert not held_out & {row.tobytes() for row in training.starts}


@pytest.mark.parametrize("task", ["rendezvous", "docking"])
def test_the_sealed_test_split_is_screened_alike_and_shares_no_start(task, tmp_path):
    problem = RendezvousProblem() if task == "rendezvous" else DockingProblem()
    search = evaluation_set(task, 64, cache_dir=tmp_path)
    test = evaluation_set(task, 64, cache_dir=tmp_path, split="test")
    assert DEFAULT_EVAL_SIZE == {"search": 128, "test": 1024}
    np.testing.assert_array_equal(search.starts, evaluation_starts(task, 64, cache_dir=tmp_path)[0])
    others = [
        search,
        demonstrations(task, 64, cache_dir=tmp_path),
        recovery_demonstrations(task, 16, cache_dir=tmp_path),
    ]
    for other in others:
        assert shared_starts(test.starts, other.starts) == 0
    assert shared_starts(test.starts, test.starts[:5]) == 5  # the check itself sees a shared start
    # Screened exactly like the search split: the expert reaches the target from every start, over
    # the whole horizon, in the same observation layout; nested in n like every set.
    finals = replay(test, problem)
    target = np.zeros((64, 3)) if task == "rendezvous" else test.goals
    np.testing.assert_allclose(finals[:, :3], target, atol=1e-6)
    assert test.trajectory_thrust().shape == (64, problem.horizon, 3)
    np.testing.assert_array_equal(
        evaluation_set(task, 8, cache_dir=tmp_path, split="test").starts, test.starts[:8]
    )
    # Content keys name the data: equal for equal sets, different for different ones.
    assert test.content_key == evaluation_set(task, 64, cache_dir=tmp_path, split="test").content_key
    assert test.content_key != search.content_key


def test_evaluation_splits_reject_an_unknown_split(tmp_path):
    with pytest.raises(ValueError, match="split must be one of"):
        evaluation_set("rendezvous", 4, cache_dir=tmp_path, split="train")
    with pytest.raises(ValueError, match="differ in length"):
        recovery_demonstrations("rendezvous", 3, cache_dir=tmp_path).trajectory_thrust()


@pytest.mark.parametrize("task", ["rendezvous", "docking"])
def test_recovery_demonstrations_resume_mid_episode(task, tmp_path):
    problem = RendezvousProblem() if task == "rendezvous" else DockingProblem()
    recovery = recovery_demonstrations(task, 5, seed=0, cache_dir=tmp_path)
    assert recovery.n_episodes == 5
    lengths = np.bincount(recovery.episode)
    assert np.all(lengths < problem.horizon) and np.all(lengths >= problem.horizon // 8)
    finals = replay(recovery, problem)
    target = np.zeros((5, 3)) if task == "rendezvous" else recovery.goals
    np.testing.assert_allclose(finals[:, :3], target, atol=1e-6)
    sources = demonstrations(task, 5, seed=0, cache_dir=tmp_path)
    np.testing.assert_array_equal(recovery.goals, sources.goals)
    if task == "docking":
        clearance = np.linalg.norm(recovery.observations[:, :3], axis=1)
        assert clearance.min() >= problem.koz_radius + problem.margin - 1e-6
    assert_same(recovery, recovery_demonstrations(task, 5, seed=0, cache_dir=tmp_path))


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda d: demonstrations("orbit", 4, cache_dir=d), "task"),
        (lambda d: demonstrations("rendezvous", 0, cache_dir=d), "n must"),
        (lambda d: demonstrations("rendezvous", 4, seed=-1, cache_dir=d), "seed"),
        (lambda d: demonstrations("docking", 4, problem=RendezvousProblem(), cache_dir=d), "DockingProblem"),
        (lambda d: evaluation_starts("docking", n=0, cache_dir=d), "n must"),
        (lambda d: recovery_demonstrations("docking", 2, noise=(-1.0, 0.0), cache_dir=d), "noise"),
        (lambda d: demonstrations("rendezvous", 4, cache_dir=d).take(0), "n_episodes"),
    ],
)
def test_bad_arguments_raise_clear_value_errors(call, message, tmp_path):
    with pytest.raises(ValueError, match=message):
        call(tmp_path)


def test_build_false_reads_the_cache_and_never_builds(tmp_path):
    with pytest.raises(CacheMiss, match="not in"):
        demonstrations("rendezvous", 4, seed=0, cache_dir=tmp_path, build=False)
    assert not list(tmp_path.iterdir())  # nothing was built or written
    built = demonstrations("rendezvous", 4, seed=0, cache_dir=tmp_path)
    cached = demonstrations("rendezvous", 4, seed=0, cache_dir=tmp_path, build=False)
    np.testing.assert_array_equal(built.observations, cached.observations)


def test_a_build_off_a_terminal_prints_a_progress_line_now_and_then(tmp_path, monkeypatch, capsys):
    """A log file sees the count and the time left while a set builds, not only when it is done."""
    from cwh_envs import datasets

    monkeypatch.setattr(datasets._Progress, "LINE_EVERY", 0.0)
    demonstrations("docking", 3, seed=0, cache_dir=tmp_path)
    lines = capsys.readouterr().err.splitlines()
    assert [line for line in lines if "/3 built, about" in line and " s left" in line]
    assert lines[-1].startswith("docking demonstrations: 3 built in")
