"""Issue 58, item 4: the robust MPC as a tube MPC (cwh_envs.tube_mpc): one plan per episode on
constraints tightened by the tube, an ancillary LQR feedback on the navigation estimate."""

from __future__ import annotations

import numpy as np
import pytest

from cwh_envs import splits
from cwh_envs.constraints import CAPTURE_RADIUS
from cwh_envs.mpc import RADIUS_MARGIN
from cwh_envs.observations import docking_observation
from cwh_envs.problems import DockingProblem, RendezvousProblem
from cwh_envs.robust_cbf import ErrorBounds
from cwh_envs.rollout import fly
from cwh_envs.tube_mpc import Tube, TubeMPC, ancillary_gain

# The constrained docking family's problem and 1-sigma dispersions (families/docking-constrained/train.py).
PROBLEM = DockingProblem(
    speed_limit=(0.01, 2 * DockingProblem().n), approach_cone=(30.0, 15.0), capture_radius=CAPTURE_RADIUS
)
DISPERSIONS = dict(thrust_scale=0.02, misalignment_deg=1.0, mass=0.02, nav_position=0.05, nav_velocity=5e-4)
BOUNDS = ErrorBounds.from_dispersions(DISPERSIONS, k_sigma=3.0)


def search_starts(n: int):
    return splits.shipped_split("docking", PROBLEM, "search").first(n)


def test_zero_bounds_make_no_tube_and_plan_the_nominal_corridor():
    mpc = TubeMPC(PROBLEM, ErrorBounds())
    assert mpc.tube == Tube(0.0, 0.0)
    assert mpc.planned == mpc.corridor
    assert mpc.corridor.approach_cone == (30.0, 15.0 + RADIUS_MARGIN)


def test_the_tube_tightens_each_constraint_by_its_own_width():
    mpc = TubeMPC(PROBLEM, BOUNDS)
    width = np.sqrt(3.0) * mpc.tube.position
    assert mpc.tube.position > 3 * 0.01 and mpc.tube.velocity > 3 * 1e-4  # both terms count
    assert mpc.planned.margin == pytest.approx(PROBLEM.margin + width)
    v0, v1 = PROBLEM.speed_limit
    assert mpc.planned.speed_limit == pytest.approx((v0 - mpc.tube.velocity - v1 * width, v1))
    assert mpc.planned.approach_cone == pytest.approx((30.0, 15.0 + RADIUS_MARGIN + width))


def test_the_navigation_part_of_the_tube_is_the_measured_spread_of_the_deviation():
    """Only navigation noise: the tube is k times the deviation's stationary standard deviation. A
    Monte Carlo of e_{k+1} = (A + B K) e_k + B K n_k agrees to a few per cent."""
    bounds = ErrorBounds(nav_position=0.05, nav_velocity=5e-4, k_sigma=3.0)
    gain = ancillary_gain(PROBLEM, 60.0)
    tube = Tube.of(PROBLEM, bounds, gain, reference_thrust=0.05)
    a, b = PROBLEM.matrices()
    closed = a + b @ gain
    rng = np.random.default_rng(0)
    e = np.zeros((4000, 6))
    spread = np.array([0.05] * 3 + [5e-4] * 3)
    for _ in range(200):  # the loop settles in about 20 steps; 200 leave it stationary
        e = e @ closed.T + (rng.normal(size=e.shape) * spread) @ (b @ gain).T
    measured = e.std(axis=0)
    assert tube.position == pytest.approx(3.0 * measured[:3].max(), rel=0.05)
    assert tube.velocity == pytest.approx(3.0 * measured[3:].max(), rel=0.05)


