"""Issue 28, item 3: one CBF QP for the keep-out, the speed limit and the approach cone."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from proxsuite import proxqp

import cwh_envs  # noqa: F401  (registers the ids)
from cwh_envs.cbf import safe_actions
from cwh_envs.cbf_multi import BARRIERS, project_polytope_box, safe_actions_multi
from cwh_envs.constraints import SPEED_TOLERANCE, cone_terms, speed_margin
from cwh_envs.controllers import pd_action
from cwh_envs.datasets import evaluation_starts
from cwh_envs.problems import DockingProblem
from cwh_envs.rollout import fly
from cwh_envs.vector import CWHDockKOZVectorEnv
from cwh_envs.wrappers import CBFSafetyFilter

PLAIN = DockingProblem()
CONSTRAINED = PLAIN.replace(speed_limit=(0.01, 2 * PLAIN.n), approach_cone=(30.0, 15.0))
U_MAX = PLAIN.u_max


def proxsuite_qp(u0, rows, rhs, u_max):
    """One dense proxsuite QP, converged far below the 1e-9 the comparison asks for."""
    qp = proxqp.dense.QP(3, 0, len(rows), True)
    qp.settings.eps_abs = 1e-12
    qp.settings.eps_rel = 0.0
    qp.settings.check_duality_gap = True
    qp.settings.eps_duality_gap_abs = 1e-12
    qp.settings.eps_duality_gap_rel = 0.0
    qp.settings.max_iter = 1000
    some = len(rows) > 0
    qp.init(
        np.eye(3),
        -u0,
        None,
        None,
        rows if some else None,
        rhs if some else None,
        np.full(len(rows), 1e20) if some else None,
        np.full(3, -u_max),
        np.full(3, u_max),
    )
    qp.solve()
    return qp.results.x, qp.results.info.status == proxqp.QPSolverOutput.PROXQP_SOLVED


def test_the_exact_minimiser_agrees_with_proxsuite_on_random_instances():
    rng = np.random.default_rng(7)
    n = 300
    u0 = rng.normal(0.0, 2.0, (n, 3))
    rows = rng.normal(size=(n, 3, 3)) * rng.uniform(0.01, 10.0, (n, 3, 1))  # unequal scales
    rhs = rng.normal(0.0, 1.5, (n, 3)) * np.linalg.norm(rows, axis=2)
    applies = rng.random((n, 3)) < 0.85
    u, feasible = project_polytope_box(u0, rows, rhs, applies, U_MAX)
    two_or_more = 0
    for i in range(n):
        reference, solved = proxsuite_qp(u0[i], rows[i][applies[i]], rhs[i][applies[i]], U_MAX)
        assert feasible[i] == solved, i
        if solved:
            assert np.max(np.abs(u[i] - reference)) <= 1e-9, i
            slack = (rows[i] @ u[i] - rhs[i]) / np.linalg.norm(rows[i], axis=1)
            two_or_more += np.sum(applies[i] & (np.abs(slack) < 1e-9)) >= 2
    # The instances reach the enumeration stage (two barriers active at once), and some are infeasible.
    assert two_or_more >= 10 and 0 < np.mean(feasible) < 1


def test_with_the_keep_out_alone_it_is_the_single_barrier_filter():
    rng = np.random.default_rng(1)
    positions = rng.normal(size=(200, 3))
    positions *= rng.uniform(6.0, 12.0, (200, 1)) / np.linalg.norm(positions, axis=1, keepdims=True)
    states = np.concatenate([positions, rng.normal(0.0, 0.05, (200, 3))], axis=1)
    nominal = -positions / np.linalg.norm(positions, axis=1, keepdims=True) * 1.5
    a, b = PLAIN.matrices()
    kwargs = dict(koz_radius=PLAIN.koz_radius, margin=PLAIN.margin, u_max=U_MAX)
    single = safe_actions(nominal, states, a, b, **kwargs)
    multi = safe_actions_multi(nominal, states, np.tile([8.0, 0, 0], (200, 1)), a, b, **kwargs)
    assert np.max(np.abs(single.u - multi.u)) <= 1e-12
    np.testing.assert_array_equal(single.infeasible, multi.infeasible)
    assert single.active.any() and not multi.dropped.any()


def pd_flight(problem, n=16):
    starts, goals = evaluation_starts("docking", n, PLAIN)
    return fly(problem, lambda obs: pd_action(obs, PLAIN), starts, goals, cbf_margin=PLAIN.margin), goals


def broken_steps(flight, goals, problem):
    after = flight.states[:, 1:]
    flat, flat_goals = after.reshape(-1, 6), np.repeat(goals, after.shape[1], axis=0)
    speed = speed_margin(flat, flat_goals, problem.speed_limit) < -SPEED_TOLERANCE
    region, slack, _ = cone_terms(flat, flat_goals, problem.approach_cone)
    koz = np.linalg.norm(flat[:, :3], axis=1) < problem.koz_radius
    shape = after.shape[:2]
    return koz.reshape(shape), speed.reshape(shape), (region & (slack < -1e-7)).reshape(shape)


def test_the_pd_law_keeps_the_keep_out_and_the_speed_limit_through_the_filter_but_not_the_cone():
    plain, goals = pd_flight(PLAIN)  # today's keep-out filter alone
    _, speed, cone = broken_steps(plain, goals, CONSTRAINED)
    assert speed.any(axis=1).all() and cone.any(axis=1).all()
    filtered, goals = pd_flight(CONSTRAINED)
    koz, speed, cone = broken_steps(filtered, goals, CONSTRAINED)
    assert not koz.any() and not speed.any()
    # The PD law flies into the cone's region off its axis, where no two-step action can recover:
    # the filter says so, drops the cone (never the others) and the env counts the violation.
    assert cone.any(axis=1).all()
    dropped = filtered.cbf_dropped
    assert dropped[..., 2].any() and not dropped[..., :2].any()
    assert np.array_equal(filtered.cbf_infeasible, dropped.any(axis=2))
    assert not filtered.is_success.any()  # success asks for every constraint met


def test_a_feasible_answer_meets_the_speed_limit_and_the_cone_on_the_prediction():
    rng = np.random.default_rng(3)
    n = 400
    goals = np.tile([8.0, 0.0, 0.0], (n, 1))
    # Near the port, mostly inside the cone, moving slowly: where both constraints bind.
    offsets = np.concatenate([rng.uniform(0.5, 14.0, (n, 1)), rng.normal(0.0, 2.0, (n, 2))], axis=1)
    states = np.concatenate([goals + offsets, rng.normal(0.0, 0.02, (n, 3))], axis=1)
    nominal = rng.uniform(-U_MAX, U_MAX, (n, 3))
    a, b = CONSTRAINED.matrices()
    result = safe_actions_multi(
        nominal,
        states,
        goals,
        a,
        b,
        koz_radius=PLAIN.koz_radius,
        margin=PLAIN.margin,
        u_max=U_MAX,
        speed_limit=CONSTRAINED.speed_limit,
        approach_cone=CONSTRAINED.approach_cone,
    )
    ok = ~result.infeasible
    assert 0.3 < ok.mean() < 1.0 and result.active[ok].mean() > 0.5
    after = states + 0.0
    after = (a @ states.T).T + (b @ result.u.T).T
    two = (a @ after.T).T + (b @ result.u.T).T
    assert np.all(speed_margin(after[ok], goals[ok], CONSTRAINED.speed_limit) >= -SPEED_TOLERANCE)
    region, slack, _ = cone_terms(two[ok], goals[ok], CONSTRAINED.approach_cone)
    assert np.all(slack[region] >= -1e-3)
    assert np.all(np.abs(result.u) <= U_MAX)
    # What it gave up where infeasible is named, and the cone goes before the speed limit.
    dropped = result.dropped[result.infeasible]
    assert dropped.any(axis=1).all() and not (dropped[:, 1] & ~dropped[:, 2]).any()


def test_the_wrapper_and_the_vector_env_report_what_the_filter_dropped():
    env = CBFSafetyFilter(
        gym.make(
            "CWHDockKOZ-v1", speed_limit=CONSTRAINED.speed_limit, approach_cone=CONSTRAINED.approach_cone
        )
    )
    # 10 m from the port, 40 degrees off the cone's axis and closing: the cone cannot be kept.
    goal = np.array([8.0, 0.0, 0.0])
    start = np.concatenate([goal + 9.0 * np.array([np.cos(0.7), np.sin(0.7), 0.0]), [0.0, -0.02, 0.0]])
    env.reset(seed=0, options={"initial_state": start, "goal": goal})
    _, _, _, _, info = env.step(np.zeros(3, np.float32))
    assert info["cbf_infeasible"] and info["cbf_dropped"] == ("cone",)
    assert set(BARRIERS) == {"keep_out", "speed", "cone"}
    vector = CWHDockKOZVectorEnv(
        2, cbf_margin=0.5, speed_limit=CONSTRAINED.speed_limit, approach_cone=CONSTRAINED.approach_cone
    )
    vector.reset(seed=0, options={"initial_state": np.stack([start, start]), "goal": np.stack([goal, goal])})
    _, _, _, _, info = vector.step(np.zeros((2, 3), np.float32))
    np.testing.assert_array_equal(info["cbf_dropped"], [[False, False, True]] * 2)
    plain = CBFSafetyFilter(gym.make("CWHDockKOZ-v1"))
    plain.reset(seed=0)
    assert "cbf_dropped" not in plain.step(np.zeros(3, np.float32))[4]


@pytest.mark.parametrize("bad", [np.zeros(2), np.full(3, np.nan)])
def test_bad_input_is_one_clear_error(bad):
    a, b = CONSTRAINED.matrices()
    with pytest.raises(ValueError, match=r"u_nominal|finite"):
        safe_actions_multi(
            bad, np.ones(6) * 20, np.array([8.0, 0, 0]), a, b, koz_radius=5.0, margin=0.5, u_max=2.0
        )
