"""What a reseeded configuration's mean hides: each reseed's worst starts, the spread over the reseeds, a
seed far outside the rest, and the runaway gate (issue 37).

A σ-based gate over ten seeds cannot see a failure that strikes one seed in ten and one start in a
thousand: the docking family's best certified at 0.521 ± 0.061 on the sealed split, and retrained at
another seed it scored 40.3 there, one start flown off to 7.3 km while 85 % of starts docked.

- **Worst starts.** A family declares in family.json which fields of a split's metrics describe its
  tail, ``"tails": {"runaway_field": ..., "worst_field": ...}``: the share of starts beyond a runaway
  bound the family sets (the shipped families: ``runaway_share``, a start ending farther than 120 m
  from its target, farther than any start began) and the worst start's value (``max_terminal_distance``).
  Every reseed reports both, on the split the gate uses.
- **A seed far outside the rest**: a reseed whose metric lies more than :data:`OUTLIER_UNITS` robust
  standard deviations from the median of the other reseeds on the worse side (1.4826 times their
  median absolute deviation; their standard deviation when that is 0, as for a metric that takes two
  values). Only the worse side: a tail that strikes most seeds makes the clean ones lie far from the
  median, and flagging those would point at the seeds that went right (the docking best at 20 seeds:
  13 leave one start about 11 m off, 7 dock every start). Flagged in the report, not gated.
- **The runaway gate** (``--gate runaway``, the default): the paper's gate, and no valid reseed with
  a start beyond the runaway bound. ``--gate paper`` is the paper's gate alone (tails still reported).
"""

from __future__ import annotations

import statistics
from typing import Any

from autoresearch.splits import Split, split_parts

RUNAWAY, PAPER = "runaway", "paper"
GATES = (RUNAWAY, PAPER)
OUTLIER_UNITS = 5.0
MAD_TO_SD = 1.4826  # a normal distribution's sd per unit of median absolute deviation


def run_tail(final_metric: dict[str, Any] | None, split: Split, fields: dict[str, str]) -> dict[str, Any]:
    """A run's worst starts on ``split``: {"runaway_share", "worst"} (None where its record lacks them)."""
    part = split_parts(final_metric or {}).get(split) if final_metric else None
    part = part if isinstance(part, dict) else {}

    def number(field: str | None) -> float | None:
        value = part.get(field) if field else None
        return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None

    return {"runaway_share": number(fields.get("runaway_field")), "worst": number(fields.get("worst_field"))}


def outlier(value: float, others: list[float], sign: int) -> dict[str, Any] | None:
    """How far ``value`` lies from the other reseeds on the worse side of ``sign``, when more than
    :data:`OUTLIER_UNITS` robust sds."""
    if len(others) < 2:
        return None
    median = statistics.median(others)
    scale = MAD_TO_SD * statistics.median(abs(v - median) for v in others) or statistics.stdev(others)
    distance = -sign * (value - median)  # positive: worse than the others
    if distance <= 0 or (scale > 0 and distance <= OUTLIER_UNITS * scale):
        return None
    return {"median_of_others": median, "units": distance / scale if scale else None}


def summarize(reseeds: list[dict[str, Any]], declared: bool, sign: int) -> dict[str, Any]:
    """The tails of the valid reseeds (``excluded`` None, a metric): the per-seed spread, the seeds far
    outside the rest on the worse side of ``sign`` (the direction's sigma_dir) and, when the family
    declares its tail fields, the worst start and the reseeds with a runaway start."""
    valid = [r for r in reseeds if r["excluded"] is None and r["metric"] is not None]
    values = [r["metric"] for r in valid]
    out: dict[str, Any] = {"spread": None, "outliers": []}
    if values:
        out["spread"] = {"min": min(values), "median": statistics.median(values), "max": max(values)}
    for i, reseed in enumerate(valid):
        far = outlier(reseed["metric"], values[:i] + values[i + 1 :], sign)
        if far is not None:
            out["outliers"].append({"seed": reseed["seed"], "metric": reseed["metric"], **far})
    if declared:
        worst = [r for r in valid if r.get("worst") is not None]
        top = max(worst, key=lambda r: r["worst"], default=None)
        out["worst"] = top and {"seed": top["seed"], "value": top["worst"]}
        out["runaways"] = [
            {"seed": r["seed"], "runaway_share": r["runaway_share"]}
            for r in valid
            if (r.get("runaway_share") or 0) > 0
        ]
        out["unknown"] = [r["seed"] for r in valid if r.get("runaway_share") is None]
    return out


def runaway_reason(tails: dict[str, Any]) -> str | None:
    """Why the runaway gate refuses the candidate, or None."""
    runaways = tails.get("runaways") or []
    if not runaways:
        return None
    seeds = ", ".join(f"s{r['seed']} ({r['runaway_share']:.3g} of its starts)" for r in runaways)
    return f"{len(runaways)} reseed(s) with a start beyond the runaway bound: {seeds}"
