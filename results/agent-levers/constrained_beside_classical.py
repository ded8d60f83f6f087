"""Constrained-docking runs beside the classical controllers, on the same search-split starts.

    OMP_NUM_THREADS=1 .venv/bin/python results/agent-levers/constrained_beside_classical.py RUN_DIR... \
        > results/agent-levers/docking-constrained-gp-cold/beside_classical.md

Each RUN_DIR is a constrained-docking run directory (its ``out/policy.pt``). No run of the campaign
was strict-feasible, so none was reseeded on the sealed test split; the runs are compared where they
were scored, on the search split (N_EVAL starts), with the closed-form law and the PD law through the
multi-constraint filter, and receding-horizon MPC (no filter, as on the leaderboard) on the first
MPC_STARTS of those starts (about 9 s a start). Every row is scored by the family's own docking_metrics, with the tail of its terminal distance.
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
MPC_STARTS = 16


def main(run_dirs: list[str]) -> None:
    train = load_train(REPO / "families" / "docking-constrained")
    problem = train.PROBLEM
    plain = problem.replace(speed_limit=None, approach_cone=None)  # the laws' own model, as the leaderboard's
    search = evaluation_set(train.TASK, train.N_EVAL, problem=problem, split="search")
    print(
        f"# Constrained docking on the search split ({len(search.starts)} starts), beside the classical rows\n"
    )
    print("`" + " ".join(["python results/agent-levers/constrained_beside_classical.py", *run_dirs]) + "`\n")
    print(
        "| controller | starts | score | success | cone broken (share of steps) | "
        "terminal distance (m): mean / p99 / max | energy / expert |"
    )
    print("|---|---:|---:|---:|---:|---|---:|")

    def row(name: str, flight, n: int) -> None:
        m = train.docking_metrics(flight, search.trajectory_thrust()[:n])
        d = flight.terminal_distance
        print(
            f"| {name} | {n} | {m['score']:.3g} | {m['success_rate']:.1%} | {m['violation_rates']['cone']:.1%} | "
            f"{d.mean():.3g} / {np.percentile(d, 99):.3g} / {d.max():.3g} | {m['effort_ratio']:.2f} |"
        )

    def flown(controller, n: int, cbf: bool = True):
        margin = problem.margin if cbf else None
        return fly(problem, controller, search.starts[:n], search.goals[:n], cbf_margin=margin)

    n = len(search.starts)
    row(
        f"MPC (first {MPC_STARTS} starts)", flown(RecedingHorizon(problem), MPC_STARTS, cbf=False), MPC_STARTS
    )
    row("closed-form law + filter", flown(MinEnergyFeedback(plain), n), n)
    row("PD + filter", flown(lambda obs: pd_action(obs, plain), n), n)
    for run_dir in run_dirs:
        policy, saved = train.load_policy(Path(run_dir) / "out")
        flight = train.fly(policy, search.starts, search.goals, saved["config"]["RUNTIME_CBF_FILTER"])
        row(f"{Path(run_dir).name} ({saved['config']['POLICY_FORM']})", flight, n)


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
