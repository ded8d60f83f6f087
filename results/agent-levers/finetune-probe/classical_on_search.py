"""The classical rows on the fine-tuning probes' starts: the 512 of each family's search split.

    OMP_NUM_THREADS=1 .venv/bin/python results/agent-levers/finetune-probe/classical_on_search.py \
        > results/agent-levers/finetune-probe/classical_on_search.md

Receding-horizon MPC (cwh_envs.mpc.RecedingHorizon), the closed-form law
(cwh_envs.controllers.MinEnergyFeedback) and the PD law, on docking through the CBF filter as the
leaderboard flies them (MPC without it), scored by the family's own metric code; with the tail (p99
and largest terminal distance) and the energy over the open-loop expert's from the same starts.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cwh_envs.controllers import MinEnergyFeedback, pd_action
from cwh_envs.datasets import evaluation_set
from cwh_envs.mpc import RecedingHorizon
from cwh_envs.prepare import load_train
from cwh_envs.rollout import fly

REPO = Path(__file__).resolve().parents[3]


def main() -> None:
    print("# The classical rows on the 512 starts of each family's search split\n")
    print("`python results/agent-levers/finetune-probe/classical_on_search.py`\n")
    print(
        "| family | controller | metric | p99 terminal distance (m) | worst start (m) | energy / expert's |"
    )
    print("|---|---|---|---|---|---|")
    for name in ("rendezvous", "docking"):
        train = load_train(REPO / "families" / name)
        problem, docking = train.PROBLEM, name == "docking"
        split = evaluation_set(train.TASK, train.N_EVAL, problem=problem, split="search")
        goals, margin = (split.goals, problem.margin) if docking else (None, None)
        rows = {
            "MPC": (RecedingHorizon(problem), None),
            "closed-form law" + (" + CBF" if docking else ""): (MinEnergyFeedback(problem), margin),
            "PD" + (" + CBF" if docking else ""): (lambda obs, p=problem: pd_action(obs, p), margin),
        }
        for controller, (policy, cbf_margin) in rows.items():
            flight = fly(problem, policy, split.starts, goals, cbf_margin=cbf_margin)
            score = train.docking_metrics if docking else train.rendezvous_metrics
            metrics = score(flight, split.trajectory_thrust())
            distance = flight.terminal_distance
            print(
                f"| {name} | {controller} | {metrics[train.METRIC]:.3g} | {np.quantile(distance, 0.99):.3g} "
                f"| {distance.max():.3g} | {metrics['effort_ratio']:.3g} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
