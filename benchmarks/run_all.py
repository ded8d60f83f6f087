"""Every benchmark the project tracks, in one Markdown table.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/run_all.py [--quick] [--tuned] [--parallel] [--out PATH]

Reuses the measurements of bench_envs.py, bench_experts_cbf.py and bench_audit.py; times each
family's train.py through autoresearch.runner, the loop's own path (a patched copy in a
temporary run directory, run as a subprocess); measures the loop's overhead per iteration on a
temporary copy of the toy family; and reads the key-free arms' experiments to target from the
committed groups of repeats in results/, the compute early stopping saved from committed campaigns
and the main job's wall time on a fresh clone from the log benchmarks/main_job_fresh_clone.sh
writes, the SB3 adapter's and the sealed split's costs from bench_sb3.py's and bench_evaluation.py's
committed output (nothing is run for those rows); ``--parallel`` also times a docking campaign at --workers 1 and 2. A few minutes; ``--quick`` shortens every measurement
(a smoke test, not numbers to quote). 'Tuned' is the audited best in each family.json: its wall
time is read from the committed reseeded runs, or with ``--tuned`` timed now (docking's takes
minutes on a CPU). Progress goes to stderr, the table to stdout.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import re
import sys
import tempfile
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from importlib.metadata import version
from pathlib import Path
from typing import Any

import numpy as np
from bench_audit import audit_walls, make_campaign
from bench_envs import NATIVE_ENVS, SYNC_ENVS, bench_single, bench_vector
from bench_experts_cbf import cbf_measure, docking_expert_run, rendezvous_expert_time
from bench_loop_parallel import campaign_wall

from autoresearch.campaign import BASELINE_PROPOSER, Campaign, Status
from autoresearch.campaign.audit_log import read_audit
from autoresearch.compare.inputs import common_family, load_arms, noise_reference, read_repeat
from autoresearch.compare.stats import best_so_far, experiments_to_target, median_experiments_to_target
from autoresearch.direction import Direction
from autoresearch.execution.runner import run_locally
from autoresearch.execution.spec import RunSpec
from autoresearch.family import Family
from autoresearch.journal import read_json, read_jsonl
from autoresearch.proposers import DEFAULT_SPACE

ROOT = Path(__file__).resolve().parents[1]
FAMILIES = ("rendezvous", "docking")
ENV_IDS = ("CWHRendezvous-v0", "CWHDockKOZ-v1")
NATIVE = NATIVE_ENVS[0]
BASELINE_TIMEOUT_S, TUNED_TIMEOUT_S = 300.0, 1800.0
# Committed groups of repeats (loop --repeats) per family: (directory, prefix of the arm groups).
MAIN_JOB_LOG = "results/logs/main_job_fresh_clone.txt"
COMPARE_GROUPS = {
    "rendezvous": ("results/compare-rendezvous", "rdv"),
    "docking": ("results/compare", "dock"),
    "docking, GP told graded constraints or 0/1": ("results/constraints-ab", "dock-gp"),
}

# Committed campaigns of one search without and with --early-stop: (label, without, with).
EARLY_STOP_PAIRS = [
    ("rendezvous TPE, 40 experiments", "results/rendezvous/tpe", "results/early_stop/rdv-tpe-asha"),
]

# Committed key-free evidence campaigns (results/evidence/run.sh), one per family.
EVIDENCE_CAMPAIGNS = ("results/evidence/rendezvous-gp", "results/evidence/docking-gp")

PARALLEL_LOG = "results/logs/bench_loop_parallel.txt"  # bench_loop_parallel.py's committed output
SB3_LOG = "results/logs/bench_sb3.txt"  # bench_sb3.py's committed output
EVALUATION_LOG = "results/logs/bench_evaluation.txt"  # bench_evaluation.py's committed output
INSTALL_LOG = "results/logs/bench_install.txt"  # bench_install.py's committed output
CBF_MULTI_LOG = "results/logs/bench_cbf_multi.txt"  # bench_cbf_multi.py's committed output
RAY_LOG = "results/logs/bench_ray_scaling.txt"  # bench_ray_scaling.py's committed output
EXPERT_SOLVERS_LOG = "results/logs/bench_expert_solvers.txt"  # bench_expert_solvers.py's committed output
FLIGHT_PATH_LOG = "results/logs/bench_flight_path.txt"

Row = tuple[str, str, str, str]  # what | measured | ratio / comparison | note


@dataclass(frozen=True)
class Settings:
    env_seconds: float  # per env measurement
    cbf_repeats: tuple[int, int]  # best-of repeats: batched, proxsuite
    rendezvous_repeats: int
    docking_demos: int
    loop_iterations: int
    audit_sleep_s: float


FULL = Settings(2.0, (50, 3), 3, 128, 10, 0.3)
QUICK = Settings(0.3, (5, 1), 1, 16, 4, 0.05)


class Progress:
    """One line per section on stderr, with the seconds since the start."""

    def __init__(self) -> None:
        self.started = time.monotonic()

    def __call__(self, message: str) -> None:
        print(f"[{time.monotonic() - self.started:6.1f} s] {message}", file=sys.stderr, flush=True)


def env_rows(seconds: float) -> list[Row]:
    rows = []
    for env_id in ENV_IDS:
        sync = bench_vector(env_id, SYNC_ENVS, "sync", seconds)
        measured = {
            "single env (gym.make)": bench_single(env_id, seconds),
            f"SyncVectorEnv x{SYNC_ENVS}": sync,
            f"native vector env x{NATIVE}": bench_vector(env_id, NATIVE, "vector_entry_point", seconds),
        }
        for name, (total, stepping) in measured.items():
            ratio = f"{stepping / sync[1]:.1f}x vs Sync ({total / sync[0]:.1f}x incl. resets)"
            if name.startswith("Sync"):
                ratio = "reference"
            note = "target >= 100x stepping only" if name.startswith("native") else ""
            rows.append(
                (
                    f"{env_id}, {name}: env-steps/s",
                    f"{stepping:,.0f} ({total:,.0f} incl. resets)",
                    ratio,
                    note,
                )
            )
    return rows


def cbf_rows(repeats: tuple[int, int]) -> list[Row]:
    m = cbf_measure(np.random.default_rng(0), repeats=repeats[0], qp_repeats=repeats[1])
    return [
        (
            "CBF filtered actions/s, batched exact `safe_actions`",
            f"{m.n / m.batched_s:,.0f}",
            f"{m.proxsuite_s / m.batched_s:.0f}x vs proxsuite (target >= 100x)",
            f"{m.n} docking states; max difference {m.gap:.1e} N",
        ),
        ("CBF filtered actions/s, one proxsuite QP per action", f"{m.n / m.proxsuite_s:,.0f}", "", ""),
    ]


def expert_rows(settings: Settings) -> list[Row]:
    rendezvous = rendezvous_expert_time(repeats=settings.rendezvous_repeats)
    _, _, solutions, docking = docking_expert_run(settings.docking_demos)
    failures = sum(s is None for s in solutions)
    return [
        (
            "rendezvous expert, ms per accepted demonstration",
            f"{1e3 * rendezvous:.2f} ms",
            "target <= 2 ms",
            "",
        ),
        (
            "docking expert (SCP), ms per demonstration",
            f"{1e3 * docking:.1f} ms",
            "target <= 58 ms",
            f"{len(solutions)} screened starts, {failures} failed",
        ),
    ]


def experiment_row(name: str, overrides: dict[str, Any], label: str, where: Path, timeout: float) -> Row:
    """Wall time of one run of the family's train.py at its baseline plus ``overrides``."""
    family = Family.load(ROOT / "families" / name)
    run_dir = where / f"{name}-{label}"
    config = {**family.baseline_config, **overrides}
    spec = RunSpec(
        family, config, f"bench-{label}", family.default_seed, run_dir, where / "runs.jsonl", timeout
    )
    result = run_locally(spec)
    what = f"{label} experiment wall time, {name}"
    config = ", ".join(f"{k}={v}" for k, v in overrides.items())
    if not result.ok:
        return (what, result.status, "", (result.reason or "")[:200])
    note = f"{family.metric} {result.metric:.4g}" + (f"; {config}" if config else "")
    return (what, f"{result.wall_seconds:.1f} s", "target < 30 s" if label == "baseline" else "", note)


