"""CBFSafetyFilter: API, exactness against cbf.safe_actions, and what it does (and does not) prevent."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from cwh_envs.cbf import safe_actions
from cwh_envs.controllers import capped_speed_action
from cwh_envs.wrappers import CBFSafetyFilter

CBF_KEYS = {"cbf_active", "cbf_infeasible", "cbf_correction_norm"}
HEAD_ON = {"initial_state": np.array([14.0, 0.0, 0.0, -0.3, 0.0, 0.0]), "goal": np.array([-8.0, 0.0, 0.0])}


def test_gymnasiums_checker_passes_with_the_filter():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # check_env always flags a wrapped env (by design); that one message is the only exemption.
        warnings.filterwarnings("ignore", message=r".*is different from the unwrapped version")
        check_env(CBFSafetyFilter(gym.make("CWHDockKOZ-v1").unwrapped))


@pytest.mark.needs("sb3")
def test_sb3s_checker_passes_with_the_filter():
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3_check_env(CBFSafetyFilter(gym.make("CWHDockKOZ-v1").unwrapped))
        sb3_check_env(CBFSafetyFilter(gym.make("CWHDockKOZ-v1")))


def test_spec_recreates_the_wrapped_env():
    env = CBFSafetyFilter(gym.make("CWHDockKOZ-v1"), margin=1.0)
    again = gym.make(env.spec)
    assert isinstance(again, CBFSafetyFilter) and again.margin == 1.0


def test_bad_arguments():
    with pytest.raises(ValueError, match="margin"):
        CBFSafetyFilter(gym.make("CWHDockKOZ-v1"), margin=-0.1)
    with pytest.raises(ValueError, match="margin"):
        CBFSafetyFilter(gym.make("CWHDockKOZ-v1"), margin=float("nan"))
    for not_a_number in (True, np.float64(np.inf), "0.5"):  # a bool is not a number of metres
        with pytest.raises(ValueError, match="margin"):
            CBFSafetyFilter(gym.make("CWHDockKOZ-v1"), margin=not_a_number)
    with pytest.raises(TypeError, match="CWHDockKOZ env"):
        CBFSafetyFilter(gym.make("CWHRendezvous-v0"))


def test_default_margin_is_the_problems():
    assert CBFSafetyFilter(gym.make("CWHDockKOZ-v1")).margin == 0.5
    assert CBFSafetyFilter(gym.make("CWHDockKOZ-v1", margin=0.8)).margin == 0.8


def test_filtered_step_is_safe_actions_applied_to_the_model():
    env = CBFSafetyFilter(gym.make("CWHDockKOZ-v1"), margin=0.5)
    base = env.unwrapped
    a, b = base.problem.matrices()
    env.reset(options=HEAD_ON)
    edited = 0
    for _ in range(15):
        x = base.state
        nominal = np.array([-1.0, 0.2, 0.0], dtype=np.float32)  # keep pushing at the sphere
        _, _, _, _, info = env.step(nominal)
        expected = safe_actions(nominal * 2.0, x, a, b, koz_radius=5.0, margin=0.5, u_max=2.0)
        assert CBF_KEYS <= set(info)
        assert info["cbf_active"] == bool(expected.active)
        assert info["cbf_correction_norm"] == pytest.approx(float(expected.correction_norm), abs=1e-12)
        np.testing.assert_allclose(base.state, a @ x + b @ expected.u, rtol=1e-12, atol=1e-12)
        edited += info["cbf_active"]
    assert edited > 0


def test_filter_is_transparent_far_from_the_keep_out():
    start = {"initial_state": np.array([-80.0, 40.0, 10.0, 0.0, 0.0, 0.0]), "goal": np.array([8.0, 0.0, 0.0])}
    plain, filtered = gym.make("CWHDockKOZ-v1"), CBFSafetyFilter(gym.make("CWHDockKOZ-v1"))
    plain.reset(options=start)
    filtered.reset(options=start)
    rng = np.random.default_rng(0)
    for _ in range(20):
        action = rng.uniform(-1, 1, 3).astype(np.float32)
        obs_p, rew_p, *_ = plain.step(action)
        obs_f, rew_f, *_, info = filtered.step(action)
        np.testing.assert_array_equal(obs_p, obs_f)
        assert rew_p == rew_f and not info["cbf_active"] and info["cbf_correction_norm"] == 0.0


def run_batch(policy, cbf_margin: float | None, num_envs: int = 64, head_on: bool = False, seed: int = 0):
    """One episode per row of the native vector env (same filter function as the wrapper).

    ``policy`` is a speed cap for :func:`~cwh_envs.controllers.capped_speed_action` or ``"random"``. ``head_on`` moves
    each sampled start to the antipode of its goal, so the straight path crosses the centre.
    Returns per-call arrays (H, N) of ``in_koz``, ``clearance`` and ``cbf_infeasible`` and the final info.
    """
    env = gym.make_vec(
        "CWHDockKOZ-v1", num_envs=num_envs, vectorization_mode="vector_entry_point", cbf_margin=cbf_margin
    )
    obs, _ = env.reset(seed=seed)
    if head_on:
        goals = env.unwrapped.goals
        distance = np.linalg.norm(env.unwrapped.states[:, :3], axis=1, keepdims=True)
        starts = np.concatenate(
            [-goals / np.linalg.norm(goals, axis=1, keepdims=True) * distance, np.zeros((num_envs, 3))],
            axis=1,
        )
        obs, _ = env.reset(options={"initial_state": starts, "goal": goals})
    rng = np.random.default_rng(seed)
    trace = {"in_koz": [], "clearance": [], "cbf_infeasible": []}
    terminated = np.zeros(num_envs, dtype=bool)
    while not terminated.all():
        action = (
            rng.uniform(-1, 1, (num_envs, 3))
            if policy == "random"
            else capped_speed_action(obs, policy, env.unwrapped.problem)
        )
        obs, _, terminated, _, info = env.step(action.astype(np.float32))
        for key in trace:
            trace[key].append(info.get(key, np.zeros(num_envs, dtype=bool)))
    return {key: np.array(value) for key, value in trace.items()}, info


@pytest.mark.parametrize("policy", ["random", 0.3])
def test_barrier_holds_two_steps_ahead_whenever_it_is_feasible(policy):
    """Under Euler, u_t fixes r_{t+2} exactly, so a feasible barrier at t puts x_{t+2} outside R + margin.

    Measured: the keep-out is entered only two steps after a step where no thrust in the box could
    satisfy the barrier (an approach too fast to stop) -- never while the filter is feasible.
    """
    trace, _ = run_batch(policy, cbf_margin=0.5, num_envs=128)
    guarded = ~trace["cbf_infeasible"][:-1]  # call t-1 feasible -> the state after call t is guarded
    assert (trace["clearance"][1:][guarded] >= 0.5 - 1e-9).all()
    assert not (trace["in_koz"][1:] & guarded).any()
    if policy == 0.3:
        assert trace["cbf_infeasible"].any()  # the fast policy does meet unstoppable approaches


def test_filter_keeps_slow_approaches_out_of_the_keep_out():
    """Measured: a naive policy flying head-on through the sphere at <= 0.05 m/s never enters it when filtered."""
    plain, _ = run_batch(0.05, None, head_on=True)
    safe, info = run_batch(0.05, 0.5, head_on=True)
    assert plain["in_koz"].any(axis=0).all()  # unfiltered, every episode crosses the keep-out
    assert not safe["in_koz"].any() and (info["violation_rate"] == 0.0).all()
    assert (info["min_clearance"] >= 0.0).all()


def test_filter_cannot_stop_fast_approaches():
    """Measured limitation: two-step lookahead with |u_i| <= 2 N cannot stop a 0.3 m/s head-on approach."""
    safe, _ = run_batch(0.3, 0.5, head_on=True)
    assert safe["in_koz"].any(axis=0).mean() > 0.9
    assert safe["cbf_infeasible"].any(axis=0).all()  # and it says so in info


def test_random_rollouts_through_the_wrapper():
    """Random-action episodes from sampled starts through the wrapper: entries follow infeasibility only."""
    env = CBFSafetyFilter(gym.make("CWHDockKOZ-v1"))
    env.action_space.seed(0)
    for episode in range(4):
        env.reset(seed=episode)
        infeasible_before, terminated = False, False
        while not terminated:
            _, _, terminated, _, info = env.step(env.action_space.sample())
            assert CBF_KEYS <= set(info)
            assert not info["in_koz"] or infeasible_before
            infeasible_before = info["cbf_infeasible"]
