"""The baselines a guidance engineer brings first: the closed-form shrinking-horizon minimum-energy
law and receding-horizon MPC, against the optimal-control experts they are built from."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import cwh_envs  # noqa: F401  (registers the ids)
from cwh_envs import experts
from cwh_envs.controllers import MinEnergyFeedback, min_energy_gains
from cwh_envs.datasets import evaluation_starts
from cwh_envs.mpc import RecedingHorizon
from cwh_envs.observations import docking_observation, rendezvous_observation
from cwh_envs.problems import DockingProblem, RendezvousProblem
from cwh_envs.rollout import control_effort, fly

CONSTRAINED = DockingProblem(speed_limit=(0.01, 2 * DockingProblem().n), approach_cone=(30.0, 15.0))


@pytest.fixture(scope="module")
def rendezvous_starts():
    starts, _ = evaluation_starts("rendezvous", 12, RendezvousProblem())
    return starts


@pytest.fixture(scope="module")
def docking_starts():
    return evaluation_starts("docking", 4, DockingProblem())


def unclipped(controls, problem) -> bool:
    return np.abs(controls).max() < problem.u_max


def test_the_gain_table_at_the_full_horizon_is_the_experts_pseudo_inverse():
    problem = DockingProblem()
    gains = min_energy_gains(problem)
    model = experts.linear_model(problem)
    np.testing.assert_allclose(gains.target_gain[-1], model.terminal_pinv[:3], rtol=0, atol=1e-15)
    np.testing.assert_allclose(gains.state_gain[-1], model.terminal_pinv[:3] @ model.powers[-1], atol=1e-15)


def test_the_law_is_the_experts_first_control_at_every_step_when_not_clipped(rendezvous_starts):
    """At every state of an unsaturated expert trajectory, the law equals the first control of the
    expert re-solved from that state over the steps left (m >= 2: the experts need two steps)."""
    problem = RendezvousProblem()
    law = MinEnergyFeedback(problem)
    checked = 0
    for x0 in rendezvous_starts:
        states, controls = experts.solve_rendezvous(x0, problem)
        if not unclipped(controls, problem):
            continue
        for k in range(problem.horizon - 1):
            obs = rendezvous_observation(states[k], k, problem.horizon, dtype=np.float64)
            _, replanned = experts.solve_rendezvous(states[k], problem, horizon=problem.horizon - k)
            np.testing.assert_allclose(law.thrust(obs), replanned[0], rtol=0, atol=1e-10)
            np.testing.assert_allclose(law.thrust(obs), controls[k], rtol=0, atol=1e-10)
            checked += 1
    assert checked >= 2 * (problem.horizon - 1)


def test_the_docking_law_aims_at_the_observed_goal_as_the_expert_does_where_nothing_binds():
    """On a near-side start the keep-out never binds, so the docking expert is the unconstrained
    minimum-energy solution and the law is its first control at every step."""
    problem = DockingProblem()
    goal = np.array([0.0, 8.0, 0.0])
    x0 = np.array([3.0, 40.0, 5.0, 0.0, 0.0, 0.0])  # on the goal's side: the straight path misses the sphere
    states, controls = experts.solve_docking(x0, goal, problem)
    assert unclipped(controls, problem)
    law = MinEnergyFeedback(problem)
    for k in range(0, problem.horizon - 1, 7):
        obs = docking_observation(states[k], goal, k, problem.horizon, dtype=np.float64)
        np.testing.assert_allclose(law.thrust(obs), controls[k], rtol=0, atol=1e-10)


def test_the_law_through_gym_make_flies_the_expert_and_refuses_a_time_to_go_outside_the_horizon():
    problem = RendezvousProblem()
    env = gym.make("CWHRendezvous-v0")
    obs, _ = env.reset(seed=3)
    _, controls = experts.solve_rendezvous(env.unwrapped.state, problem)
    law = MinEnergyFeedback(problem)
    terminated = False
    while not terminated:
        obs, _, terminated, _, info = env.step(law(obs))
    if unclipped(controls, problem):
        assert info["terminal_distance"] < 1e-4  # float32 observations: ~1e-7 relative per step
    with pytest.raises(ValueError, match="time-to-go"):
        law(np.array([0, 0, 0, 0, 0, 0, 1.5]))


@pytest.mark.parametrize("task", ["rendezvous", "docking"])
def test_mpc_on_the_nominal_model_flies_the_open_loop_expert(task, rendezvous_starts, docking_starts):
    """Bellman: the tail of an optimal plan is optimal for the rest, so MPC re-solving from each state
    flies the expert's trajectory. Through ``fly`` it re-plans from float32 observations (~1e-7
    relative), which the saturated rendezvous plans amplify: tolerances 5e-3 m and 0.1 % of the energy
    (rendezvous); docking's SCP stops once its iterates move less than 1e-3 m, its tolerance here."""
    if task == "rendezvous":
        problem, starts, goals = RendezvousProblem(), rendezvous_starts, None
        plans = [experts.solve_rendezvous(x0, problem) for x0 in starts]
        position_tol, energy_tol = 5e-3, 1e-3
    else:
        problem, (starts, goals) = DockingProblem(), docking_starts
        plans = [experts.solve_docking(x0, g, problem) for x0, g in zip(starts, goals, strict=True)]
        position_tol, energy_tol = 1e-3, 1e-6
    mpc = RecedingHorizon(problem)
    flight = fly(problem, mpc, starts, goals)
    expert_states = np.stack([s for s, _ in plans])
    expert_thrust = np.stack([u for _, u in plans])
    assert np.abs(flight.states[..., :3] - expert_states[..., :3]).max() < position_tol
    energy, _ = control_effort(flight.thrust, problem)
    expert_energy, _ = control_effort(expert_thrust, problem)
    np.testing.assert_allclose(energy, expert_energy, rtol=energy_tol)
    assert flight.terminal_distance.max() < 1e-5
    assert mpc.fallbacks.sum() == mpc.infeasible.sum() and mpc.soft.sum() == 0  # each on its previous plan
    assert len(mpc.solve_seconds) == mpc.solves.sum() == len(starts) * (problem.horizon - 1)  # m >= 2
    if task == "docking":
        assert flight.violation_rate.max() == 0.0


