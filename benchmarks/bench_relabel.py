"""What DAgger's relabelling costs on constrained docking, per state, three ways (issue 35).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_relabel.py [--starts 4] [--states 48] [--chain 1]

The states are those a PD law flies through the multi-constraint CBF filter from the first
``--starts`` search-split starts: a policy off the expert's path, as an untrained one is. Each label
is the constrained expert's first control re-solved from the state over the steps left
(``cwh_envs.mpc.RecedingHorizon``, the soft expert where the hard one cannot answer):

1. ``chain``: every state of the first ``--chain`` flights in time order, each re-solve warm-started
   from the previous label's plan (the families' ``relabel``, DAGGER_STATES = 0);
2. ``flight-warm``: ``--states`` states drawn at random, each solved alone, warm-started from the
   thrust the flight applied from there (``RecedingHorizon.answer``, DAGGER_STATES > 0);
3. ``cold``: the same drawn states, solved alone with no warm start.

Prints seconds per state (mean, median, max) and, for 2 against 3, how far apart their labels are:
the SCP is local, so a different warm start can land on another route around the keep-out. Run it
alone: the times are wall-clock.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time

import numpy as np

from cwh_envs.controllers import pd_action
from cwh_envs.datasets import evaluation_starts
from cwh_envs.mpc import RecedingHorizon
from cwh_envs.observations import docking_observation
from cwh_envs.problems import DockingProblem
from cwh_envs.rollout import fly

PROBLEM = DockingProblem(speed_limit=(0.01, 2 * DockingProblem().n), approach_cone=(30.0, 15.0))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--starts", type=int, default=4, help="PD flights whose states are drawn from")
    parser.add_argument("--states", type=int, default=48, help="states drawn for flight-warm and cold")
    parser.add_argument("--chain", type=int, default=1, help="flights relabelled whole, in time order")
    args = parser.parse_args()
    plain = PROBLEM.replace(speed_limit=None, approach_cone=None)
    starts, goals = evaluation_starts("docking", args.starts, plain)
    flight = fly(PROBLEM, lambda obs: pd_action(obs, plain), starts, goals, cbf_margin=PROBLEM.margin)
    horizon = PROBLEM.horizon

    chain = RecedingHorizon(PROBLEM, on_failure="soft")
    chain_seconds = []
    for k in range(horizon):
        obs = docking_observation(
            flight.states[: args.chain, k], goals[: args.chain], k, horizon, dtype=np.float64
        )
        started = time.perf_counter()
        chain(obs)
        chain_seconds.append((time.perf_counter() - started) / args.chain)

    rng = np.random.default_rng(0)
    picks = np.sort(rng.choice(args.starts * horizon, size=args.states, replace=False))
    rows, steps = picks // horizon, picks % horizon
    states = docking_observation(flight.states[rows, steps], goals[rows], steps, horizon, dtype=np.float64)
    timed, labels = {}, {}
    for name in ("flight-warm", "cold"):
        expert, seconds, actions = RecedingHorizon(PROBLEM, on_failure="soft"), [], []
        for row, k, obs in zip(rows, steps, states, strict=True):
            warm = flight.thrust[row, k:] if name == "flight-warm" else None
            started = time.perf_counter()
            actions.append(expert.answer(obs[None], [warm])[0])
            seconds.append(time.perf_counter() - started)
        timed[name], labels[name] = seconds, np.array(actions) * PROBLEM.u_max

    print(
        f"Python {platform.python_version()}, {os.cpu_count()} CPUs (load average {os.getloadavg()[0]:.2f}); "
        f"constrained docking, PD + multi-constraint filter flights from {args.starts} search starts\n"
    )
    print("| relabelling | states | s a state: mean | median | max |")
    print("|---|---:|---:|---:|---:|")
    for name, seconds in (("chain (time order)", chain_seconds), *timed.items()):
        print(
            f"| {name} | {len(seconds) * (args.chain if name.startswith('chain') else 1)} | "
            f"{statistics.fmean(seconds):.3f} | {statistics.median(seconds):.3f} | {max(seconds):.3f} |"
        )
    gap = np.abs(labels["flight-warm"] - labels["cold"]).max(axis=1)
    print(
        f"\nflight-warm against cold labels, max |thrust difference| per state (N): median {np.median(gap):.2g}, "
        f"max {gap.max():.2g}; {np.mean(gap > 1e-3):.0%} of states differ by more than 1e-3 N"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