def test_the_thrust_part_of_the_tube_bounds_every_error_up_to_its_size_and_is_attained():
    """Only thrust error, of size e_u * reference_thrust per axis at most: no sequence of such errors
    drives the deviation past the tube, and the worst one (the impulse response's signs) reaches it."""
    bounds = ErrorBounds(thrust_scale=0.02, k_sigma=3.0)
    gain = ancillary_gain(PROBLEM, 60.0)
    tube = Tube.of(PROBLEM, bounds, gain, reference_thrust=0.05)
    size = bounds.actuation() * 0.05
    a, b = PROBLEM.matrices()
    closed = a + b @ gain
    steps = 400
    responses = [np.linalg.matrix_power(closed, j) @ b for j in range(steps)]  # (6, 3) each
    rng = np.random.default_rng(1)
    for _ in range(20):
        w = rng.choice([-size, size], size=(steps, 3))
        e = sum(responses[steps - 1 - k] @ w[k] for k in range(steps))
        assert np.abs(e[:3]).max() <= tube.position and np.abs(e[3:]).max() <= tube.velocity
    worst = np.array([np.sign(responses[steps - 1 - k][0]) * size for k in range(steps)])  # x position
    e = sum(responses[steps - 1 - k] @ worst[k] for k in range(steps))
    assert e[0] == pytest.approx(tube.position, rel=0.01)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(time_constant=0.0), "time_constant must be a positive number"),
        (dict(time_constant=float("nan")), "time_constant must be a positive number"),
        (dict(time_constant="60"), "time_constant must be a positive number"),
        (dict(reference_thrust=-0.1), "reference_thrust must be in"),
        (dict(reference_thrust=3.0), "reference_thrust must be in"),
        (dict(bounds={"nav_position": 0.05}), "bounds must be an ErrorBounds"),
        (dict(problem=RendezvousProblem()), "problem must be a DockingProblem"),
        (dict(bounds=ErrorBounds(nav_velocity=0.01)), "leaves no speed at the port"),
    ],
)
def test_bad_input_is_refused_by_name(kwargs, message):
    arguments = {"problem": PROBLEM, "bounds": BOUNDS, **kwargs}
    with pytest.raises(ValueError, match=message):
        TubeMPC(**arguments)


def test_the_nominal_flight_is_the_tightened_plan_and_docks():
    starts, goals = search_starts(1)
    mpc = TubeMPC(PROBLEM, BOUNDS)
    flight = fly(PROBLEM, mpc, starts, goals)
    assert mpc.counts == {"cold": 1, "warm": 0, "boxed": 0, "soft": 0, "corridor": 0, "law": 0}
    (states, _controls) = mpc.plans[0]
    # The feedback sees only the observation's float32 rounding: the flight is the plan.
    np.testing.assert_allclose(flight.states[0], states, atol=1e-4)
    assert flight.terminal_distance[0] < 1e-5 and flight.is_success[0]
    assert flight.keep_out_depth[0] == flight.speed_depth[0] == flight.cone_depth[0] == 0.0
    # The plan keeps the tightened speed limit, which the untightened corridor's plan would not.
    v0, v1 = mpc.planned.speed_limit
    speed = np.linalg.norm(states[1:, 3:], axis=1)
    distance = np.linalg.norm(states[1:, :3] - goals[0], axis=1)
    assert np.all(speed <= v0 + v1 * distance + 1e-9)


def test_with_the_navigation_filter_the_nominal_flight_is_unchanged():
    """No noise, no thrust error: the filter sees no innovation (beyond float32 rounding), so the
    filtered tube MPC flies what the unfiltered one does."""
    starts, goals = search_starts(1)
    plain = fly(PROBLEM, TubeMPC(PROBLEM, BOUNDS), starts, goals)
    filtered = fly(PROBLEM, TubeMPC(PROBLEM, BOUNDS, navigation=True), starts, goals)
    np.testing.assert_allclose(filtered.states, plain.states, atol=1e-6)
    assert filtered.is_success[0]


def test_a_start_the_tightened_expert_cannot_solve_cold_is_planned_from_the_corridors_plan():
    """Search start 3: the tightened SCP's first subproblem is infeasible from a cold start; warm-started
    from the untightened corridor's plan it converges (counted as ``warm``), and the flight docks."""
    starts, goals = search_starts(4)
    mpc = TubeMPC(PROBLEM, BOUNDS)
    flight = fly(PROBLEM, mpc, starts[3:4], goals[3:4])
    assert mpc.counts["warm"] == 1 and mpc.counts["cold"] == 0
    assert flight.is_success[0] and flight.speed_depth[0] == 0.0 and flight.cone_depth[0] == 0.0


def test_under_the_dispersions_it_is_sized_for_no_constraint_breaks_and_every_plan_is_answered():
    starts, goals = search_starts(4)
    mpc = TubeMPC(PROBLEM, BOUNDS)
    flight = fly(PROBLEM, mpc, starts, goals, dispersions=DISPERSIONS, dispersion_seed=0)
    assert flight.is_success.all()
    assert flight.keep_out_depth.max() == flight.speed_depth.max() == flight.cone_depth.max() == 0.0
    assert sum(mpc.counts.values()) == 4 and mpc.counts["law"] == 0
    assert len(mpc.plan_seconds) == 4


def test_one_observation_in_one_action_out():
    starts, goals = search_starts(1)
    obs = docking_observation(starts, goals, np.array([0]), PROBLEM.horizon)[0]
    mpc = TubeMPC(PROBLEM, BOUNDS)
    action = mpc(obs.astype(np.float32))
    assert action.shape == (3,) and np.all(np.abs(action) <= 1.0)
    with pytest.raises(ValueError, match="not docking observations"):
        mpc(obs[:-3])
