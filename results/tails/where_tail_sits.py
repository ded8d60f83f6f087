"""Where a docking recipe's tail sits: which sealed test starts its reseeds leave more than a metre off.

    OMP_NUM_THREADS=1 .venv/bin/python results/tails/where_tail_sits.py RUN_DIR... \
        > results/tails/docking-best/where_tail_sits.md

Each RUN_DIR is a docking run directory (its ``out/policy.pt``, e.g. a reseed under
``audit/verify/``). Every policy flies the sealed test split (1024 starts) as it is deployed (the
CBF filter on when its config says so), and so does the closed-form law (cwh_envs.controllers.
MinEnergyFeedback) through the same filter. A start is *missed* by a run when it ends more than
MISSED metres from its port. Printed: per run how many starts it missed and its worst three, then the
TOP starts missed by the most runs: how many miss each, where it begins (its range and position) and
what the law + CBF does from it.
"""

from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from cwh_envs.controllers import MinEnergyFeedback
from cwh_envs.datasets import evaluation_set
from cwh_envs.prepare import load_train
from cwh_envs.rollout import fly

REPO = Path(__file__).resolve().parents[2]
MISSED = 1.0  # m from the port at the last step
WORST = 3  # missed starts listed per run
TOP = 12  # starts listed, those missed by the most runs first


def as_typed(run_dirs: list[str]) -> str:
    """The run directories as a user would type them: ``PARENT/*/`` when they are all of PARENT's."""
    parents = {Path(d).parent for d in run_dirs}
    if len(parents) == 1:
        parent = parents.pop()
        if {Path(d) for d in run_dirs} == {d for d in parent.iterdir() if d.is_dir()}:
            return f"{parent}/*/"
    return " ".join(run_dirs)


def spread(distance: np.ndarray) -> str:
    """Mean / 99th percentile / largest terminal distance, as the leaderboard's tail columns."""
    return f"{distance.mean():.3g} / {np.percentile(distance, 99):.3g} / {distance.max():.3g}"


def main(run_dirs: list[str]) -> None:
    train = load_train(REPO / "families" / "docking")
    problem = train.PROBLEM
    test = evaluation_set(train.TASK, train.N_TEST, problem=problem, split="test")
    law = fly(problem, MinEnergyFeedback(problem), test.starts, test.goals, cbf_margin=problem.margin)
    print(
        f"# Where the docking tail sits: the sealed test starts ({len(test.starts)}) ended more than {MISSED:g} m off\n"
    )
    print(f"`python results/tails/where_tail_sits.py {as_typed(run_dirs)}`\n")
    print("| run | terminal distance (m): mean / p99 / max | starts missed | the worst (index: metres off) |")
    print("|---|---|---|---|")
    missed: dict[int, list[float]] = defaultdict(list)
    pooled = []
    for run_dir in run_dirs:
        policy, saved = train.load_policy(Path(run_dir) / "out")
        distance = train.fly(
            policy, test.starts, test.goals, saved["config"]["RUNTIME_CBF_FILTER"]
        ).terminal_distance
        pooled.append(distance)
        off = np.flatnonzero(distance > MISSED)
        for i in off:
            missed[int(i)].append(float(distance[i]))
        worst = (
            ", ".join(f"{i}: {distance[i]:.2f}" for i in off[np.argsort(-distance[off])][:WORST]) or "none"
        )
        print(f"| {Path(run_dir).name} | {spread(distance)} | {len(off)} | {worst} |")
    print(
        f"\n{len(run_dirs)} runs, their starts pooled: {spread(np.concatenate(pooled))} m. The closed-form "
        f"law + CBF from the same starts: {spread(law.terminal_distance)} m (mean / p99 / max).\n"
    )
    if not missed:
        print("No start missed by any run.")
        return
    print(
        f"{len(missed)} starts missed by at least one run; the {min(len(missed), TOP)} missed by the most runs:\n"
    )
    print(
        "| start | runs missing it | metres off (min / max) | initial range (m) | initial position (m) | law + CBF (m) |"
    )
    print("|---|---|---|---|---|---|")
    for i, values in sorted(missed.items(), key=lambda kv: (-len(kv[1]), -max(kv[1])))[:TOP]:
        position = test.starts[i, :3]
        print(
            f"| {i} | {len(values)} of {len(run_dirs)} | {min(values):.2f} / {max(values):.2f} | "
            f"{np.linalg.norm(position):.1f} | ({', '.join(f'{x:.1f}' for x in position)}) | "
            f"{law.terminal_distance[i]:.3g} |"
        )


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
