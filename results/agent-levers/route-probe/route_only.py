"""The route alone: how far learning CONE_ROUTE's 16 waypoint positions takes the routed law, no network.

    OMP_NUM_THREADS=1 .venv/bin/python results/agent-levers/route-probe/route_only.py > results/agent-levers/route-probe/route_only.md

The family's "route" form with its correction zeroed (the network's last layer at 0, and its
fine-tuning rate at 1e-12, so it stays there) is the routed law exactly; the family's own closed-loop
fine-tuning (``finetune``, ROUTE_LR 0.5 m, FINETUNE_STEPS 300, 128 training-pool starts a step, the
0.75 m pool) then moves only the waypoints, at each FINETUNE_ENERGY below. Each route is flown from
the 128 search starts through the multi-constraint filter and scored by the family's metrics, as a
run is. One seed (0); the search split never shapes the route (it learns on the training pool).
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

from cwh_envs.datasets import evaluation_set
from cwh_envs.prepare import load_train

FAMILY = Path(__file__).resolve().parents[3] / "families" / "docking-constrained"
ENERGY_WEIGHTS = (0.0, 0.5)


def main() -> None:
    train = load_train(FAMILY)
    torch.set_num_threads(1)
    search = evaluation_set(train.TASK, train.N_EVAL, problem=train.PROBLEM, split="search")
    base = {name: getattr(train, name) for name in train.CONFIG_NAMES}
    base |= {"POLICY_FORM": "route", "EXPERT_MARGIN": 0.75, "FINETUNE_STEPS": 300, "FINETUNE_LR": 1e-12}
    print(
        "| route | fine-tuning loss (first / last step) | score | success | strict-feasible | energy / expert's |"
    )
    print("|---|---|---:|---:|---|---:|")
    rows = [("as drawn (CONE_ROUTE)", None)] + [(f"learned, FINETUNE_ENERGY {w}", w) for w in ENERGY_WEIGHTS]
    for name, weight in rows:
        torch.manual_seed(0)
        policy = train.build_policy(base)
        with torch.no_grad():
            policy.net[-1].weight.zero_()
            policy.net[-1].bias.zero_()
        loss = "-"
        if weight is not None:
            config = base | {"FINETUNE_ENERGY": weight, "ROUTE_LR": 0.5}
            generator = torch.Generator().manual_seed(0)
            policy, counts = train.finetune(
                config, policy, torch.device("cpu"), generator, train.Budget(None)
            )
            loss = f"{counts['first_loss']:.3g} / {counts['last_loss']:.3g}"
            print(f"<!-- {name}: along {counts['route']['along']}, across {counts['route']['across']} -->")
        m = train.evaluate(policy, search, {"cbf_margin": train.PROBLEM.margin}, dispersed=False)
        print(
            f"| {name} | {loss} | {m['score']:.3g} | {m['success_rate']:.1%} | {m['strict_feasible']} "
            f"| {m['effort_ratio']:.3f} |",
            flush=True,
        )


if __name__ == "__main__":
    sys.exit(main())
