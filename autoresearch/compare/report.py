"""``autoresearch compare``: arms scored over their repeats, written as compare.md, compare.json and three
figures (best so far against experiments and against wall-clock, and the performance profile).

Only feasible runs count toward the best so far and the target (the ``feasible`` of each record, i.e.
the family's ``feasibility_field``). The statistics are :mod:`autoresearch.compare.stats`'s; the arms come
from :mod:`autoresearch.compare.inputs`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator, NullFormatter

from autoresearch.audit.report import LOG_SPAN
from autoresearch.compare import stats as compare
from autoresearch.compare.inputs import CompareError, RepeatedArm, common_family, noise_reference
from autoresearch.direction import Direction
from autoresearch.loop.campaign import portable_path

BUDGET_TRIGGERS = ("max_iters", "max_runs", "wall_clock", "max_cost")
TIME_POINTS = 200
CHECKPOINTS = 8


@dataclass(frozen=True)
class Analysis:
    family: dict[str, Any]
    direction: int
    budget: int
    noise: dict[str, Any] | None
    arms: list[RepeatedArm]
    summaries: dict[str, dict[str, Any]]
    improvement: dict[tuple[str, str], tuple[float, float, float]]
    notes: list[str]


def analyse(
    arms: list[RepeatedArm],
    budget: int | None = None,
    sigma: float | None = None,
    seed: int = 0,
    n_resamples: int = compare.RESAMPLES,
) -> Analysis:
    family = common_family(arms)
    direction = Direction.of(family["direction"])
    longest = max(r.n for arm in arms for r in arm.repeats)
    if longest == 0:
        raise CompareError("no campaign has run an experiment yet")
    budget = min(budget or longest, longest)
    rng = np.random.default_rng(seed)
    matrices = {
        arm.name: np.array(
            [compare.best_so_far(r.metrics, r.feasible, direction, budget) for r in arm.repeats]
        )
        for arm in arms
    }
    summaries = {
        name: compare.summarize_arm(m, direction, family["target"], rng, n_resamples)
        for name, m in matrices.items()
    }
    finals = {name: s["finals"] for name, s in summaries.items()}
    notes = []
    for arm in arms:
        short = [r for r in arm.repeats if r.n < budget and r.ended in BUDGET_TRIGGERS]
        if short:
            notes.append(
                f"{arm.name}: {len(short)} repeat(s) ended by their own budget ({short[0].ended}) before "
                f"{budget} experiments and are held at their final best; pass --budget "
                f"{min(r.n for r in short)} to compare like for like."
            )
        if arm.unstarted:
            notes.append(
                f"{arm.name}: not started yet, left out: {', '.join(d.name for d in arm.unstarted)}."
            )
        unfinished = [r.dir.name for r in arm.repeats if r.ended is None]
        if unfinished:
            notes.append(
                f"{arm.name}: unfinished (running or interrupted), held at their last best: {', '.join(unfinished)}."
            )
    return Analysis(
        family,
        direction,
        budget,
        noise_reference(arms, sigma),
        arms,
        summaries,
        compare.improvement_table(finals, direction, rng, n_resamples),
        notes,
    )


# ----- figures ---------------------------------------------------------------------------


def _color(i: int) -> str:
    return f"C{i % 10}"


def _finite(x: np.ndarray) -> np.ndarray:
    return np.where(np.isfinite(x), x, np.nan)  # "no feasible run" is not drawn


def _decorate(ax, a: Analysis, values: list[np.ndarray]) -> None:
    """Target, baseline noise band, log scale once the values span a decade, and the sigma axis."""
    target = a.family["target"]
    if a.noise:
        mu, sd = a.noise["reference"], a.noise["sigma"]
        ax.axhline(mu, color="gray", lw=1, ls=":", label="baseline")
        ax.axhspan(mu - sd, mu + sd, color="gray", alpha=0.15)
    if target is not None:
        ax.axhline(target, color="black", lw=1, ls="--", label=f"target {target:g}")
    finite = np.concatenate([v[np.isfinite(v)] for v in values] + [np.array([target or np.nan])])
    finite = finite[np.isfinite(finite)]
    if finite.size and finite.min() > 0 and finite.max() / finite.min() >= LOG_SPAN:
        ax.set_yscale("log")
        _log_ticks(ax.yaxis)
    elif a.noise:  # an affine sigma axis only makes sense on a linear one
        mu, sd, d = a.noise["reference"], a.noise["sigma"], a.direction
        sec = ax.secondary_yaxis("right", functions=(lambda v: d * (v - mu) / sd, lambda m: mu + d * m * sd))
        sec.set_ylabel("σ better than the baseline")


def _log_ticks(axis) -> None:
    """Plain labels at 1, 2 and 5 times each power of ten: a log axis spanning one decade stays readable."""
    axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def _band_figure(
    a: Analysis, x: np.ndarray, bands: dict[str, dict], xlabel: str, title: str, out: Path, where: str
) -> None:
    """Each arm's IQM (line) with its 95% band and its median (dashed), as steps: a best so far only
    changes when an experiment ends."""
    fig = Figure(figsize=(8, 4.5))
    ax = fig.add_subplot()
    values = []
    for i, arm in enumerate(a.arms):
        iqm, med = bands[arm.name]["iqm"], bands[arm.name]["median"]
        color = _color(i)
        label = f"{arm.name} (n={len(arm.repeats)})"
        ax.step(x, _finite(iqm["point"]), where=where, color=color, lw=2, label=label)
        ax.step(x, _finite(med["point"]), where=where, color=color, lw=1, ls="--")
        low, high = _finite(iqm["low"]), _finite(iqm["high"])
        ax.fill_between(x, low, high, step=where, color=color, alpha=0.2, lw=0)
        values += [iqm["low"], iqm["high"], med["point"]]
    _decorate(ax, a, values)
    better = "lower" if a.direction < 0 else "higher"
    ax.set(xlabel=xlabel, ylabel=f"best {a.family['metric']} so far ({better} is better)", title=title)
    if where == "pre":  # experiments: whole numbers
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)


def budget_figure(a: Analysis, out: Path) -> None:
    """Against experiments: the value after k experiments is drawn over (k-1, k]."""
    x = np.arange(0, a.budget + 1)
    bands = {
        name: {k: {e: np.insert(v, 0, v[0]) for e, v in s[k].items()} for k in ("iqm", "median")}
        for name, s in a.summaries.items()
    }
    title = "Best so far across repeats: IQM (line) with 95% CI, median (dashed)"
    _band_figure(a, x, bands, "experiments", title, out, where="pre")


def wallclock_figure(a: Analysis, out: Path, rng: np.random.Generator, n_resamples: int) -> None:
    """The same bands against loop time: a repeat's best at time t is its best among experiments done by t."""
    ends = [r.elapsed[: a.budget][-1] for arm in a.arms for r in arm.repeats if r.n]
    horizon = max(ends) if ends else 0.0
    unit, scale = ("h", 3600.0) if horizon > 7200 else ("min", 60.0) if horizon > 120 else ("s", 1.0)
    grid = np.linspace(0.0, horizon, TIME_POINTS)
    bands = {}
    for arm in a.arms:
        matrix = np.array(
            [
                compare.best_at_times(
                    compare.best_so_far(r.metrics, r.feasible, a.direction, min(r.n, a.budget)),
                    r.elapsed[: a.budget],
                    grid,
                    a.direction,
                )
                for r in arm.repeats
            ]
        )
        bands[arm.name] = {
            name: dict(
                zip(
                    ("point", "low", "high"),
                    compare.location_band(matrix, stat, rng, n_resamples),
                    strict=True,
                )
            )
            for name, stat in (("iqm", compare.iqm), ("median", compare.median))
        }
    title = "Best so far against wall-clock (loop time): IQM with 95% CI, median (dashed)"
    _band_figure(a, grid / scale, bands, f"wall-clock ({unit})", title, out, where="post")