def recorded_tuned_row(name: str, config: dict[str, Any]) -> Row:
    """Wall time of the audited best configuration as its committed reseeded runs recorded it."""
    walls = [
        row["wall_seconds"]
        for log in sorted((ROOT / "results").glob("**/audit/*/*.jsonl"))
        if log.stem in ("verify", "prune")
        for row in read_jsonl(log)
        if row.get("status") == "ok" and row.get("config") == config and row.get("wall_seconds")
    ]
    what = f"tuned experiment wall time, {name}"
    if not walls:
        return (what, "not recorded", "", "no reseeded run of the family's best in results/; use --tuned")
    note = f"median of {len(walls)} reseeded runs in results/ (audit logs); --tuned times one now"
    return (what, f"{float(np.median(walls)):.1f} s", "", note)


def experiment_rows(tuned: bool, where: Path, progress: Progress) -> list[Row]:
    """Baseline and tuned ('tuned': the audited best in the family's family.json) wall times."""
    rows = []
    for name in FAMILIES:
        progress(f"baseline experiment, {name}")
        rows.append(experiment_row(name, {}, "baseline", where, BASELINE_TIMEOUT_S))
    for name in FAMILIES:
        best = Family.load(ROOT / "families" / name).registry.get("best")
        if not best:
            rows.append((f"tuned experiment wall time, {name}", "no audited best", "", "run the audit first"))
        elif tuned:
            progress(f"tuned experiment, {name}")
            rows.append(experiment_row(name, best["config"], "tuned", where, TUNED_TIMEOUT_S))
        else:
            rows.append(recorded_tuned_row(name, best["config"]))
    return rows


