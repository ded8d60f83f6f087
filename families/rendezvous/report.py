"""Fly a saved rendezvous policy from its first search-split starts against the expert (paper Fig. trajectories).

    python report.py --policy <train.py --out dir, or its policy.pt> --out trajectories.png [--starts 5]

Left: the 3-D paths in LVLH, cloned policy solid, optimal-control expert dashed. Right: the
position norm over the 800 s horizon. The closed loop is train.py's own (same model, clipping).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from cwh_envs.datasets import evaluation_starts
from cwh_envs.experts import solve_rendezvous
from cwh_envs.prepare import legend_starts, load_train, policy_title

HERE = Path(__file__).resolve().parent


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--starts", type=int, default=5, help="held-out starts to fly (the first n)")
    args = parser.parse_args()
    train = load_train(HERE)
    policy, saved = train.load_policy(args.policy)
    starts, _ = evaluation_starts(train.TASK, train.N_EVAL, problem=train.PROBLEM)
    starts = starts[: args.starts]
    flown = train.fly(policy, starts).states
    expert = np.array([solve_rendezvous(x0, train.PROBLEM)[0] for x0 in starts])
    time_s = np.arange(train.PROBLEM.horizon + 1) * train.PROBLEM.dt

    fig = plt.figure(figsize=(12, 5))
    paths = fig.add_subplot(1, 2, 1, projection="3d")
    norms = fig.add_subplot(1, 2, 2)
    for i, color in zip(range(len(starts)), plt.cm.tab10.colors, strict=False):
        paths.plot(*flown[i, :, :3].T, color=color, lw=1.6)
        paths.plot(*expert[i, :, :3].T, color=color, lw=1.0, ls="--")
        paths.scatter(*starts[i, :3], color=color, s=15)
        norms.plot(time_s, np.linalg.norm(flown[i, :, :3], axis=1), color=color, lw=1.6)
        norms.plot(time_s, np.linalg.norm(expert[i, :, :3], axis=1), color=color, lw=1.0, ls="--")
    paths.scatter(0, 0, 0, color="k", marker="*", s=80)
    paths.set(xlabel="x radial [m]", ylabel="y along-track [m]", zlabel="z cross-track [m]")
    paths.set_title("policy (solid) vs expert (dashed)")
    norms.set(xlabel="time [s]", ylabel="||r|| [m]")
    final = np.linalg.norm(flown[:, -1, :3], axis=1)
    norms.set_title(
        f"terminal distance: mean {final.mean():.3g} m over these {len(starts)} search-split starts"
    )
    legend_starts(norms, starts, final, plt.cm.tab10.colors)
    title = policy_title(
        "Rendezvous", saved.get("record", {}), train, "mean terminal distance {mean_terminal_distance:.3g} m"
    )
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}: {title}".replace("\n", " "))
    return 0


if __name__ == "__main__":
    sys.exit(main())
