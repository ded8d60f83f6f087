"""The leave-one-out probes of a committed hand recipe, read under each rule (results/pruning.md).

For every edit: the paper's probes (shared seeds, Delta against mu_R) in the baseline's unit and in
the candidate's sigma_R, and the paired probes logged so far in audit/prune/prune.jsonl (each
reversion and the full recipe at the same seed), in both units. Reads only; runs nothing, so it
also shows a paired step that has not finished.

    python results/pruning_probes.py rendezvous docking
"""

from __future__ import annotations

import sys
from pathlib import Path

from autoresearch.audit import stats
from autoresearch.campaign.audit_log import StepLog
from autoresearch.journal import read_json

HERE = Path(__file__).resolve().parent


def decide(deltas: list[float], sigma: float) -> str:
    decision = stats.loo_decision(deltas[0], sigma)
    if decision == stats.ESCALATE and len(deltas) > 1:
        decision = stats.loo_decision(deltas[0], sigma, deltas[1])
    return "drop†" if decision == stats.DROP_DAGGER else decision


def fmt(deltas: list[float], sigma: float) -> str:
    return "; ".join(f"{d / sigma:+.2f}" for d in deltas) + f" → {decide(deltas, sigma)}"


def table(family: str) -> str:
    campaign = HERE / family / "hand"
    audit = read_json(campaign / "audit.json")
    sign = -1 if read_json(campaign / "family.json")["direction"] == "minimize" else 1
    verify = audit["verify"]
    full = next(c for c in verify["candidates"] if c["config_id"] == verify["promoted"])
    sigma, sigma_r, mu_r = verify["noise"]["std"], full["sigma_r"], full["mu_r"]
    logged = StepLog(campaign / "audit" / "prune" / "prune.jsonl").read()
    rows = {r.key: r for r in logged if r.ok}
    failed = {r.key: r.status for r in logged if not r.ok and r.key not in rows}
    paired_plan = audit.get("prune_paired_candidate") or audit.get("prune_paired") or {}
    seeds = paired_plan.get("probe_seeds", [])
    n = len(full["changed"])
    lines = [
        f"### {family}: mu_R = {mu_r:.4g}, sigma (baseline) = {sigma:.4g}, sigma_R (candidate) = {sigma_r:.4g}",
        "",
        "Δ1; Δ2 in units of σ → decision (negative = reverting hurts); paired: seeds as planned, pairs done so far.",
        "",
        "| edit | paper (σ) | paper, noise at candidate (σ_R) | paired seeds | paired (σ) | paired, noise at candidate (σ_R) |",
        "|---|---|---|---|---|---|",
    ]
    for i, d in enumerate(audit["prune"]["decisions"]):
        name = d["param"]
        if d["note"]:
            paper = candidate = f"keep ({d['note'].split(':')[0]})"
        else:
            values = [p["metric"] for p in d["probes"]]
            deltas = [stats.loo_delta(values[: k + 1], mu_r, sign) for k in range(len(values))]
            paper, candidate = fmt(deltas, sigma), fmt(deltas, sigma_r)
        own = [seeds[i], seeds[n + i]] if len(seeds) >= 2 * n else []
        pairs = []
        for seed in own:
            reverted = rows.get(f"loo-{full['config_id']}-{name}-s{seed}")
            whole = rows.get(f"full-{full['config_id']}-s{seed}")
            if reverted is None or whole is None:
                break
            pairs.append((reverted.scores.search.metric, whole.scores.search.metric))
        if pairs:
            deltas = [
                stats.paired_loo_delta([r for r, _ in pairs[: k + 1]], [f for _, f in pairs[: k + 1]], sign)
                for k in range(len(pairs))
            ]
            paired, paired_candidate = fmt(deltas, sigma), fmt(deltas, sigma_r)
        else:
            first = (
                [f"loo-{full['config_id']}-{name}-s{own[0]}", f"full-{full['config_id']}-s{own[0]}"]
                if own
                else []
            )
            pending = [key for key in first if key in failed]
            paired = paired_candidate = (
                f"{pending[0].split('-')[0]} run at seed {own[0]}: {failed[pending[0]]} (retried on resume)"
                if pending
                else "not run yet"
            )
        lines.append(f"| {name} | {paper} | {candidate} | {own or '—'} | {paired} | {paired_candidate} |")
    return "\n".join(lines)


if __name__ == "__main__":
    print("\n\n".join(table(family) for family in sys.argv[1:] or ["rendezvous", "docking"]))
