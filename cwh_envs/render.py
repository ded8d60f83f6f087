"""Trajectory pictures: the envs' ``rgb_array`` frames and reusable comparison plots.

Everything draws on explicit ``Figure`` / ``FigureCanvasAgg`` objects, never through pyplot, so
rendering touches no global matplotlib state and works headless in worker processes.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Circle

# (horizontal, vertical) state indices of the three LVLH projections.
PROJECTIONS = ((0, 1), (0, 2), (1, 2))
AXIS_NAMES = ("x radial [m]", "y along-track [m]", "z cross-track [m]")


def plot_trajectories(
    target: Figure | Sequence[Axes],
    trajectories: Sequence[np.ndarray],
    problem,
    goal: np.ndarray | None = None,
    labels: Sequence[str] | None = None,
) -> list[Axes]:
    """Draw trajectories in the x-y, x-z and y-z planes with the target, keep-out and goal.

    Args:
        target: a figure (three side-by-side axes are added) or three axes to draw on.
        trajectories: arrays (K, 6) or (K, 3) of states; each starts at a dot and ends at a cross.
        problem: a :class:`~cwh_envs.problems.RendezvousProblem` or ``DockingProblem``; a keep-out
            disc (the sphere's projection) is drawn when it has ``koz_radius``.
        goal: the docking point (3,), drawn as a star; without it the origin is starred.
        labels: one legend entry per trajectory (e.g. ``["policy", "expert"]``).

    Returns:
        The three axes, for further styling.
    """
    axes = list(target.subplots(1, 3)) if isinstance(target, Figure) else list(target)
    if len(axes) != 3:
        raise ValueError(f"need three axes (one per projection), got {len(axes)}")
    if labels is not None and len(labels) != len(trajectories):
        raise ValueError(f"got {len(labels)} labels for {len(trajectories)} trajectories")
    koz = getattr(problem, "koz_radius", None)
    star = np.zeros(3) if goal is None else np.asarray(goal, dtype=np.float64)
    for ax, (i, j) in zip(axes, PROJECTIONS, strict=True):
        if koz is not None:
            ax.add_patch(Circle((0.0, 0.0), koz, color="tab:red", alpha=0.3, label="keep-out"))
        for n, trajectory in enumerate(trajectories):
            path = np.asarray(trajectory, dtype=np.float64)
            (line,) = ax.plot(path[:, i], path[:, j], lw=1.2, label=None if labels is None else labels[n])
            ax.plot(path[0, i], path[0, j], "o", color=line.get_color(), ms=4)
            ax.plot(path[-1, i], path[-1, j], "x", color=line.get_color(), ms=6)
        ax.plot(star[i], star[j], "*", color="k", ms=10, label="target" if goal is None else "goal")
        ax.set_xlabel(AXIS_NAMES[i])
        ax.set_ylabel(AXIS_NAMES[j])
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, lw=0.3)
    if labels is not None or koz is not None:
        axes[0].legend(loc="best", fontsize="small")
    return axes


def render_frame(
    trajectory: np.ndarray,
    problem,
    goal: np.ndarray | None = None,
    width: int = 960,
    height: int = 320,
) -> np.ndarray:
    """One trajectory drawn by :func:`plot_trajectories` as an RGB image, uint8 (height, width, 3)."""
    dpi = 80
    figure = Figure(figsize=(width / dpi, height / dpi), dpi=dpi, layout="constrained")
    canvas = FigureCanvasAgg(figure)
    plot_trajectories(figure, [trajectory], problem, goal=goal)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()
