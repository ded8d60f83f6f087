"""How scripts/main.sh's proposer seed was chosen: the first draws of each seed, priced by the
committed rendezvous runs (nothing is trained).

    .venv/bin/python benchmarks/pick_main_seed.py [--proposer tpe] [--seeds 12] [--draws 4]

A key-free proposer's first draws are a pure function of its seed (TPE's first ten are its random
start-up), so the configurations main.sh's campaign will run are known in advance. Two
least-squares fits over the committed runs of results/rendezvous (tpe, tpe-random, hand) price
them: the idle wall time, log(t - 2 s) linear in log(N_DEMOS x EPOCHS), log(width^2 x depth + 1000)
and log(BATCH_SIZE); and the metric, log(distance) linear in log N_DEMOS, log EPOCHS, log width,
depth, log learning rate, dropout and relu. Prints each seed's draws as (seconds, metric) and
the fits' correlations. The fits are rough (they ignore seed noise); they only rank seeds.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from autoresearch.proposers import make_proposer  # noqa: E402
from autoresearch.proposers.base import ProposerContext, RunOutcome  # noqa: E402

ARMS = ("tpe", "tpe-random", "hand")


def cost_features(c: dict) -> list[float]:
    size = c["HIDDEN_DIM"] ** 2 * c["N_LAYERS"] + 1000
    return [1.0, math.log(c["N_DEMOS"] * c["EPOCHS"]), math.log(size), math.log(c["BATCH_SIZE"])]


def metric_features(c: dict) -> list[float]:
    return [
        1.0,
        math.log(c["N_DEMOS"]),
        math.log(c["EPOCHS"]),
        math.log(c["HIDDEN_DIM"]),
        c["N_LAYERS"],
        math.log(c["LEARNING_RATE"]),
        c["DROPOUT"],
        float(c["ACTIVATION"] == "relu"),
    ]


def fit(rows: list[tuple[list[float], float]]) -> tuple[np.ndarray, float]:
    x, y = np.array([f for f, _ in rows]), np.array([v for _, v in rows])
    coef = np.linalg.lstsq(x, y, rcond=None)[0]
    return coef, float(np.corrcoef(x @ coef, y)[0, 1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--proposer", default="tpe")
    parser.add_argument("--space", default="random-range")
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--draws", type=int, default=4)
    args = parser.parse_args()
    ran = [
        record
        for arm in ARMS
        for line in (ROOT / "results" / "rendezvous" / arm / "proposals.jsonl").read_text().splitlines()
        if (record := json.loads(line)).get("status") == "ran"
    ]
    cost, r_cost = fit(
        [(cost_features(r["config"]), math.log(max(r["wall_seconds"] - 2.0, 0.3))) for r in ran]
    )
    quality, r_quality = fit([(metric_features(r["config"]), math.log(r["metric"])) for r in ran])
    print(f"fits over {len(ran)} committed runs: r(time) = {r_cost:.2f}, r(metric) = {r_quality:.2f}")
    registry = json.loads((ROOT / "families" / "rendezvous" / "family.json").read_text())
    baseline = registry["baseline"]["config"]
    for seed in range(args.seeds):
        proposer = make_proposer(args.proposer, registry, seed=seed, space=args.space)
        proposer.tell(RunOutcome(baseline, registry["baseline"]["metric"], True))  # as the loop tells it
        history, priced = [baseline], []
        for iteration in range(2, args.draws + 2):
            context = ProposerContext.of_configs(iteration, registry, history, baseline)
            config = proposer.propose(context).overrides
            proposer.tell(RunOutcome(config, None, False))  # start-up draws do not depend on the outcomes
            history.append(config)
            seconds = 2.0 + math.exp(np.dot(cost, cost_features(config)))
            priced.append(f"({seconds:.0f} s, {math.exp(np.dot(quality, metric_features(config))):.2f} m)")
        print(f"{args.proposer} seed {seed:2d}: " + " ".join(priced))


if __name__ == "__main__":
    main()
