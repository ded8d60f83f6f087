"""Fly a saved constrained-docking policy from its first search-split starts against the constrained expert.

    python report.py --policy <train.py --out dir, or its policy.pt> --out trajectories.png [--starts 5]

Left: the 3-D paths around the keep-out sphere (shaded), cloned policy solid, optimal-control
expert dashed, docking points as crosses. Middle: the keep-out clearance ||r|| - R near the chief
(it must stay >= 0; dotted: the 0.5 m standoff). Right: the distance to the docking point. The closed loop is
train.py's own, with the CBF filter exactly as the saved configuration sets it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from cwh_envs.datasets import evaluation_set
from cwh_envs.dynamics import rollout
from cwh_envs.prepare import legend_starts, load_train, policy_title

HERE = Path(__file__).resolve().parent


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--starts", type=int, default=5, help="held-out starts to fly (the first n)")
    args = parser.parse_args()
    train = load_train(HERE)
    problem = train.PROBLEM
    policy, saved = train.load_policy(args.policy)
    cbf = saved["config"]["RUNTIME_CBF_FILTER"]
    held_out = evaluation_set(train.TASK, train.N_EVAL, problem=problem).take(args.starts)
    starts, goals = held_out.starts, held_out.goals
    flown = train.fly(policy, starts, goals, train.safety_filter(saved["config"])).states
    # The expert's trajectories are cached with the split: re-solving takes minutes per start here.
    a, b = problem.matrices()
    expert = np.array(
        [rollout(x0, u, a, b) for x0, u in zip(starts, held_out.trajectory_thrust(), strict=True)]
    )
    time_s = np.arange(problem.horizon + 1) * problem.dt

    fig = plt.figure(figsize=(16, 5))
    paths = fig.add_subplot(1, 3, 1, projection="3d")
    clearance = fig.add_subplot(1, 3, 2)
    distance = fig.add_subplot(1, 3, 3)
    u, v = np.mgrid[0 : 2 * np.pi : 40j, 0 : np.pi : 20j]
    radius = problem.koz_radius
    paths.plot_surface(
        radius * np.cos(u) * np.sin(v),
        radius * np.sin(u) * np.sin(v),
        radius * np.cos(v),
        color="red",
        alpha=0.25,
    )
    for i, color in zip(range(len(starts)), plt.cm.tab10.colors, strict=False):
        paths.plot(*flown[i, :, :3].T, color=color, lw=1.6)
        paths.plot(*expert[i, :, :3].T, color=color, lw=1.0, ls="--")
        paths.scatter(*starts[i, :3], color=color, s=15)
        paths.scatter(*goals[i], color=color, marker="x", s=40)
        clearance.plot(time_s, np.linalg.norm(flown[i, :, :3], axis=1) - radius, color=color, lw=1.6)
        clearance.plot(
            time_s, np.linalg.norm(expert[i, :, :3], axis=1) - radius, color=color, lw=1.0, ls="--"
        )
        distance.plot(time_s, np.linalg.norm(flown[i, :, :3] - goals[i], axis=1), color=color, lw=1.6)
        distance.plot(
            time_s, np.linalg.norm(expert[i, :, :3] - goals[i], axis=1), color=color, lw=1.0, ls="--"
        )
    paths.set(xlabel="x radial [m]", ylabel="y along-track [m]", zlabel="z cross-track [m]")
    robust = saved["config"].get("ROBUST_FILTER_K", 0.0) if cbf else 0.0
    shown = f"robust CBF at {robust:g} sigma" if robust else f"CBF {'on' if cbf else 'off'}"
    paths.set_title(f"policy (solid, {shown}) vs expert (dashed)")
    clearance.axhline(0.0, color="red", lw=1.0)
    clearance.axhline(problem.margin, color="red", lw=0.8, ls=":")
    clearance.set(xlabel="time [s]", ylabel="keep-out clearance ||r|| - R [m]", ylim=(-1.0, 10.0))
    clearance.set_title(f"min clearance {(np.linalg.norm(flown[:, 1:, :3], axis=2) - radius).min():.2f} m")
    final = np.linalg.norm(flown[:, -1, :3] - goals, axis=1)
    distance.set(
        xlabel="time [s]", ylabel="distance to the docking point [m]", yscale="log", ylim=(1e-3, None)
    )
    distance.set_title(
        f"terminal distance: mean {final.mean():.3g} m over these {len(starts)} search-split starts"
    )
    legend_starts(distance, starts, final, plt.cm.tab10.colors)
    record = saved.get("record", {})
    title = policy_title(
        "Constrained docking", record, train, "score {score:.3g}, strict-feasible {strict_feasible}"
    )
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}: {title}".replace("\n", " "))
    return 0


if __name__ == "__main__":
    sys.exit(main())
