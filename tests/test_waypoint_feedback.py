"""WaypointFeedback: the minimum-energy law through position waypoints. Without waypoints it is the
closed-form law; on the nominal model, unclipped, it passes each waypoint at its step and docks at
rest at H; its waypoints sit where they are declared; bad routes are refused by name."""

import numpy as np
import pytest

from cwh_envs.controllers import CONE_ROUTE, MinEnergyFeedback, Waypoint, WaypointFeedback
from cwh_envs.problems import DockingProblem
from cwh_envs.rollout import fly

CONSTRAINED = DockingProblem(speed_limit=(0.01, 2 * DockingProblem().n), approach_cone=(30.0, 15.0))


def far_side(n: int, seed: int = 0, distance: float = 60.0):
    """n docking points 8 m out on random bearings and starts at rest ``distance`` m out, behind the
    keep-out and off the axis (rotated 30 degrees from straight behind)."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    side = np.cross(axis, rng.normal(size=(n, 3)))
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    where = -np.cos(np.radians(30)) * axis + np.sin(np.radians(30)) * side
    starts = np.concatenate([distance * where, np.zeros((n, 3))], axis=1)
    return starts, 8.0 * axis


def observations(problem, n: int = 64, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    starts, goals = far_side(n, seed)
    tau = rng.integers(1, problem.horizon + 1, size=(n, 1)) / problem.horizon
    state = starts + rng.normal(scale=[5, 5, 5, 0.02, 0.02, 0.02], size=starts.shape)
    return np.concatenate([state, goals, tau], axis=1)


def test_without_waypoints_it_is_the_closed_form_law():
    obs = observations(CONSTRAINED)
    route, law = WaypointFeedback(CONSTRAINED, ()), MinEnergyFeedback(CONSTRAINED)
    np.testing.assert_allclose(route.thrust(obs), law.thrust(obs), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(route(obs[3]), law(obs[3]), rtol=1e-9, atol=1e-12)  # one observation
    batched = obs[:6].reshape(2, 3, -1)
    np.testing.assert_allclose(route.thrust(batched), law.thrust(obs[:6]).reshape(2, 3, 3), rtol=1e-9)
    assert np.abs(route.thrust(obs)).max() > 1e-3  # the law thrusts: not zeros compared


def test_unclipped_on_the_nominal_model_it_passes_each_waypoint_and_docks():
    """On the axis (angle 0) a waypoint does not move with the chaser: the re-planned law meets it
    exactly at its step, and ends at (g, 0), as the open-loop minimum-energy plan would."""
    problem = CONSTRAINED.replace(u_max=1e6)  # no clipping: the law as planned
    route = (Waypoint(120, 30.0, 0.0), Waypoint(200, 6.0, 0.0), Waypoint(230, 1.0, 0.0))
    starts, goals = far_side(8)
    flight = fly(problem, WaypointFeedback(problem, route), starts, goals)
    axis = goals / np.linalg.norm(goals, axis=1, keepdims=True)
    for w in route:
        np.testing.assert_allclose(flight.states[:, w.step, :3], goals + w.distance * axis, atol=1e-6)
    np.testing.assert_allclose(flight.states[:, -1, :3], goals, atol=1e-6)
    np.testing.assert_allclose(flight.states[:, -1, 3:], 0.0, atol=1e-8)
    law = fly(problem, MinEnergyFeedback(problem), starts, goals)
    assert (
        np.linalg.norm(law.states[:, 120, :3] - (goals + 30 * axis), axis=1).min() > 5
    )  # the route moved it


def test_waypoints_sit_at_their_distance_and_angle_on_the_chasers_side():
    obs = observations(CONSTRAINED, n=16)
    positions = WaypointFeedback(CONSTRAINED).waypoint_positions(obs)  # (16, 8, 3)
    goals, chaser = obs[:, None, 6:9], obs[:, None, :3]
    axis = goals / np.linalg.norm(goals, axis=-1, keepdims=True)
    offset = positions - goals
    distance = np.linalg.norm(offset, axis=-1)
    np.testing.assert_allclose(distance, np.broadcast_to([w.distance for w in CONE_ROUTE], distance.shape))
    angle = np.degrees(np.arccos(np.clip(np.sum(offset * axis, axis=-1) / distance, -1, 1)))
    np.testing.assert_allclose(
        angle,
        np.broadcast_to([w.angle_deg for w in CONE_ROUTE], angle.shape),
        atol=1e-5,  # arccos near 1 keeps ~1e-6 degrees
    )

    def off_axis(x):
        return x - np.sum(x * axis, axis=-1, keepdims=True) * axis

    # coplanar with the axis and the chaser, on its side
    side = off_axis(chaser - goals)
    np.testing.assert_allclose(np.cross(off_axis(offset), side), 0.0, atol=1e-9)
    tilted = [i for i, w in enumerate(CONE_ROUTE) if w.angle_deg % 180]
    assert np.all(np.sum(off_axis(offset)[:, tilted] * side, axis=-1) > 0)
    on_axis = obs[:1].copy()
    on_axis[0, :3] = 3.0 * on_axis[0, 6:9]  # on the axis: a fixed perpendicular, finite
    assert np.all(np.isfinite(WaypointFeedback(CONSTRAINED).thrust(on_axis)))


@pytest.mark.parametrize(
    ("route", "message"),
    [
        ((Waypoint(100, 10.0, 0.0), Waypoint(100, 5.0, 0.0)), "strictly increasing"),
        ((Waypoint(150, 10.0, 0.0), Waypoint(100, 5.0, 0.0)), "strictly increasing"),
        ((Waypoint(0, 10.0, 0.0),), r"step must be an integer in \[1, 239\]"),
        ((Waypoint(240, 10.0, 0.0),), r"step must be an integer in \[1, 239\]"),
        ((Waypoint(10.5, 10.0, 0.0),), "step must be an integer"),
        ((Waypoint(100, -1.0, 0.0),), "finite distance >= 0"),
        ((Waypoint(100, 1.0, float("nan")),), "finite angle"),
        (((100, 1.0, 0.0),), r"Waypoint\(step, distance, angle_deg\)"),
    ],
)
def test_a_bad_route_is_refused_by_name(route, message):
    with pytest.raises(ValueError, match=message):
        WaypointFeedback(CONSTRAINED, route)


def test_rendezvous_observations_and_a_spent_clock_are_refused():
    law = WaypointFeedback(CONSTRAINED)
    with pytest.raises(ValueError, match="docking observations"):
        law(np.zeros(7))
    obs = observations(CONSTRAINED, n=1)
    obs[0, -1] = 0.0
    with pytest.raises(ValueError, match="time-to-go"):
        law(obs)