def loop_row(iterations: int, where: Path) -> Row:
    """The loop's own time per experiment: its clock minus its runs' wall times, key-free proposer."""
    records = Campaign(make_campaign(where, iterations)).records()
    runs = [r for r in records if r.status in (Status.RAN, Status.FAILED)]
    loop_s = records[-1].elapsed_s  # the orchestrator's own clock at its last record
    run_s = sum(r.wall_seconds for r in runs)
    return (
        "orchestrator overhead per iteration (no training, no LLM)",
        f"{1e3 * (loop_s - run_s) / len(runs):.0f} ms",
        "",
        f"toy family, random proposer, {len(runs)} runs: loop {loop_s:.1f} s - runs {run_s:.1f} s",
    )


def audit_row(sleep: float, where: Path) -> Row:
    roots = {w: make_campaign(Path(tempfile.mkdtemp(dir=where))) for w in (1, 2)}
    results = audit_walls(roots, sleep)
    (one, runs), (two, _) = results[1], results[2]
    return (
        "audit wall time, 2 workers vs 1",
        f"{two:.1f} s vs {one:.1f} s",
        f"{two / one:.2f}x (target <= 0.6x)",
        f"toy campaign audit, {runs} runs, train.py sleeps {sleep:g} s",
    )


def committed_walls(log: Path) -> dict[int, float]:
    """{workers: wall seconds} from bench_loop_parallel.py's committed output."""
    if not log.is_file():
        return {}
    lines = [line.split() for line in log.read_text().splitlines() if line.startswith("docking random")]
    at = [words.index("--workers") for words in lines]  # "--workers K  WALL s ..."
    return {int(words[i + 1]): float(words[i + 2]) for words, i in zip(lines, at, strict=True)}


