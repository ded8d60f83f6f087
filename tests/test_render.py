"""rgb_array frames and the reusable trajectory plot."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from matplotlib.figure import Figure

from cwh_envs.problems import DockingProblem, RendezvousProblem
from cwh_envs.render import plot_trajectories, render_frame


@pytest.mark.parametrize("env_id", ["CWHRendezvous-v0", "CWHDockKOZ-v1"])
def test_rgb_array_is_an_image_of_the_trajectory(env_id):
    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    for _ in range(20):
        env.step(env.action_space.sample())
    frame = env.render()
    assert isinstance(frame, np.ndarray) and frame.dtype == np.uint8 and frame.shape == (320, 960, 3)
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 10  # drawn, not blank
    assert not np.array_equal(first, frame)  # the trajectory grew


def test_keep_out_and_goal_are_drawn():
    trajectory = np.array([[-40.0, 0.0, 0.0, 0, 0, 0], [-20.0, 10.0, 5.0, 0, 0, 0]])
    plain = render_frame(trajectory, RendezvousProblem())
    docking = render_frame(trajectory, DockingProblem(), goal=np.array([8.0, 0.0, 0.0]))
    assert plain.shape == docking.shape == (320, 960, 3)
    reddish = lambda img: np.sum((img[..., 0] > 200) & (img[..., 1] < 220) & (img[..., 2] < 220))  # noqa: E731
    assert reddish(docking) > 10 * max(reddish(plain), 1)  # the translucent keep-out discs


def test_render_without_mode_warns_and_returns_none():
    env = gym.make("CWHRendezvous-v0").unwrapped
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None


def test_plot_trajectories_for_comparison_figures():
    figure = Figure()
    policy = np.cumsum(np.ones((30, 6)), axis=0) - 40.0
    expert = policy * 0.5
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        axes = plot_trajectories(
            figure, [policy, expert], DockingProblem(), goal=np.ones(3) * 5, labels=["policy", "expert"]
        )
    assert len(axes) == 3 and axes[0].get_legend() is not None
    labels = [text.get_text() for text in axes[0].get_legend().get_texts()]
    assert {"policy", "expert", "goal", "keep-out"} <= set(labels)
    with pytest.raises(ValueError, match="three axes"):
        plot_trajectories(figure.subplots(1, 2), [policy], RendezvousProblem())
    with pytest.raises(ValueError, match="labels"):
        plot_trajectories(Figure(), [policy], RendezvousProblem(), labels=["a", "b"])
