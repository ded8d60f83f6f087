"""The audit report's figures: the search (paper Fig. hero a: every experiment's metric and each
arm's running best), the recipe (Fig. hero b: how each parameter moved), and the family's own
domain figure for the promoted configuration's saved policy (its optional report.py hook)."""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from autoresearch.audit.inputs import AuditedCampaign
from autoresearch.audit.outcome import promoted
from autoresearch.campaign import Campaign, Record, portable_path
from autoresearch.execution.runner import family_env
from autoresearch.family import Family
from autoresearch.verdicts import best_feasible

COLORS = {"agent": "#2ca02c", "random": "#1f77b4", "random_matched": "#6baed6", "other": "#ff7f0e"}
HOOK_TIMEOUT_S = 600.0
LOG_SPAN = 10.0  # the search figure goes log-scale once the metric spans a decade (paper Fig. hero a)


@dataclass(frozen=True)
class PlottedArm:
    label: str
    color: str
    records: list[Record]

    @property
    def ran(self) -> list[Record]:
        return [r for r in self.records if r.ran]


def load_arm(directory: Path, label: str | None, color: str) -> PlottedArm:
    arm = Campaign(directory)
    proposer = arm.meta().proposer if arm.exists() else "?"
    return PlottedArm(label or f"{proposer} ({directory.name})", color, arm.records())


def random_arms(audit: dict[str, Any]) -> list[PlottedArm]:
    """The random arms the campaign's audit ran."""
    arms = []
    for step, label in (("random", "random search"), ("random_matched", "random search, matched range")):
        part = audit.get(step)
        if part and Path(part["dir"]).is_dir():
            arms.append(load_arm(Path(part["dir"]), label, COLORS[step]))
    return arms


def search_figure(arms: list[PlottedArm], family: Family, noise: dict[str, Any] | None, out: Path) -> Figure:
    """Per-experiment metric (filled: feasible, hollow: infeasible) and each arm's running best, on
    the search split, one seed each; the x-axis spans the experiments (a stop record is none) and
    the legend sits beside the plot, never over the data. Returns the figure it saved."""
    fig = Figure(figsize=(10.5, 4.5))
    ax = fig.add_subplot()
    values, last = [], 1
    unfinished = []  # (arm, iterations) of the runs that started and came back without a metric
    for arm in arms:
        ran = arm.ran
        values += [r.metric for r in ran]
        lost = [r.iteration for r in arm.records if r.status.started_a_run and not r.ran]
        if lost:
            unfinished.append((arm, lost))
        for feasible in (True, False):
            pts = [r for r in ran if bool(r.feasible) == feasible]
            ax.scatter(
                [r.iteration for r in pts],
                [r.metric for r in pts],
                s=18,
                alpha=0.6,
                facecolors=arm.color if feasible else "none",
                edgecolors=arm.color,
                label=f"{arm.label}: {'feasible' if feasible else 'infeasible'} runs" if pts else None,
            )
        started = [r for r in arm.records if r.status.started_a_run]
        last = max([last, *(r.iteration for r in started)])
        trace = [(r.iteration, r.best_so_far) for r in started if r.best_so_far is not None]
        if trace:
            ax.step(
                *zip(*trace, strict=True),
                where="post",
                color=arm.color,
                lw=2,
                label=f"{arm.label}: best so far",
            )
    if noise and "mean" in noise:  # the search split's (a noise known only on the test split draws none)
        ax.axhline(noise["mean"], color="gray", lw=1, ls=":", label=f"baseline over {noise['k']} seeds")
        ax.axhspan(noise["mean"] - noise["std"], noise["mean"] + noise["std"], color="gray", alpha=0.15)
    if family.target is not None:
        ax.axhline(family.target, color="black", lw=1, ls="--", label=f"target {family.target:g}")
        values.append(family.target)
    if values and min(values) > 0 and max(values) / min(values) >= LOG_SPAN:
        ax.set_yscale("log")
    for arm, iterations in unfinished:  # drawn on the top edge: it has no value, but it cost a run
        ax.scatter(
            iterations,
            [1.0] * len(iterations),
            transform=ax.get_xaxis_transform(),
            marker="x",
            s=30,
            color=arm.color,
            clip_on=False,
            label=f"{arm.label}: did not finish (failed or timed out)",
        )
    better = "lower" if family.direction < 0 else "higher"
    ax.set(
        xlabel="experiment (in the order proposed)",
        ylabel=f"{family.metric_label} ({better} is better)",
        title="Search: every experiment, one seed each, on the search split",
        xlim=(0.5, last + 0.5),
    )
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    return fig


def recorded_params(records: list[Record], family: Family) -> list[str]:
    """The parameters the campaign's runs recorded, in the family's order: a parameter the family
    declared after the campaign ran (a family that only grew) is in none of its configurations."""
    recorded = {name for r in records if r.config for name in r.config}
    return [name for name in family.space.names if name in recorded]


def searched(registry: dict[str, Any] | None, name: str) -> bool:
    """Whether the campaign searched ``name``: False where its copy of family.json (``registry``, the
    space it searched) holds it at one value, as a protocol holds the axes it excludes."""
    spec = ((registry or {}).get("search_space") or {}).get(name)
    if not isinstance(spec, dict):
        return True
    if "choices" in spec:
        return len(spec["choices"]) > 1
    return not ("low" in spec and spec.get("low") == spec.get("high"))


