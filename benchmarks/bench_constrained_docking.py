"""The constrained docking problem's constants, held to the three measurements that chose them.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_constrained_docking.py [--starts 128] [--solve 16]

On the docking search split's screened starts (cwh_envs.datasets.evaluation_starts):

1. each constraint binds on the keep-out (minimum-energy) expert: the share of starts whose expert
   trajectory breaks it;
2. the critically damped PD law with today's keep-out CBF filter breaks it on a clear share;
3. the constrained expert solves and meets every constraint, as the env counts them, on the first
   ``--solve`` starts (its thrust flown through the constrained env); with its energy against the
   keep-out expert's and its solve time.

Prints Markdown tables.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time

import numpy as np

from cwh_envs.constraints import cone_terms, speed_margin
from cwh_envs.controllers import pd_action
from cwh_envs.datasets import evaluation_starts
from cwh_envs.experts import Infeasible, scp_docking
from cwh_envs.problems import DockingProblem
from cwh_envs.rollout import fly

PLAIN = DockingProblem()
SPEED_LIMIT = (0.01, 2 * PLAIN.n)  # m/s, 1/s: ACT3's v1 = 2n; v0 chosen below
APPROACH_CONE = (30.0, 15.0)  # deg, m


def broken(states: np.ndarray, goals: np.ndarray) -> dict[str, np.ndarray]:
    """Per trajectory (E, H+1, 6): whether x_1..x_H break the speed limit, the cone."""
    after = states[:, 1:]
    flat, flat_goals = after.reshape(-1, 6), np.repeat(goals, after.shape[1], axis=0)
    speed = speed_margin(flat, flat_goals, SPEED_LIMIT).reshape(after.shape[:2]) < 0
    region, slack, _ = cone_terms(flat, flat_goals, APPROACH_CONE)
    cone = (region & (slack < 0)).reshape(after.shape[:2])
    return {"speed limit": speed.any(axis=1), "approach cone": cone.any(axis=1)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--starts", type=int, default=128, help="search-split starts for 1 and 2")
    parser.add_argument("--solve", type=int, default=16, help="starts the constrained expert solves (3)")
    args = parser.parse_args()
    starts, goals = evaluation_starts("docking", args.starts, PLAIN)
    plain = np.array([scp_docking(x0, g, PLAIN).states for x0, g in zip(starts, goals, strict=True)])
    pd = fly(PLAIN, lambda obs: pd_action(obs, PLAIN), starts, goals, cbf_margin=PLAIN.margin)
    expert_broken, pd_broken = broken(plain, goals), broken(pd.states, goals)

    problem = PLAIN.replace(speed_limit=SPEED_LIMIT, approach_cone=APPROACH_CONE)
    solved, seconds, energy = 0, [], []
    for x0, g in zip(starts[: args.solve], goals[: args.solve], strict=True):
        started = time.perf_counter()
        try:
            solution = scp_docking(x0, g, problem)
        except Infeasible as err:
            print(f"[bench_constrained_docking] infeasible: {err}", file=sys.stderr)
            continue
        seconds.append(time.perf_counter() - started)
        flight = fly(problem, _open_loop(solution.controls, problem), x0[None], g[None])
        assert flight.is_success[0], "the env counts a constraint broken by the constrained expert"
        solved += 1
        energy.append(solution.cost / scp_docking(x0, g, PLAIN).cost)

    print(
        f"Python {platform.python_version()}, {os.cpu_count()} CPUs (load average {os.getloadavg()[0]:.2f}); "
        f"speed_limit={SPEED_LIMIT[0]:g} m/s + {SPEED_LIMIT[1]:.5f}/s x distance, "
        f"approach_cone={APPROACH_CONE[0]:g} deg within {APPROACH_CONE[1]:g} m; docking search split\n"
    )
    print(f"| constraint | keep-out expert breaks it ({args.starts} starts) | PD + keep-out CBF breaks it |")
    print("|---|---:|---:|")
    for name in expert_broken:
        print(f"| {name} | {expert_broken[name].mean():.0%} | {pd_broken[name].mean():.0%} |")
    print()
    print("| constrained expert | value |")
    print("|---|---:|")
    print(f"| solved, every constraint met as the env counts it | {solved} of {args.solve} |")
    if seconds:
        print(
            f"| energy against the keep-out expert, median (range) | {statistics.median(energy):.2f}x "
            f"({min(energy):.2f}-{max(energy):.2f}) |"
        )
        print(
            f"| solve time per start, median (max) | {statistics.median(seconds):.1f} s ({max(seconds):.0f} s) |"
        )
    return 0


def _open_loop(controls: np.ndarray, problem: DockingProblem):
    """A policy replaying ``controls`` (H, 3) step by step (fly calls it once a step)."""
    steps = iter(controls / problem.u_max)
    return lambda obs: next(steps)[None]


if __name__ == "__main__":
    sys.exit(main())