def parallel_row(measure: bool, where: Path) -> Row:
    """Campaign wall time, --workers 2 vs 1 (bench_loop_parallel.py's docking campaign of 8 runs)."""
    what = "campaign wall time, loop --workers 2 vs 1"
    note = "docking random, 8 runs, seed 0"
    if measure:
        walls = {w: campaign_wall("docking", w, 8, 0, where)[0] for w in (1, 2)}
    else:  # minutes of training: the committed measurement unless asked to time it again
        walls = committed_walls(ROOT / PARALLEL_LOG)
        note += f"; from {PARALLEL_LOG} (--parallel times it again)"
    if not {1, 2} <= set(walls):
        return (what, "not run", "", "--parallel times it (minutes)")
    one, two = walls[1], walls[2]
    return (what, f"{two:.1f} s vs {one:.1f} s", f"{two / one:.2f}x (target <= 0.6x)", note)


def _search_cost(root: Path, direction: int) -> tuple[int, float, float | None, int]:
    """(experiments, run-seconds, best finished metric, finished runs) of a committed campaign."""
    runs = [r for r in Campaign(root).started() if r.proposer != BASELINE_PROPOSER]
    finished = [r.metric for r in runs if r.ran]
    best = max(finished, key=lambda m: direction * m) if finished else None
    return len(runs), sum(r.wall_seconds or 0.0 for r in runs), best, len(finished)


def early_stop_rows() -> list[Row]:
    """Run-seconds per experiment and best found, the same search without and with early stopping,
    from committed campaigns (nothing is run)."""
    rows = []
    for label, without, with_ in EARLY_STOP_PAIRS:
        what = f"early stopping, {label}: run-seconds per experiment"
        if not (ROOT / with_ / "proposals.jsonl").is_file():
            rows.append((what, "not run", "", f"needs {with_} (results/early_stop/)"))
            continue
        direction = Direction.of(Campaign(ROOT / without).registry()["direction"])
        stop = Campaign(ROOT / with_).meta().settings["early_stop"]
        (n0, s0, best0, done0), (n1, s1, best1, done1) = (
            _search_cost(ROOT / d, direction) for d in (without, with_)
        )
        rows.append(
            (
                f"{what}, {stop} vs none",
                f"{s1 / n1:.1f} s vs {s0 / n0:.1f} s",
                f"{s1 / n1 / (s0 / n0):.2f}x",
                f"best {best1:.4g} vs {best0:.4g}; runs finished {done1}/{n1} vs {done0}/{n0}; {with_}",
            )
        )
    return rows


def main_job_row() -> Row:
    """The main job's wall time on a fresh clone once installed, read from the log that
    benchmarks/main_job_fresh_clone.sh writes (scripts/main.sh's own '[main] wall time' line)."""
    what = "main job (`bash scripts/main.sh`) on a fresh clone, once installed: wall time"
    how = "bash benchmarks/main_job_fresh_clone.sh"
    log = ROOT / MAIN_JOB_LOG
    text = log.read_text(encoding="utf-8") if log.is_file() else ""
    wall = re.search(r"^\[main\] wall time: (\d+) s$", text, re.MULTILINE)
    if not wall:
        return (what, "not run", "", f"{how} writes {MAIN_JOB_LOG}")
    install = re.search(r"install: (\d+) s", text)
    headline = re.search(r"^\[main\] headline: (.*)$", text, re.MULTILINE)
    notes = [headline.group(1) if headline else "no headline", MAIN_JOB_LOG, how]
    if install:
        notes.insert(1, f"install {install.group(1)} s before it")
    return (what, f"{wall.group(1)} s", "target <= 600 s", "; ".join(notes))