def searched_choices(registry: dict[str, Any] | None, name: str) -> list[Any] | None:
    """The choices of categorical ``name`` in the campaign's copy of family.json (the space it searched),
    or None: a choice the family added since was never one of the campaign's."""
    spec = ((registry or {}).get("search_space") or {}).get(name)
    choices = spec.get("choices") if isinstance(spec, dict) and spec.get("type") == "categorical" else None
    return list(choices) if isinstance(choices, list) and choices else None


def recipe_figure(
    records: list[Record], family: Family, out: Path, registry: dict[str, Any] | None = None
) -> Figure:
    """How each parameter the campaign recorded moved: every run's value (dots) and the running
    best's value (line). A run without a parameter (recorded before the family declared it) has no
    dot for it, and no value is made up for it. A categorical's levels are those the campaign
    searched (``registry``: its copy of family.json), else the family's; a parameter the campaign's
    protocol held at one value has no panel (a flat line says nothing). Returns the figure it saved."""
    ran = [r for r in records if r.ran]
    names = [name for name in recorded_params(ran, family) if searched(registry, name)]
    ncols = max(1, min(3, len(names)))
    nrows = max(1, math.ceil(len(names) / ncols))
    fig = Figure(figsize=(4 * ncols, 2.3 * nrows))
    if not names:
        fig.text(0.5, 0.5, "no run of the campaign has a result yet", ha="center", va="center")
    best, best_configs = None, []
    for r in ran:
        best = best_feasible([best, r], family.direction)
        best_configs.append((r.iteration, best.config if best else None))
    for i, name in enumerate(names, start=1):
        ax = fig.add_subplot(nrows, ncols, i)
        param = family.space.params[name]
        has = [r for r in ran if name in r.config]
        if param.type == "categorical":
            levels = searched_choices(registry, name) or list(param.choices)
        else:
            levels = [False, True]
        if param.type in ("categorical", "bool"):  # a value recorded outside the declared ones keeps its own
            levels += [v for v in dict.fromkeys(r.config[name] for r in has) if v not in levels]

        def y(value, param=param, levels=levels):
            return levels.index(value) if param.type in ("categorical", "bool") else value

        ax.scatter(
            [r.iteration for r in has], [y(r.config[name]) for r in has], s=10, color="gray", alpha=0.5
        )
        line = [(it, y(cfg[name])) for it, cfg in best_configs if cfg is not None and name in cfg]
        if line:
            ax.step(*zip(*line, strict=True), where="post", color=COLORS["agent"], lw=2)
        if param.type in ("categorical", "bool"):
            ax.set_yticks(range(len(levels)), [str(v) for v in levels])
        elif param.type == "log-real":
            ax.set_yscale("log")
        ax.set_title(f"{name} ({param.axis})", fontsize=9)
        ax.set_ylabel("value", fontsize=7)
        if i > len(names) - ncols:  # the bottom row
            ax.set_xlabel("experiment", fontsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.tick_params(labelsize=7)
    fig.suptitle(
        "Recipe: each parameter the campaign searched, per experiment (dots: every run's value; line: the "
        "value of the best run so far, on the search split)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    return fig


def promoted_policy(campaign: AuditedCampaign, audit: dict[str, Any]) -> tuple[str, Path] | str:
    """The step and the saved policy directory of the promoted configuration's first valid reseed, or
    why there is none."""
    found = promoted(audit)
    if found is None:
        return "no promoted configuration to"
    step, entry = found
    run = next((r for r in entry["reseeds"] if r["excluded"] is None), None)
    return step, campaign.step_dir(step) / run["run_id"] / "out"


def family_hook(
    campaign: AuditedCampaign, audit: dict[str, Any], out: Path, hook: str = "report.py"
) -> str | None:
    """Run one of the family's optional hooks on the promoted configuration's saved policy, writing
    ``out``: report.py (``--out``, its domain figure) or export.py (``--onnx``, the policy as a file
    that flies). None when it wrote ``out``, else why not."""
    family = campaign.family
    verb = "export" if hook == "export.py" else "plot"
    if not (family.path / hook).is_file():
        return f"the family has no {hook} {'export' if verb == 'export' else 'plotting'} hook"
    found = promoted_policy(campaign, audit)
    if isinstance(found, str):
        return f"{found} {verb}"
    step, policy = found
    if not policy.is_dir():  # verification runs are not committed: a clone keeps the output, not the weights
        if out.exists():
            return None
        return f"the promoted policy's saved run ({portable_path(policy)}) is not here; re-run {step} to {verb} it"
    flag = "--onnx" if hook == "export.py" else "--out"
    cmd = [sys.executable, hook, "--policy", str(policy), flag, str(out.resolve())]
    try:
        done = subprocess.run(
            cmd,
            cwd=family.path,
            env=family_env(family.path),
            capture_output=True,
            text=True,
            timeout=HOOK_TIMEOUT_S,
        )
    except subprocess.TimeoutExpired:
        return f"the family's {hook} did not finish within {HOOK_TIMEOUT_S:g} s"
    if done.returncode != 0 or not out.exists():
        return f"the family's {hook} failed (exit {done.returncode}): {done.stderr.strip()[-300:]}"
    return None
