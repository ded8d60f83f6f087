"""Where a rendezvous policy's terminal error sits: the starts whose expert rides the thrust box.

    OMP_NUM_THREADS=1 .venv/bin/python results/agent-levers/where_error_sits.py RUN_DIR... \
        > results/agent-levers/rendezvous_error.md

Each RUN_DIR is a rendezvous run directory (its ``out/policy.pt``: a campaign's or a reseed's). The
policies and the leaderboard's classical rows (receding-horizon MPC, cwh_envs.mpc.RecedingHorizon;
the closed-form law, cwh_envs.controllers.MinEnergyFeedback, clipped to the box; the PD law) fly
the sealed test split (1024 starts); a start counts as *saturated* when the open-loop expert's
thrust from it reaches the box (|u| >= 0.999 u_max on some axis at some step): there the law,
which ignores the box until it clips, and a correction bounded by the same box, must plan around
it. Per controller, the mean, p99 and largest terminal distance on all starts, on saturated and on
unsaturated starts, and the share of the summed error that the saturated starts carry.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from cwh_envs.controllers import MinEnergyFeedback, pd_action
from cwh_envs.datasets import evaluation_set
from cwh_envs.mpc import RecedingHorizon
from cwh_envs.prepare import load_train
from cwh_envs.rollout import fly

REPO = Path(__file__).resolve().parents[2]
SATURATED = 0.999  # of u_max: the expert's thrust at the box


def row(name: str, distance: np.ndarray, saturated: np.ndarray) -> str:
    cells = [name]
    for part in (np.ones_like(saturated), saturated, ~saturated):
        d = distance[part]
        cells.append(f"{d.mean():.3g} / {np.quantile(d, 0.99):.3g} / {d.max():.3g}")
    cells.append(f"{distance[saturated].sum() / distance.sum():.0%}")
    return "| " + " | ".join(cells) + " |"


def main(run_dirs: list[str]) -> None:
    train = load_train(REPO / "families" / "rendezvous")
    test = evaluation_set(train.TASK, train.N_TEST, problem=train.PROBLEM, split="test")
    expert = test.trajectory_thrust()
    saturated = (np.abs(expert) >= SATURATED * train.PROBLEM.u_max).any(axis=(1, 2))
    print(
        f"# Where the rendezvous error sits: {saturated.sum()} of {len(saturated)} sealed test starts saturated\n"
    )
    print("`" + " ".join(["python results/agent-levers/where_error_sits.py", *run_dirs]) + "`\n")
    print(
        "A start is saturated when the open-loop expert's thrust from it reaches the box "
        f"(|u| >= {SATURATED} u_max on an axis). Terminal distance in m, mean / p99 / max.\n"
    )
    print(
        "| controller | all starts | saturated starts | unsaturated starts | saturated share of the summed error |"
    )
    print("|---|---|---|---|---|")
    classical = {
        "MPC": RecedingHorizon(train.PROBLEM),
        "closed-form law (clipped)": MinEnergyFeedback(train.PROBLEM),
        "PD": lambda obs: pd_action(obs, train.PROBLEM),
    }
    for name, controller in classical.items():
        print(row(name, fly(train.PROBLEM, controller, test.starts).terminal_distance, saturated))
    for run_dir in run_dirs:
        policy, saved = train.load_policy(Path(run_dir) / "out")
        distance = train.fly(policy, test.starts).terminal_distance
        form = saved["config"].get("POLICY_FORM", "direct")
        print(row(f"{Path(run_dir).name} ({form})", distance, saturated))


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