def table_cells(text: str, first: str) -> list[list[str]]:
    """The cells of every Markdown table row in ``text`` whose first cell starts with ``first``."""
    return [
        [c.strip() for c in line.strip().strip("|").split("|")]
        for line in text.splitlines()
        if line.startswith(f"| {first}")
    ]


def sb3_rows() -> list[Row]:
    """PPO's throughput on the native SB3 adapter against DummyVecEnv, from bench_sb3.py's
    committed output (one table per env, in the order it ran; nothing is run)."""
    log = ROOT / SB3_LOG
    what = "SB3 PPO.learn env-steps/s, NativeVecEnv vs DummyVecEnv"
    if not log.is_file():
        return [(what, "not run", "", f"benchmarks/bench_sb3.py > {SB3_LOG}")]
    text = log.read_text(encoding="utf-8")
    envs = re.findall(r"PPO on (\S+), (\d+) envs", text)
    native, dummy = table_cells(text, "NativeVecEnv, info_keys"), table_cells(text, "DummyVecEnv")
    return [
        (
            f"{what}, {env}",
            f"{fast[2]} vs {slow[2]}",
            f"{fast[3]} (rollout alone {fast[5]})",
            f"{n} envs, info_keys=('is_success',); from {SB3_LOG}",
        )
        for (env, n), fast, slow in zip(envs, native, dummy, strict=True)
    ]


def evaluation_rows() -> list[Row]:
    """What scoring on the sealed test split costs an audit run, from bench_evaluation.py's
    committed output (nothing is run)."""
    log = ROOT / EVALUATION_LOG
    what = "evaluation per audit run, sealed test split (1024 starts) vs search split"
    if not log.is_file():
        return [(what, "not run", "", f"benchmarks/bench_evaluation.py > {EVALUATION_LOG}")]
    searched = re.search(r"build search \((\d+)\)", log.read_text(encoding="utf-8"))
    what += f" ({searched.group(1)})" if searched else ""  # the size the log was measured at
    return [
        (
            f"{what}, {family}",
            f"{test} vs {search}",
            ratio,
            f"start sets built once: {build}; {EVALUATION_LOG}",
        )
        for family, _, build, search, test, ratio in table_cells(log.read_text(encoding="utf-8"), "")
        if family != "family"  # the header
    ]


def install_rows() -> list[Row]:
    """Install sizes and start-up times, from bench_install.py's committed output (building its
    venvs takes minutes and the network, so nothing is run here)."""
    log = ROOT / INSTALL_LOG
    if not log.is_file():
        return [("install size and start-up", "not run", "", f"benchmarks/bench_install.py > {INSTALL_LOG}")]
    text = log.read_text(encoding="utf-8")
    cells = table_cells(text, "install size") + table_cells(text, "start-up")
    return [(what, value, comparison, f"from {INSTALL_LOG}") for what, value, comparison in cells]


def cbf_multi_rows() -> list[Row]:
    """The multi-constraint CBF QP against proxsuite and the whole filter's throughput, from
    bench_cbf_multi.py's committed output (nothing is run)."""
    log = ROOT / CBF_MULTI_LOG
    what = "multi-constraint CBF QP/s, exact batched vs one proxsuite QP"
    if not log.is_file():
        return [(what, "not run", "", f"benchmarks/bench_cbf_multi.py > {CBF_MULTI_LOG}")]
    text = log.read_text(encoding="utf-8")
    qps = [
        (
            f"{what}, {cells[0]} instances",
            f"{cells[5]} vs {cells[6]}",
            f"{cells[7]} (target >= 50x)",
            f"max gap {cells[4]} N; {CBF_MULTI_LOG}",
        )
        for cells in table_cells(text, "")
        if len(cells) == 8 and cells[0].startswith(("random", "the filter"))
    ]
    whole = [
        (
            f"multi-constraint CBF, whole filter: actions/s, {name}",
            actions,
            f"{ratio} one proxsuite QP",
            CBF_MULTI_LOG,
        )
        for name, actions, ratio in table_cells(text, "safe_actions_multi")
    ]
    return qps + whole


