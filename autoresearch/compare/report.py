"""``autoresearch compare``: arms scored over their repeats, written as compare.md, compare.json and three
figures (best so far against experiments and against wall-clock, and the performance profile).

Only feasible runs count toward the best so far and the target (the ``feasible`` of each record, i.e.
the family's ``feasibility_field``). The numbers are :mod:`autoresearch.compare.analysis`'s, from the
statistics of :mod:`autoresearch.compare.stats`; the arms come from :mod:`autoresearch.compare.inputs`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from autoresearch.campaign import portable_path
from autoresearch.compare import stats as compare
from autoresearch.compare.analysis import Analysis, analyse
from autoresearch.compare.figures import budget_figure, profile_figure, wallclock_figure
from autoresearch.compare.inputs import RepeatedArm

CHECKPOINTS = 8


# ----- figures ---------------------------------------------------------------------------


def _num(v: float) -> str:
    return "none feasible" if math.isinf(v) else f"{v:.4g}"


def _ci(low: float, high: float) -> str:
    if math.isnan(low):
        return ""
    return f" [{_num(low)}, {_num(high)}]"


def _units(a: Analysis, v: float) -> float:
    return float(compare.noise_units(v, a.noise["reference"], a.noise["sigma"], a.direction))


def _sigma(u: float) -> str:
    return "—" if math.isinf(u) else f"{round(u, 1) + 0.0:+.1f}"  # + 0.0: no "-0.0"


def _cell(a: Analysis, point: float, low: float, high: float) -> str:
    """The value with its interval, then the same in noise units when the family has them."""
    text = _num(point) + _ci(low, high)
    if a.noise and math.isfinite(point):
        text += f"; {_sigma(_units(a, point))}σ"
        if not math.isnan(low):
            lo_u, hi_u = sorted((_units(a, low), _units(a, high)))  # a minimized metric flips the order
            text += f" [{_sigma(lo_u)}, {_sigma(hi_u)}]"
    return text


def _to_target(a: Analysis, s: dict[str, Any]) -> str:
    """Two cells: the fraction reaching the target (Wilson CI), the median experiments to reach it."""
    k, n, low, high = s["reach"]
    m = s["median_to_target"]
    return f"{k}/{n} ({k / n:.0%}, 95% CI {low:.0%}–{high:.0%}) | " + (
        f">{a.budget}" if math.isinf(m) else f"{m:g}"
    )


def _final_table(a: Analysis) -> list[str]:
    target = a.family["target"] is not None
    head = "| Arm | Repeats | Median final best [95% CI] | IQM final best [95% CI] |"
    rule = "|---|---|---|---|"
    if target:
        head += " Reached target | Experiments to target (median) |"
        rule += "---|---|"
    rows = [head, rule]
    for arm in a.arms:
        s = a.summaries[arm.name]
        med, q = s["median"], s["iqm"]
        row = (
            f"| {arm.name} | {s['n']} | {_cell(a, med['point'][-1], med['low'][-1], med['high'][-1])} "
            f"| {_cell(a, q['point'][-1], q['low'][-1], q['high'][-1])} |"
        )
        if target:
            row += f" {_to_target(a, s)} |"
        rows.append(row)
    return rows


def _checkpoints(a: Analysis) -> list[str]:
    budgets = np.unique(np.round(np.linspace(1, a.budget, min(a.budget, CHECKPOINTS))).astype(int))
    rows = [
        "| Experiments | " + " | ".join(arm.name for arm in a.arms) + " |",
        "|---" * (len(a.arms) + 1) + "|",
    ]
    for b in budgets:
        cells = []
        for arm in a.arms:
            q = a.summaries[arm.name]["iqm"]
            cells.append(_cell(a, q["point"][b - 1], q["low"][b - 1], q["high"][b - 1]))
        rows.append(f"| {b} | " + " | ".join(cells) + " |")
    return rows


def _improvement(a: Analysis) -> list[str]:
    names = [arm.name for arm in a.arms]
    rows = ["| P(row beats column) | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for x in names:
        cells = []
        for y in names:
            if x == y:
                cells.append("—")
                continue
            p, low, high = a.improvement[x, y]
            cells.append(f"{p:.2f}" + ("" if math.isnan(low) else f" [{low:.2f}, {high:.2f}]"))
        rows.append(f"| {x} | " + " | ".join(cells) + " |")
    return rows


def _arms_table(a: Analysis) -> list[str]:
    rows = [
        "| Arm | Proposer | Repeats | Experiments per repeat | Feasible at the end | Directories |",
        "|---|---|---|---|---|---|",
    ]
    for arm in a.arms:
        counts = [min(r.n, a.budget) for r in arm.repeats]
        span = f"{min(counts)}" if min(counts) == max(counts) else f"{min(counts)}–{max(counts)}"
        feasible = int(np.isfinite(a.summaries[arm.name]["finals"]).sum())
        parents = sorted(
            {portable_path(r.dir.parent if r.dir.name.startswith("repeat-") else r.dir) for r in arm.repeats}
        )
        rows.append(
            f"| {arm.name} | {arm.proposers} | {len(arm.repeats)} | {span} | {feasible} of {len(arm.repeats)} "
            f"| {', '.join(parents)} |"
        )
    return rows


def _jsonable(x: Any) -> Any:
    """compare.json: arrays as lists, infinities (no feasible run) as null."""
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


def write_comparison(
    arms: list[RepeatedArm],
    out_dir: Path,
    *,
    budget: int | None = None,
    sigma: float | None = None,
    seed: int = 0,
    n_resamples: int = compare.RESAMPLES,
) -> Path:
    """Write compare.md, compare.json and the figures into ``out_dir``; return compare.md's path."""
    a = analyse(arms, budget, sigma, seed, n_resamples)
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed + 1)
    budget_figure(a, out_dir / "best_so_far.png")
    wallclock_figure(a, out_dir / "best_so_far_wallclock.png", rng, n_resamples)
    profile_figure(a, out_dir / "performance_profile.png", rng, n_resamples)
    fam = a.family
    better = "lower" if a.direction < 0 else "higher"
    feasibility = (
        f"only runs with `{fam['feasibility_field']}` true count toward the best so far and the target"
        if fam["feasibility_field"]
        else "every successful run is feasible"
    )
    if a.noise:
        n = a.noise
        units = (
            f"Seed noise σ = {n['sigma']:.4g} ({n['note']}); each value is followed by how many σ it is better "
            f"than the baseline mean {n['reference']:.4g} (positive: better), as the audit's m."
        )
    else:
        units = "No measured seed noise: values in raw units only (`autoresearch noise`, or --sigma)."
    lines = [
        f"# Comparison: {', '.join(arm.name for arm in a.arms)}",
        "",
        f"Family **{fam['name']}**, metric `{fam['metric']}` ({better} is better), target {fam['target']}; "
        f"{feasibility}. Budget: {a.budget} experiments (attempted runs, the shared baseline included). "
        f"{units} Intervals: 95% percentile bootstrap over repeats, resampled within each arm "
        f"({n_resamples} resamples, seed {seed}). How to read this: docs/compare.md.",
        "",
        *[f"- Note: {note}\n" for note in a.notes],
        "## Arms",
        "",
        *_arms_table(a),
        "",
        f"## Final best after {a.budget} experiments",
        "",
        *_final_table(a),
        "",
        "## Best so far by budget (IQM [95% CI])",
        "",
        *_checkpoints(a),
        "",
        "## Probability of improvement",
        "",
        "P(X > Y): the probability that a repeat of the row arm ends with a better final best than a repeat of "
        "the column arm (ties count 1/2; Mann-Whitney U / (n m)), with its 95% stratified-bootstrap interval.",
        "",
        *_improvement(a),
        "",
        "## Figures",
        "",
        "![best so far](best_so_far.png)",
        "",
        "![best so far against wall-clock](best_so_far_wallclock.png)",
        "",
        "![performance profile](performance_profile.png)",
        "",
    ]
    (out_dir / "compare.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    data = {
        "family": fam,
        "budget": a.budget,
        "noise": a.noise,
        "resamples": n_resamples,
        "seed": seed,
        "arms": {
            arm.name: {
                "dirs": [portable_path(r.dir) for r in arm.repeats],
                "experiments": [r.n for r in arm.repeats],
                **a.summaries[arm.name],
            }
            for arm in a.arms
        },
        "improvement": {
            f"{x} > {y}": dict(zip(("p", "low", "high"), v, strict=True))
            for (x, y), v in a.improvement.items()
        },
        "notes": a.notes,
    }
    (out_dir / "compare.json").write_text(json.dumps(_jsonable(data), indent=2) + "\n", encoding="utf-8")
    return out_dir / "compare.md"
