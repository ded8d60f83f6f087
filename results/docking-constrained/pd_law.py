"""The PD law on the constrained family's own evaluation starts, scored by the family's own metric.

    OMP_NUM_THREADS=1 .venv/bin/python results/docking-constrained/pd_law.py

The critically damped PD law of cwh_envs.controllers (three lines, no learning), flown with no
filter and with the multi-constraint filter (bench_constrained_docking.py has the keep-out filter
alone: it breaks both new constraints on every start), on the search split and the sealed test split of families/docking-constrained, through the family's
own ``fly`` and ``docking_metrics`` (so the numbers compare with the family's records). Writes
pd_law.json beside this file and prints a Markdown table.
"""

from __future__ import annotations

import json
from pathlib import Path

from scored import load_train, scored

from cwh_envs.controllers import pd_action
from cwh_envs.datasets import evaluation_set

HERE = Path(__file__).resolve().parent


def main() -> None:
    train = load_train()
    problem = train.PROBLEM
    plain = problem.replace(speed_limit=None, approach_cone=None)
    law = lambda obs: pd_action(obs, plain)  # noqa: E731
    out = {}
    for split, n in (("search", train.N_EVAL), ("test", train.N_TEST)):
        held_out = evaluation_set(train.TASK, n, problem=problem, split=split)
        for name, cbf in (("no filter", False), ("multi-constraint filter", True)):
            out[f"{split}/{name}"] = scored(train, law, held_out, cbf)
    (HERE / "pd_law.json").write_text(json.dumps(out, indent=2) + "\n", encoding="utf-8")
    print(
        "| PD law | split | score | success | keep-out / speed / cone violation rate | effort ratio | strict-feasible |"
    )
    print("|---|---|---|---|---|---|---|")
    for key, m in out.items():
        split, name = key.split("/")
        r = m["violation_rates"]
        print(
            f"| {name} | {split} | {m['score']:.3f} | {m['success_rate']:.1%} | "
            f"{r['keep_out']:.3f} / {r['speed']:.3f} / {r['cone']:.3f} | {m['effort_ratio']:.2f} | {m['strict_feasible']} |"
        )


if __name__ == "__main__":
    main()