def expert_solver_rows() -> list[Row]:
    """The constrained docking expert with Clarabel's SOCP against tangent-plane cuts, per start and
    in all, from bench_expert_solvers.py's committed output (nothing is run)."""
    log = ROOT / EXPERT_SOLVERS_LOG
    what = "constrained docking expert (SCP), s per start: Clarabel SOCP vs polyhedral cuts"
    if not log.is_file():
        return [(what, "not run", "", f"benchmarks/bench_expert_solvers.py > {EXPERT_SOLVERS_LOG}")]
    text = log.read_text(encoding="utf-8")
    runs = {cells[0]: cells for cells in table_cells(text, "") if len(cells) == 6 and " of " in cells[1]}
    conic, cuts = runs["Clarabel SOCP"], runs["polyhedral cuts"]
    agreement = re.search(r"final costs agree within (\S+) relative", text)
    return [
        (
            f"{what} (median, max)",
            f"{conic[2]} vs {cuts[2]}; max {conic[3]} vs {cuts[3]}",
            f"in all {conic[4]} vs {cuts[4]}",
            f"verified {conic[1]} vs {cuts[1]}; final costs within {agreement.group(1) if agreement else '?'}; "
            f"{EXPERT_SOLVERS_LOG}",
        )
    ]


def flight_path_rows() -> list[Row]:
    """The learned robust row's per-step compute, numpy against compiled (filters and policy), and
    against the robust MPC's mean step, from bench_flight_path.py's committed output (nothing is run)."""
    log = ROOT / FLIGHT_PATH_LOG
    what = "learned robust row, µs a step (median): numpy path vs compiled (filters and policy compiled)"
    if not log.is_file():
        return [(what, "not run", "", f"benchmarks/bench_flight_path.py > {FLIGHT_PATH_LOG}")]
    text = log.read_text(encoding="utf-8")
    medians = {line[:44].strip(): line[44:].split()[0] for line in text.splitlines() if line[44:].split()}
    pattern = r"{}: (\S+) of the numpy path; of the robust MPC's mean step, \S+ with navigation, exported policy \+ filter (\S+?);?\s"
    onnx, compiled = (
        re.search(pattern.format(path), text)
        for path in ("compiled, ONNX policy", "compiled, compiled policy")
    )
    if onnx is None or compiled is None:
        raise ValueError(f"{FLIGHT_PATH_LOG} has no ratios line: run benchmarks/bench_flight_path.py again")
    return [
        (
            what,
            f"{medians['numpy']} vs {medians['compiled, compiled policy']}",
            f"{compiled.group(1)} (means); exported policy + filter {compiled.group(2)} of the robust MPC's "
            f"mean step (target <= 0.01; ONNX policy: {onnx.group(2)})",
            f"policy {medians['numpy: policy']} (torch) vs {medians['compiled, compiled policy: policy']} "
            f"(ONNX {medians['compiled, ONNX policy: policy']}), filter {medians['numpy: filter']} vs "
            f"{medians['compiled, compiled policy: filter']}, navigation filter {medians['numpy: navigation']} "
            f"vs {medians['compiled, compiled policy: navigation']}; {FLIGHT_PATH_LOG}",
        )
    ]


