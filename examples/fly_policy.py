"""Fly a saved family policy from the held-out starts, with and without the CBF filter, against the expert.

    .venv/bin/python families/docking/train.py --out /tmp/bc_docking --runs-log /tmp/bc_docking/runs.jsonl
    .venv/bin/python examples/fly_policy.py --family docking --policy /tmp/bc_docking

The policy is loaded by the family's own train.py (``load_policy``) and flown by its own ``fly`` on
all 128 held-out starts at once; the printed metrics are the family's (rendezvous has no keep-out,
so no filter). The first --plot starts are drawn next to the expert's trajectory (solve_* from the
same start) in the three LVLH planes.
"""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

import torch
from matplotlib.figure import Figure

from cwh_envs.datasets import evaluation_set
from cwh_envs.experts import solve_docking, solve_rendezvous
from cwh_envs.render import plot_trajectories

ROOT = Path(__file__).resolve().parents[1]


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--family", required=True, choices=["rendezvous", "docking"])
    parser.add_argument("--policy", type=Path, required=True, help="a train.py --out dir or its policy.pt")
    parser.add_argument("--plot", type=int, default=3, help="held-out starts to draw")
    parser.add_argument("--out", type=Path, default=Path("results/fly_policy"))
    return parser.parse_args()


def load_family(name: str):
    """The family's train.py as a module (its main() is guarded): load_policy, fly, metrics."""
    spec = importlib.util.spec_from_file_location(f"{name}_train", ROOT / "families" / name / "train.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main() -> None:
    args = parse_args()
    torch.set_num_threads(1)  # a small MLP on 128 rows: more threads only contend on a busy machine
    family = load_family(args.family)
    policy, saved = family.load_policy(args.policy)
    if saved["task"] != family.TASK:
        raise SystemExit(f"{args.policy} holds a {saved['task']} policy, not {args.family}")
    held_out = evaluation_set(family.TASK, family.N_EVAL, problem=family.PROBLEM)
    starts, goals = held_out.starts, held_out.goals

    # Each variant: closed-loop states of all starts (N, H+1, 6) and the family's metrics.
    flown = {}
    if family.TASK == "rendezvous":
        flown["policy"] = (family.fly(policy, starts).states, family.evaluate(policy, held_out))
    else:
        for label, cbf in (("policy", False), ("policy + CBF", True)):
            states = family.fly(policy, starts, goals, cbf).states
            flown[label] = (states, family.evaluate(policy, held_out, cbf))

    metric = family.METRIC
    print(f"{args.family} policy {args.policy} on {len(starts)} held-out starts:")
    print(f"| variant | {metric} | success rate | violation rate | min clearance [m] |")
    print("|---|---:|---:|---:|---:|")
    for label, (_, m) in flown.items():
        violation = f"{m['violation_rate']:.2%}" if "violation_rate" in m else "-"
        clearance = f"{m['min_clearance']:.3f}" if "min_clearance" in m else "-"
        print(f"| {label} | {m[metric]:.4g} | {m['success_rate']:.1%} | {violation} | {clearance} |")

    n_plot = min(args.plot, len(starts))
    figure = Figure(figsize=(13, 4 * n_plot), layout="constrained")
    for i, axes in enumerate(figure.subplots(n_plot, 3, squeeze=False)):
        if family.TASK == "rendezvous":
            expert, goal = solve_rendezvous(starts[i], family.PROBLEM)[0], None
        else:
            expert, goal = solve_docking(starts[i], goals[i], family.PROBLEM)[0], goals[i]
        paths = [states[i] for states, _ in flown.values()] + [expert]
        plot_trajectories(axes, paths, family.PROBLEM, goal=goal, labels=[*flown, "expert"])
        axes[1].set_title(f"held-out start {i}")
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"fly_{args.family}.png"
    figure.savefig(path, dpi=80)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
