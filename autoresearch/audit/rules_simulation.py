"""How often each leave-one-out rule keeps a hitchhiker or drops a needed edit (docs/audit.md).

No training: a family with known effects and Gaussian seed noise, put through the audit's own
decision functions (stats.loo_delta, stats.paired_loo_delta, stats.loo_decision) at the audit's
default seeds: K = 10 baseline seeds, 10 verification reseeds, one probe seed escalated to two.

The family, in units of the candidate's true seed sd (negative: reverting hurts): two hitchhikers
(0), a borderline edit (-0.75), a load-bearing edit (-3), and a pair needed jointly (each alone 0,
both reverted -3). A run's oriented metric at seed s is effect + sd * (sqrt(rho) z_s +
sqrt(1 - rho) e), z_s shared by every configuration run at seed s (what a seed fixes for all of
them: data order, initialization) and e its own; rho is that shared fraction of the variance.
The baseline's seeds have sd ``baseline_sd`` (the unit the paper measures at).

    python -m autoresearch.audit.rules_simulation      # the table docs/audit.md quotes
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autoresearch.audit import stats

K_NOISE = 10  # the audit's default seeds
N_RESEEDS = 10
N_PROBES = 2
TARGET = -1.0  # the full recipe (at 0) reaches it; losing a -3 edit (or the pair) does not
EFFECTS = {"hitch1": 0.0, "hitch2": 0.0, "border": -0.75, "load": -3.0, "joint_a": 0.0, "joint_b": 0.0}
JOINT = ("joint_a", "joint_b")
JOINT_EFFECT = -3.0
LOST = -0.5  # a published recipe this much worse than the full one lost a needed effect
RULES = (("paper", False, "baseline"), ("paper, noise at candidate", False, "candidate"))
RULES += (("paired", True, "baseline"), ("paired, noise at candidate", True, "candidate"))


@dataclass(frozen=True)
class Scenario:
    name: str
    rho: float  # the fraction of a run's seed variance shared by every configuration at that seed
    baseline_sd: float  # the baseline's seed sd, in units of the candidate's


SCENARIOS = (
    Scenario("same noise, rho 0.5", 0.5, 1.0),
    Scenario("same noise, rho 0", 0.0, 1.0),
    Scenario("same noise, rho 0.9", 0.9, 1.0),
    Scenario("baseline 50x noisier (rendezvous-like), rho 0.5", 0.5, 50.0),
)


def _value(rng: np.random.Generator, mean: float, shared: float, rho: float) -> float:
    return mean + math.sqrt(rho) * shared + math.sqrt(1 - rho) * rng.standard_normal()


def _decide(rng, scenario: Scenario, paired: bool, noise_at: str) -> tuple[dict[str, str], bool]:
    """One audit: every edit's decision, and whether a pruned recipe that lost a needed effect
    (the borderline edit, the load-bearing one, or the pair together) was published."""
    rho, sign = scenario.rho, 1  # values are oriented: higher is better
    baseline = scenario.baseline_sd * rng.standard_normal(K_NOISE)
    reseeds = np.array([_value(rng, 0.0, rng.standard_normal(), rho) for _ in range(N_RESEEDS)])
    mu_r = float(reseeds.mean())
    sigma = float(baseline.std(ddof=1)) if noise_at == "baseline" else float(reseeds.std(ddof=1))
    names = list(EFFECTS)
    shared_seeds = rng.standard_normal(N_PROBES)  # the paper's rule: the same seeds for every edit
    own_seeds = rng.standard_normal((len(names), N_PROBES))  # paired: each edit its own
    decisions = {}
    for i, name in enumerate(names):
        reverted, full, deltas = [], [], []
        for k in range(N_PROBES):
            z = own_seeds[i, k] if paired else shared_seeds[k]
            reverted.append(_value(rng, EFFECTS[name], z, rho))
            if paired:  # the full configuration at the same seed
                full.append(_value(rng, 0.0, z, rho))
                deltas.append(stats.paired_loo_delta(reverted, full, sign))
            else:
                deltas.append(stats.loo_delta(reverted, mu_r, sign))
            decision = stats.loo_decision(deltas[0], sigma, deltas[1] if k else None)
            if decision != stats.ESCALATE:
                break
        decisions[name] = decision
    dropped = [n for n, d in decisions.items() if d in stats.DROPPED]
    loss = sum(EFFECTS[n] for n in dropped) + (JOINT_EFFECT if set(JOINT) <= set(dropped) else 0.0)
    pruned = np.array([_value(rng, loss, rng.standard_normal(), rho) for _ in range(N_RESEEDS)])
    # Eq. prunereverify: the target kept (the margin over a baseline far below is taken as passed).
    published = bool(dropped) and float(pruned.mean()) >= TARGET
    return decisions, published and loss <= LOST


def rates(scenario: Scenario, paired: bool, noise_at: str, n: int = 2000, seed: int = 0) -> dict[str, float]:
    """Over ``n`` simulated audits: hitchhikers kept, each needed edit dropped (alone), both
    hitchhikers kept together, and a published recipe that lost a needed effect."""
    rng = np.random.default_rng(seed)
    counts = dict.fromkeys(("hitch_kept", "both_hitch_kept", "border", "load", "joint", "bad_publish"), 0)
    for _ in range(n):
        d, published = _decide(rng, scenario, paired, noise_at)
        kept = [d[h] not in stats.DROPPED for h in ("hitch1", "hitch2")]
        counts["hitch_kept"] += sum(kept) / 2
        counts["both_hitch_kept"] += all(kept)
        for name in ("border", "load"):
            counts[name] += d[name] in stats.DROPPED
        counts["joint"] += sum(d[j] in stats.DROPPED for j in JOINT) / 2
        counts["bad_publish"] += published
    return {k: v / n for k, v in counts.items()}


def table(n: int = 2000, seed: int = 0) -> str:
    head = (
        "| scenario | rule | hitchhiker kept | both kept together | borderline dropped | load-bearing dropped "
        "| joint member dropped (alone) | published recipe lost a needed effect |"
    )
    lines = [head, "|---|---|---|---|---|---|---|---|"]
    for scenario in SCENARIOS:
        for name, paired, noise_at in RULES:
            r = rates(scenario, paired, noise_at, n, seed)
            cells = [
                r[k] for k in ("hitch_kept", "both_hitch_kept", "border", "load", "joint", "bad_publish")
            ]
            lines.append(f"| {scenario.name} | {name} | " + " | ".join(f"{c:.1%}" for c in cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(table())