def ray_rows() -> list[Row]:
    """Campaign and audit wall time against Ray workers, and Ray's overhead per run, from
    bench_ray_scaling.py's committed output (it starts a Ray instance per worker count)."""
    log = ROOT / RAY_LOG
    what = "Ray workers: campaign (--early-stop median) and audit wall time"
    if not log.is_file():
        return [(what, "not run", "", f"benchmarks/bench_ray_scaling.py > {RAY_LOG}")]
    text = log.read_text(encoding="utf-8")
    rows: list[Row] = [
        (
            f"{what}, {workers} vs 1 worker(s)",
            f"{campaign} / {audit}",
            f"{campaign_ratio} / {audit_ratio}",
            f"sleep-dominated toy runs, local Ray instance; {RAY_LOG}",
        )
        for workers, campaign, campaign_ratio, audit, audit_ratio in (
            cells for cells in table_cells(text, "") if len(cells) == 5 and cells[0].isdigit()
        )
        if workers != "1"
    ]
    rows += [
        (
            f"Ray overhead per run, {mode.split(', ')[1]}",
            f"{seconds} s per run",
            f"{extra} s vs local",
            RAY_LOG,
        )
        for mode, seconds, extra in table_cells(text, "Ray task")
    ]
    return rows


def evidence_rows() -> list[Row]:
    """Experiments and wall-clock to the family's target (single seed, feasible runs) in each
    committed evidence campaign, and its best candidate's reseeded verification (nothing is run)."""
    rows = []
    for where in EVIDENCE_CAMPAIGNS:
        root = ROOT / where
        if not (root / "proposals.jsonl").is_file():
            rows.append((f"key-free evidence campaign {root.name}", "not run", "", f"needs {where}"))
            continue
        meta, run = Campaign(root).meta(), read_repeat(root)
        registry, settings, target = run.registry, meta.settings, run.registry["target"]
        direction = Direction.of(registry["direction"])
        best = best_so_far(run.metrics, run.feasible, direction, run.n)
        (hit,) = experiments_to_target(best[None, :], target, direction)
        measured = (
            f"target {target:g} after {hit} of {run.n} finished experiments, {run.elapsed[hit - 1]:.0f} s"
            if hit
            else f"target {target:g} not reached in {run.n} experiments, {run.elapsed[-1]:.0f} s"
        )
        audit = read_audit(root)
        split = (audit.get("verify") or {}).get("split", "search")  # audits before the sealed split: search
        reseeded = [
            c for c in (audit.get("verify") or {}).get("candidates", []) if c.get("sigma_r") is not None
        ]
        verdict = (
            "; ".join(
                f"{c['config_id']} reseeded on {split} {c['mu_r']:.4g} +- {c['sigma_r']:.2g} (n={c['n']}): "
                f"{c['reason']}"
                for c in reseeded
            )
            or "no candidate reseeded"
        )
        rows.append(
            (
                f"key-free evidence campaign, {registry['name']}: {meta.proposer} over {settings['space']}",
                measured,
                verdict,
                f"{settings['workers']} workers, --early-stop {settings['early_stop']}, "
                f"{settings['timeout_per_run']:g} s cap; {where}",
            )
        )
    return rows


def group_space(group: Path) -> str:
    """The space a group of repeats searched (before --space: its proposer's default)."""
    meta = read_json(group / "repeats.json")
    return meta["settings"].get("space") or DEFAULT_SPACE.get(meta["proposer"], "bounds")


