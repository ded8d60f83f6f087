"""``autoresearch compare``'s figures: the best so far against experiments and against wall-clock
(median and IQM with their bootstrap bands), and the performance profile of the final bests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator, NullFormatter

from autoresearch.audit.figures import LOG_SPAN
from autoresearch.compare import stats as compare
from autoresearch.compare.analysis import Analysis

TIME_POINTS = 200


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