def profile_figure(a: Analysis, out: Path, rng: np.random.Generator, n_resamples: int) -> None:
    """Performance profile: the fraction of repeats whose final best is at or beyond each value, with a
    95% band (a repeat with no feasible run counts for no value)."""
    finals = np.concatenate([s["finals"] for s in a.summaries.values()])
    finite = finals[np.isfinite(finals)]
    target = a.family["target"]
    if target is not None:
        finite = np.append(finite, target)
    fig = Figure(figsize=(7, 4.5))
    ax = fig.add_subplot()
    positive = finite.size and finite.min() > 0
    if finite.size:
        lo, hi = finite.min(), finite.max()
        pad = (hi - lo) * 0.05 or abs(hi) * 0.05 or 1.0
        grid = (
            np.geomspace(lo / 1.1, hi * 1.1, TIME_POINTS)
            if positive
            else np.linspace(lo - pad, hi + pad, TIME_POINTS)
        )
        for i, arm in enumerate(a.arms):
            indicators = compare.profile(a.summaries[arm.name]["finals"], grid, a.direction)
            point, low, high = compare.location_band(indicators, np.mean, rng, n_resamples)
            ax.step(
                grid, point, where="post", color=_color(i), lw=2, label=f"{arm.name} (n={len(arm.repeats)})"
            )
            ax.fill_between(grid, low, high, step="post", color=_color(i), alpha=0.2, lw=0)
    if target is not None:
        ax.axvline(target, color="black", lw=1, ls="--", label=f"target {target:g}")
    if positive:
        ax.set_xscale("log")
        _log_ticks(ax.xaxis)
    relation = "≤" if a.direction < 0 else "≥"
    metric = a.family["metric"]
    ax.set(
        xlabel=f"{metric} value τ",
        ylabel=f"fraction of repeats with final best {relation} τ",
        ylim=(-0.02, 1.02),
        title=f"Performance profile at {a.budget} experiments",
    )
    if ax.get_legend_handles_labels()[0]:  # nothing to draw when no repeat is feasible and there is no target
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)


# ----- compare.md and compare.json -------------------------------------------------------


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