def compare_rows() -> list[Row]:
    """Experiments to target per key-free arm, from the committed groups of repeats, computed by
    autoresearch.compare (best-so-far over feasible runs, right-censored at the budget)."""
    rows = []
    for name, (where, prefix) in COMPARE_GROUPS.items():
        groups = sorted(g for g in (ROOT / where).glob(f"{prefix}-*") if (g / "repeats.json").is_file())
        what = f"key-free arms, {name}: experiments to target (median over repeats)"
        if not groups:
            rows.append((what, "not run", "", f"needs {where}/{prefix}-<arm>/ groups (loop --repeats)"))
            continue
        arms = load_arms([(g.name.removeprefix(prefix + "-"), [g]) for g in groups])
        registry = common_family(arms)
        direction = Direction.of(registry["direction"])
        budget = max(r.n for arm in arms for r in arm.repeats)  # as compare: a stopped repeat keeps its best
        noise = noise_reference(arms, None)
        targets = [("target", registry["target"])]
        if noise:  # the audit's gate: 2 sigma of seed noise better than the baseline's seed mean
            targets.append(("2-sigma gate", noise["reference"] + direction * 2 * noise["sigma"]))
        spaces = {arm.name: group_space(g) for arm, g in zip(arms, groups, strict=True)}
        for label, target in targets:
            cells = []
            for arm in arms:
                matrix = np.array(
                    [best_so_far(r.metrics, r.feasible, direction, budget) for r in arm.repeats]
                )
                hits = experiments_to_target(matrix, target, direction)
                median_hit = median_experiments_to_target(hits)
                reached = sorted(h for h in hits if h is not None)
                count = f"{len(reached)}/{len(hits)}"
                if math.isinf(median_hit):  # censored at the budget, as compare prints it
                    at = f", at {', '.join(map(str, reached))}" if reached else ""
                    cells.append(f"{arm.name} >{budget} ({count}{at})")
                else:
                    cells.append(f"{arm.name} {median_hit:g} ({count})")
            same = len(set(spaces.values())) == 1
            space_note = (
                f"all over {next(iter(spaces.values()))}"
                if same
                else "spaces differ: " + ", ".join(f"{a} {s}" for a, s in spaces.items())
            )
            rows.append(
                (
                    f"{what}, {label} {target:.4g}",
                    "; ".join(cells),
                    f"budget {budget}, {min(len(a.repeats) for a in arms)}+ repeats per arm",
                    f"{space_note}; (k/n): repeats that reached it (at: their experiment counts); {where}",
                )
            )
    return rows


def machine_line() -> str:
    return (
        f"{os.cpu_count()} CPUs (load average {os.getloadavg()[0]:.2f}), Python {platform.python_version()}, "
        f"torch {version('torch')}, numpy {np.__version__}, "
        f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, "
        f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC"
    )


def table(rows: list[Row]) -> str:
    lines = ["| what | measured | ratio / comparison | note |", "|---|---|---|---|"]
    # A failed run's note quotes its stderr: keep every cell on one line and inside its column.
    cells = [[c.replace("\n", " ").replace("|", "\\|") for c in row] for row in rows]
    lines += [f"| {' | '.join(row)} |" for row in cells]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short measurements: a smoke test")
    parser.add_argument("--tuned", action="store_true", help="also time a tuned experiment per family")
    parser.add_argument("--parallel", action="store_true", help="also time a campaign at --workers 1 and 2")
    parser.add_argument("--out", type=Path, help="also write the table as Markdown to this file")
    args = parser.parse_args()
    settings = QUICK if args.quick else FULL
    progress = Progress()
    rows: list[Row] = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        progress("env throughput")
        rows += env_rows(settings.env_seconds)
        progress("CBF filter")
        rows += cbf_rows(settings.cbf_repeats)
        progress("experts")
        rows += expert_rows(settings)
        rows += experiment_rows(args.tuned, tmp, progress)
        progress("orchestrator overhead")
        rows.append(loop_row(settings.loop_iterations, Path(tempfile.mkdtemp(dir=tmp))))
        progress("audit, 1 and 2 workers")
        rows.append(audit_row(settings.audit_sleep_s, tmp))
        progress("campaign wall time, --workers 2 vs 1" if args.parallel else "parallel campaigns: skipped")
        rows.append(parallel_row(args.parallel, Path(tempfile.mkdtemp(dir=tmp))))
        progress("key-free arms and early stopping, from results/")
        rows += compare_rows()
        rows += early_stop_rows()
        rows += evidence_rows()
        rows += sb3_rows() + evaluation_rows() + install_rows() + cbf_multi_rows() + expert_solver_rows()
        rows += flight_path_rows()
        rows += ray_rows()
        rows.append(main_job_row())
    progress("done")
    text = f"{machine_line()}\n\n{table(rows)}\n"
    print(text, end="")
    if args.out:
        args.out.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