def test_mpc_keeps_every_constraint_of_constrained_docking_on_a_handful_of_starts(docking_starts):
    starts, goals = docking_starts[0][:3], docking_starts[1][:3]
    flight = fly(CONSTRAINED, RecedingHorizon(CONSTRAINED), starts, goals)
    assert flight.is_success.all()
    assert flight.violation_rate.max() == 0.0
    assert flight.speed_violation_rate.max() == 0.0
    assert flight.cone_violation_rate.max() == 0.0
    assert flight.min_clearance.min() >= 0.0


def test_a_failed_resolve_flies_the_previous_plan_or_the_soft_expert_as_asked():
    """A start no box thrust can bring home: every hard re-solve fails. The controller's default
    re-plans with the soft-terminal expert where it has no plan yet, then flies that plan; asked for
    the soft expert (DAgger's labels), it re-plans softly from every state. The counters say which."""
    problem = RendezvousProblem()
    far = np.array([[400.0, 300.0, 100.0, 0.3, 0.3, 0.1]])
    with pytest.raises(experts.Infeasible):
        experts.solve_rendezvous(far[0], problem)
    _, soft = experts.solve_rendezvous_soft(far[0], problem)
    steps = problem.horizon - 1  # solves: the last step is the law's
    planned = RecedingHorizon(problem)
    flight = fly(problem, planned, far)
    assert planned.infeasible[0] == planned.solves[0] == steps
    assert planned.soft[0] == 1 and planned.fallbacks[0] == steps - 1
    np.testing.assert_allclose(
        flight.thrust[0, :steps], soft[:steps], atol=1e-6
    )  # the first soft plan, flown
    relabelling = RecedingHorizon(problem, on_failure="soft")
    flight = fly(problem, relabelling, far)
    assert relabelling.infeasible[0] == relabelling.soft[0] == steps and relabelling.fallbacks[0] == 0
    np.testing.assert_allclose(flight.thrust[0, 0], soft[0], atol=1e-6)  # float32 observation
    with pytest.raises(ValueError, match="on_failure"):
        RecedingHorizon(problem, on_failure="pray")


def test_the_soft_terminal_experts_equal_the_hard_ones_where_both_answer(rendezvous_starts, docking_starts):
    problem = RendezvousProblem()
    saturated = 0
    for x0 in rendezvous_starts:
        _, hard = experts.solve_rendezvous(x0, problem)
        states, soft = experts.solve_rendezvous_soft(x0, problem)
        saturated += not unclipped(hard, problem)
        np.testing.assert_allclose(soft, hard, rtol=0, atol=1e-9)
        assert np.abs(states[-1]).max() < 1e-9
    assert saturated >= 1  # the penalty's weight covers starts that ride the box
    for x0, goal in zip(*docking_starts, strict=True):
        hard = experts.scp_docking(x0, goal)
        soft = experts.soft_docking(x0, goal)
        np.testing.assert_allclose(soft.controls, hard.controls, rtol=0, atol=1e-6)


