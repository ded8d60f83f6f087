"""Screened start samplers: determinism, nesting, the screen's guarantees and its speed."""

from __future__ import annotations

import time

import numpy as np
import pytest

from cwh_envs.experts import Infeasible, koz_active, linear_model, solve_docking, solve_rendezvous
from cwh_envs.problems import DockingProblem, RendezvousProblem
from cwh_envs.sampling import (
    NoAdmissibleStart,
    docking_candidates,
    docking_screen,
    sample_docking_start,
    sample_docking_starts,
    sample_rendezvous_start,
    sample_rendezvous_starts,
    unconstrained_min_distance,
    unconstrained_peak_thrust,
)

RDZV = RendezvousProblem()
DOCK = DockingProblem()
RADIUS = DOCK.koz_radius + DOCK.margin


def rng(seed=0):
    return np.random.default_rng(seed)


def test_rendezvous_starts_are_deterministic_nested_and_reachable():
    starts = sample_rendezvous_starts(rng(), 20, RDZV)
    assert starts.shape == (20, 6)
    np.testing.assert_array_equal(starts, sample_rendezvous_starts(rng(), 20, RDZV))
    np.testing.assert_array_equal(starts[:7], sample_rendezvous_starts(rng(), 7, RDZV))
    assert not np.array_equal(starts, sample_rendezvous_starts(rng(1), 20, RDZV))
    half = np.concatenate([RDZV.position_box, RDZV.velocity_box])
    assert np.all(np.abs(starts) <= half)
    for x0 in starts[:5]:
        states, _ = solve_rendezvous(x0, RDZV)
        assert np.abs(states[-1]).max() <= RDZV.reach_tolerance
    np.testing.assert_array_equal(sample_rendezvous_start(rng(), RDZV), starts[0])


def test_rendezvous_screen_rejects_unreachable_candidates():
    generator = rng(3)
    half = np.concatenate([RDZV.position_box, RDZV.velocity_box])
    candidates = generator.uniform(-half, half, size=(64, 6))
    unreachable = 0
    for x0 in candidates:
        try:
            solve_rendezvous(x0, RDZV)
        except Infeasible:
            unreachable += 1
    assert unreachable > 0  # the box does contain unreachable starts, so the screen matters


def test_docking_starts_follow_the_far_side_geometry():
    starts, goals = sample_docking_starts(rng(), 200, DOCK)
    assert starts.shape == (200, 6) and goals.shape == (200, 3)
    np.testing.assert_allclose(np.linalg.norm(goals, axis=1), DOCK.goal_radius)
    distance = np.linalg.norm(starts[:, :3], axis=1)
    assert np.all((distance >= DOCK.start_distance[0]) & (distance <= DOCK.start_distance[1]))
    cosine = np.einsum("ni,ni->n", starts[:, :3], -goals) / (distance * DOCK.goal_radius)
    assert np.all(cosine >= np.cos(np.radians(DOCK.start_cone_deg)) - 1e-12)  # far side, opposite g
    np.testing.assert_array_equal(starts[:, 3:], 0.0)  # default: released from a hold point


def test_docking_starts_are_deterministic_and_nested():
    starts, goals = sample_docking_starts(rng(5), 50, DOCK)
    again = sample_docking_starts(rng(5), 50, DOCK)
    np.testing.assert_array_equal(starts, again[0])
    np.testing.assert_array_equal(goals, again[1])
    fewer = sample_docking_starts(rng(5), 9, DOCK)
    np.testing.assert_array_equal(starts[:9], fewer[0])
    one = sample_docking_start(rng(5), DOCK)
    np.testing.assert_array_equal(one[0], starts[0])
    np.testing.assert_array_equal(one[1], goals[0])


def test_screen_maps_equal_the_explicit_minimum_energy_rollout():
    starts, goals = sample_docking_starts(rng(2), 10, DOCK)
    model = linear_model(DOCK)
    closest = unconstrained_min_distance(starts, goals, DOCK)
    peak = unconstrained_peak_thrust(starts, goals, DOCK)
    for i in range(10):
        controls = model.min_energy(starts[i], np.r_[goals[i], 0.0, 0.0, 0.0])
        states = model.rollout(starts[i], controls)
        np.testing.assert_allclose(closest[i], np.linalg.norm(states[:, :3], axis=1).min(), atol=1e-9)
        np.testing.assert_allclose(peak[i], np.abs(controls).max(), atol=1e-12)
    assert np.all(closest <= RADIUS - DOCK.pierce_depth) and np.all(peak <= DOCK.u_max)
    assert docking_screen(starts, goals, DOCK).all()


def test_keep_out_binds_in_screened_expert_demonstrations():
    starts, goals = sample_docking_starts(rng(11), 24, DOCK)
    trajectories = np.stack([solve_docking(x0, g, DOCK)[0] for x0, g in zip(starts, goals, strict=True)])
    assert koz_active(trajectories, DOCK).mean() >= 0.8  # 1.0: a pierced start always binds


def test_a_naive_far_side_sampler_rarely_binds():
    """Why the screen exists: without it most far-side starts never reach the keep-out."""
    unscreened = DOCK.replace(pierce_depth=0.0)
    starts, goals = docking_candidates(rng(4), unscreened)
    assert (unconstrained_min_distance(starts, goals, unscreened) <= RADIUS).mean() < 0.3


def test_batched_docking_screen_is_fast():
    sample_docking_starts(rng(), 8, DOCK)  # warm the cached maps
    started = time.perf_counter()
    sample_docking_starts(rng(1), 1024, DOCK)
    assert time.perf_counter() - started < 2.0  # ~0.1 s on 2 cores


@pytest.mark.parametrize("n", [0, -3, 2.5])
def test_bad_counts_raise(n):
    with pytest.raises(ValueError, match="n must be"):
        sample_rendezvous_starts(rng(), n, RDZV)
    with pytest.raises(ValueError, match="n must be"):
        sample_docking_starts(rng(), n, DOCK)


@pytest.mark.parametrize(
    ("sample", "problem"),
    [
        (sample_rendezvous_starts, RendezvousProblem(horizon=4)),
        (sample_docking_starts, DockingProblem(horizon=4)),
    ],
)
def test_sampler_gives_up_with_a_clear_error_when_no_start_is_admissible(sample, problem):
    with pytest.raises(NoAdmissibleStart, match="no start passed the screen"):
        sample(np.random.default_rng(0), 1, problem)
