"""Which Optuna sampler to put behind a sample-efficient key-free proposer: random, TPE, GP, CMA-ES.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_keyfree_samplers.py [--trials 30] [--seeds 3]

Each arm runs the project's own proposer (random, tpe, gp; CMA-ES through the same class with
Optuna's CmaEsSampler, random draws for categoricals) for ``--trials`` experiments on a synthetic
objective over each family's real search space (random-range), starting from the baseline as the
loop does. The objective is a bowl in the space's normalized coordinates (log scale for log-real,
each choice of a categorical a fixed offset) whose minimum sits away from the baseline, with a
slice of the space (as rendezvous' slow corners do) that "times out" and is told as a failure. It
costs nothing to evaluate, so the table measures the samplers, not training. Prints the median
best-after-N over seeds and the asks' wall time.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import optuna

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from autoresearch.proposers import make_proposer  # noqa: E402
from autoresearch.proposers.base import ProposerContext, RunOutcome  # noqa: E402
from autoresearch.proposers.tpe import TPEProposer, _derived_seed  # noqa: E402
from autoresearch.space import NUMERIC_TYPES, ParamSpec  # noqa: E402


class CmaEsProposer(TPEProposer):
    """The CMA-ES candidate, benchmarked only: CmaEsSampler, random draws for categoricals."""

    name = "cmaes"

    def _ask(self, trials, attempt):
        seed = _derived_seed("cmaes", self.seed, len(trials), attempt)
        sampler = optuna.samplers.CmaEsSampler(
            seed=seed,
            n_startup_trials=5,
            independent_sampler=optuna.samplers.RandomSampler(seed=seed),
            warn_independent_sampling=False,
            with_margin=True,
        )
        study = optuna.create_study(direction=self.direction.study, sampler=sampler)
        study.add_trials(trials)
        return self.space.validate_full(study.ask(self.distributions).params)


def _unit(param: ParamSpec, value: Any) -> float:
    """``value`` mapped to [0, 1] over the parameter's domain (a choice: its index, spread)."""
    if param.type in NUMERIC_TYPES:
        low, high, v = param.low, param.high, value
        if param.type == "log-real":
            low, high, v = math.log(low), math.log(high), math.log(v)
        return 0.5 if high == low else (v - low) / (high - low)
    choices = list(param.choices or (False, True))
    return choices.index(value) / max(1, len(choices) - 1)


def _target(name: str, family: str) -> float:
    """A fixed optimum coordinate per parameter, away from the centre."""
    digest = hashlib.sha256(f"{family}:{name}".encode()).digest()
    return 0.15 + 0.7 * digest[0] / 255


def objective(space, family: str, config: dict[str, Any]) -> float | None:
    """The bowl, or None ("timed out") in the costly corner where the first two axes are both high."""
    units = {n: _unit(p, config[n]) for n, p in space.params.items()}
    first, second = list(units)[:2]
    if units[first] > 0.85 and units[second] > 0.85:
        return None
    weights = [3.0 / (1 + i) for i in range(len(units))]  # a few parameters matter most
    return sum(w * (u - _target(n, family)) ** 2 for w, (n, u) in zip(weights, units.items(), strict=True))


def run_arm(name: str, registry: dict[str, Any], family: str, seed: int, trials: int) -> tuple[list, float]:
    if name == "cmaes":
        proposer = CmaEsProposer(registry, seed=seed, n_startup_trials=5, space="random-range")
    else:
        proposer = make_proposer(name, registry, seed=seed, space="random-range")
    space = proposer.space
    config = registry["baseline"]["config"]
    history, best, bests, ask_s = [], math.inf, [], 0.0
    for iteration in range(1, trials + 1):
        if iteration > 1:
            context = ProposerContext.of_configs(iteration, registry, history, registry["baseline"]["config"])
            start = time.perf_counter()
            config = proposer.propose(context).overrides
            ask_s += time.perf_counter() - start
        value = objective(space, family, config) if space.contains(config) else None
        proposer.tell(RunOutcome(config, value, value is not None))
        history.append(config)
        best = min(best, value if value is not None else math.inf)
        bests.append(best)
    return bests, ask_s / max(1, trials - 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--arms", default="random,tpe,gp,cmaes")
    parser.add_argument("--families", default="rendezvous,docking")
    args = parser.parse_args()
    optuna.logging.set_verbosity(optuna.logging.ERROR)
    checkpoints = [n for n in (10, 20, 30, 60) if n <= args.trials]
    print(
        f"| family | arm | {' | '.join(f'best@{n} (median of {args.seeds})' for n in checkpoints)} | s/ask |"
    )
    print("|---|---|" + "---|" * (len(checkpoints) + 1))
    for family in args.families.split(","):
        registry = json.loads((ROOT / "families" / family / "family.json").read_text())
        for arm in args.arms.split(","):
            runs = [run_arm(arm, registry, family, seed, args.trials) for seed in range(args.seeds)]
            cells = [f"{statistics.median(b[n - 1] for b, _ in runs):.3f}" for n in checkpoints]
            ask = statistics.mean(a for _, a in runs)
            print(f"| {family} | {arm} | {' | '.join(cells)} | {ask:.2f} |", flush=True)


if __name__ == "__main__":
    main()