def test_the_soft_terminal_experts_answer_where_the_hard_ones_cannot():
    """From a start no box thrust brings home, the soft expert's answer is the penalised optimum: no
    worse than coasting, nor than the unconstrained minimum-energy thrust clipped to the box."""
    problem = RendezvousProblem()
    model = experts.linear_model(problem)
    far = np.array([400.0, 300.0, 100.0, 0.3, 0.3, 0.1])
    weights = experts._soft_weights("rendezvous")

    def objective(controls):
        return 0.5 * controls.ravel() @ controls.ravel() + weights @ np.abs(model.rollout(far, controls)[-1])

    states, controls = experts.solve_rendezvous_soft(far, problem)
    assert np.abs(controls).max() <= problem.u_max
    np.testing.assert_allclose(states, model.rollout(far, controls))
    clipped = np.clip(model.min_energy(far, np.zeros(6)), -problem.u_max, problem.u_max)
    assert objective(controls) <= min(objective(np.zeros_like(controls)), objective(clipped)) * (1 - 1e-3)
    docking = DockingProblem()
    goal = np.array([8.0, 0.0, 0.0])
    inside = np.array([-5.0, 1.0, 0.0, 0.02, 0.0, 0.0])  # in the keep-out's margin already
    with pytest.raises(experts.Infeasible):
        experts.scp_docking(inside, goal, docking)
    solution = experts.soft_docking(inside, goal, docking)
    assert np.linalg.norm(solution.states[-1, :3] - goal) < 1e-6
    # step 2 is the first the thrust moves: it is pushed out as far as the box allows, then held out
    coasting = experts.linear_model(docking).rollout(inside, np.zeros((docking.horizon, 3)))
    distances = np.linalg.norm(solution.states[:, :3], axis=1)
    assert distances[2] > np.linalg.norm(coasting[2, :3]) + 0.1
    assert distances[3:].min() >= docking.koz_radius + docking.margin - 1e-6


def test_a_warm_start_at_the_optimum_converges_in_one_iteration(docking_starts):
    x0, goal = docking_starts[0][0], docking_starts[1][0]
    cold = experts.scp_docking(x0, goal)
    warm = experts.scp_docking(x0, goal, warm_start=cold.controls)
    assert warm.iterations == 1
    np.testing.assert_allclose(warm.controls, cold.controls, rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match="warm_start"):
        experts.scp_docking(x0, goal, warm_start=cold.controls[:-1])


def test_answer_solves_each_unrelated_state_from_its_own_warm_start_and_never_flies_it():
    """``answer``: DAgger's subsample relabelling. Each row is the expert re-solved from its state
    over its steps to go, linearised about the warm start given; a row the hard expert cannot answer
    gets the soft expert's control even under the controller's default on_failure (the warm start
    is another policy's thrust, not a plan of this expert); the last step is the law's."""
    problem = RendezvousProblem()
    far = np.array([400.0, 300.0, 100.0, 0.3, 0.3, 0.1])
    _, soft = experts.solve_rendezvous_soft(far, problem)
    mpc = RecedingHorizon(problem)  # on_failure="previous_plan"
    obs = rendezvous_observation(far, 0, problem.horizon, dtype=np.float64)
    action = mpc.answer(obs[None], [np.zeros((problem.horizon, 3))])
    np.testing.assert_allclose(action[0] * problem.u_max, soft[0], atol=1e-9)
    assert mpc.infeasible[0] == mpc.soft[0] == 1 and mpc.fallbacks[0] == 0

    starts, goals = evaluation_starts("docking", 1, DockingProblem())
    mpc = RecedingHorizon(CONSTRAINED, on_failure="soft")
    law, u_max = MinEnergyFeedback(CONSTRAINED), CONSTRAINED.u_max
    flight = fly(CONSTRAINED, lambda o: np.clip(law.thrust(o) / u_max, -1, 1), starts, goals)
    steps = np.array([0, 150, CONSTRAINED.horizon - 1])
    states = docking_observation(
        flight.states[0, steps], goals[0], steps, CONSTRAINED.horizon, dtype=np.float64
    )
    warm = [flight.thrust[0, k:] for k in steps]
    actions = mpc.answer(states, warm)
    for row, k in enumerate(steps[:2]):
        planned = mpc.planned.replace(horizon=CONSTRAINED.horizon - int(k))
        try:
            controls = experts.solve_docking(states[row, :6], goals[0], planned, warm_start=warm[row])[1]
        except experts.Infeasible:
            controls = experts.soft_docking(states[row, :6], goals[0], planned, warm_start=warm[row]).controls
        np.testing.assert_allclose(actions[row], np.clip(controls[0] / u_max, -1, 1), atol=1e-9)
    np.testing.assert_allclose(actions[2:], np.clip(law.thrust(states[2:]) / u_max, -1, 1), atol=1e-12)
    assert mpc.solves.tolist() == [1, 1, 0] and mpc.plans == [None] * 3  # no row goes on as an episode
    with pytest.raises(ValueError, match="steps to go"):
        mpc.answer(states[:1], [flight.thrust[0, 1:]])
    with pytest.raises(ValueError, match="rows"):
        mpc.answer(states, warm[:2])
