"""Constrained-docking runs beside the classical controllers, on the same starts of one split.

    OMP_NUM_THREADS=1 .venv/bin/python results/agent-levers/constrained_beside_classical.py RUN_DIR... \
        > results/agent-levers/docking-constrained-gp-cold/beside_classical.md
    OMP_NUM_THREADS=1 .venv/bin/python results/agent-levers/constrained_beside_classical.py --split test \
        --mpc-starts 0 RUN_DIR... > results/agent-levers/docking-constrained-gp-route/beside_classical.md

Each RUN_DIR is a constrained-docking run directory (its ``out/policy.pt``), e.g. a campaign's run or
an audit's reseed. The runs are compared on ``--split`` (search: N_EVAL starts, where a campaign's
runs were scored; test: the N_TEST sealed starts, where the audit's reseeds were) with the
closed-form law, the same law routed through CONE_ROUTE's waypoints and the PD law, each through
the multi-constraint filter, and receding-horizon MPC (no filter, as on the leaderboard) on the
first ``--mpc-starts`` of those starts (about 9 s a start; 0: no MPC row). Every row is scored by
the family's own docking_metrics, with the tail of its terminal distance.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from cwh_envs.controllers import MinEnergyFeedback, WaypointFeedback, pd_action
from cwh_envs.datasets import evaluation_set
from cwh_envs.mpc import RecedingHorizon
from cwh_envs.prepare import load_train
from cwh_envs.rollout import fly

REPO = Path(__file__).resolve().parents[2]


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dirs", nargs="+", metavar="RUN_DIR")
    parser.add_argument("--split", choices=("search", "test"), default="search")
    parser.add_argument("--mpc-starts", type=int, default=16, help="starts MPC flies (0: no MPC row)")
    args = parser.parse_args(argv)
    run_dirs = args.run_dirs
    train = load_train(REPO / "families" / "docking-constrained")
    problem = train.PROBLEM
    plain = problem.replace(speed_limit=None, approach_cone=None)  # the laws' own model, as the leaderboard's
    size = train.N_EVAL if args.split == "search" else train.N_TEST
    held_out = evaluation_set(train.TASK, size, problem=problem, split=args.split)
    print(
        f"# Constrained docking on the {args.split} split ({len(held_out.starts)} starts), beside the classical rows\n"
    )
    print("`" + " ".join(["python results/agent-levers/constrained_beside_classical.py", *argv]) + "`\n")
    print(
        "| controller | starts | score | success | cone broken: share of steps (starts breaking any constraint) | "
        "terminal distance (m): mean / p99 / max | energy / expert |"
    )
    print("|---|---:|---:|---:|---:|---|---:|")

    def row(name: str, flight, n: int) -> None:
        m = train.docking_metrics(flight, held_out.trajectory_thrust()[:n])
        d = flight.terminal_distance
        print(
            f"| {name} | {n} | {m['score']:.3g} | {m['success_rate']:.1%} | {m['violation_rates']['cone']:.2%} ({m['violating_starts']}) | "
            f"{d.mean():.3g} / {np.percentile(d, 99):.3g} / {d.max():.3g} | {m['effort_ratio']:.2f} |"
        )

    def flown(controller, n: int, cbf: bool = True):
        margin = problem.margin if cbf else None
        return fly(problem, controller, held_out.starts[:n], held_out.goals[:n], cbf_margin=margin)

    n, mpc = len(held_out.starts), args.mpc_starts
    if mpc:
        row(f"MPC (first {mpc} starts)", flown(RecedingHorizon(problem), mpc, cbf=False), mpc)
    row("closed-form law + filter", flown(MinEnergyFeedback(plain), n), n)
    row("routed law (CONE_ROUTE) + filter", flown(WaypointFeedback(problem), n), n)
    row("PD + filter", flown(lambda obs: pd_action(obs, plain), n), n)
    for run_dir in run_dirs:
        policy, saved = train.load_policy(Path(run_dir) / "out")
        config = {name: getattr(train, name) for name in train.CONFIG_NAMES} | saved[
            "config"
        ]  # keys added since at their defaults
        flight = train.fly(policy, held_out.starts, held_out.goals, train.safety_filter(config))
        row(f"{Path(run_dir).name} ({saved['config']['POLICY_FORM']})", flight, n)


if __name__ == "__main__":
    main(sys.argv[1:])
