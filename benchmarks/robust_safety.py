"""Safety under the benchmark's own dispersions (issue 58): each classical controller on a shipped
sealed split, nominal and dispersed at 1 sigma and 3 sigma, with the filter and MPC on the navigation
estimate (the env scores the true state).

    python benchmarks/robust_safety.py                           # constrained docking, 1024 sealed starts
    python benchmarks/robust_safety.py --task docking            # the paper's docking problem
    python benchmarks/robust_safety.py --mpc-starts 2            # ... plus MPC rows on the first 2 starts

Per row: nominal success and fuel (energy over the shipped expert energy of the same start: median,
99th percentile, worst); per dispersion level: success, starts breaking each constraint and the
deepest violation of each (m, m/s, m), with the distance from the port where the deepest cone
violation sat; µs per step of one start flown alone (the policy and the filter, or MPC's solve).
The dispersions are the families' ``DISPERSIONS`` (1 sigma) and the same scaled by 3; the robust
filter and the robust MPC are sized for the 1-sigma set at ``--k-sigma`` (default 3).
Writes ``results/robust-safety/<task>.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from cwh_envs import splits
from cwh_envs.constraints import violation_depths
from cwh_envs.controllers import MinEnergyFeedback, WaypointFeedback
from cwh_envs.mpc import RecedingHorizon
from cwh_envs.prepare import load_train
from cwh_envs.robust_cbf import ErrorBounds
from cwh_envs.rollout import control_effort, fly
from cwh_envs.tube_mpc import TubeMPC

ROOT = Path(__file__).resolve().parents[1]
TASKS = ("docking-constrained", "docking")  # families whose PROBLEM and DISPERSIONS (1 sigma) are flown
DISPERSION_SEED = 0
TIMED_STARTS = 8
CONSTRAINTS = ("keep_out", "speed", "cone")


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", choices=TASKS, default="docking-constrained")
    parser.add_argument("--starts", type=int, default=None, help="the first N sealed starts (default: all)")
    parser.add_argument("--mpc-starts", type=int, default=0, help="MPC rows on the first N starts (slow)")
    parser.add_argument("--k-sigma", type=float, default=3.0)
    parser.add_argument(
        "--rows",
        nargs="+",
        default=None,
        help="fly only the rows named so (prefixes); keep the rest from the JSON",
    )
    parser.add_argument(
        "--retime",
        action="store_true",
        help="measure only the µs column of the rows named by --rows again (run alone); keep their flights",
    )
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "robust-safety")
    return parser.parse_args(argv)


def rows(problem, bounds: ErrorBounds, mpc_starts: int) -> list[dict]:
    """(name, policy factory, fly keywords, starts) of every row."""
    law = WaypointFeedback if problem.approach_cone is not None else MinEnergyFeedback
    label = "routed law" if problem.approach_cone is not None else "min-energy law"
    out = [
        dict(name=f"{label} + CBF", make=lambda: law(problem), fly=dict(cbf_margin=problem.margin)),
        dict(
            name=f"{label} + CBF fed the truth (comparison)",
            make=lambda: law(problem),
            fly=dict(cbf_margin=problem.margin, filter_sees="truth"),
        ),
        dict(
            name=f"{label} + robust CBF (1σ bounds, k={bounds.k_sigma:g})",
            make=lambda: law(problem),
            fly=dict(cbf_margin=problem.margin, cbf_bounds=bounds),
        ),
        dict(  # the same on flight software's navigation filter, commanding through its thrust estimate
            name=f"{label} + robust CBF + navigation filter (1σ bounds, k={bounds.k_sigma:g})",
            make=lambda: law(problem),
            fly=dict(cbf_margin=problem.margin, cbf_bounds=bounds, navigation=bounds),
        ),
        dict(  # the robust MPC of the targets: one plan per episode, cheap enough for every start
            name=f"tube MPC (1σ bounds, k={bounds.k_sigma:g})",
            make=lambda: TubeMPC(problem, bounds),
            fly={},
        ),
        dict(  # the same on the navigation filter's estimate, compensating the estimated thrust error
            name=f"tube MPC + navigation filter (1σ bounds, k={bounds.k_sigma:g})",
            make=lambda: TubeMPC(problem, bounds, navigation=True),
            fly={},
        ),
        dict(  # the tube MPC under the robust CBF, both on fly's navigation filter: the layers together
            name=f"tube MPC + robust CBF + navigation filter (1σ bounds, k={bounds.k_sigma:g})",
            make=lambda: TubeMPC(problem, bounds),
            fly=dict(cbf_margin=problem.margin, cbf_bounds=bounds, navigation=bounds),
        ),
    ]
    # The robust CBF's navigation margins sized by the navigation filter's own covariance (a
    # measurement-robust CBF on the estimator's error at each step; rollout.fly's cbf_navigation).
    covariance = dict(
        cbf_margin=problem.margin, cbf_bounds=bounds, navigation=bounds, cbf_navigation="covariance"
    )
    out += [
        dict(
            name=f"{label} + covariance-sized robust CBF + navigation filter (k={bounds.k_sigma:g})",
            make=lambda: law(problem),
            fly=covariance,
        ),
        dict(
            name=f"tube MPC + covariance-sized robust CBF + navigation filter (1σ bounds, k={bounds.k_sigma:g})",
            make=lambda: TubeMPC(problem, bounds),
            fly=covariance,
        ),
        dict(  # the same two with the robust filter's stop line (cwh_envs.robust_cbf)
            name=f"{label} + covariance-sized robust CBF with stop line + navigation filter (k={bounds.k_sigma:g})",
            make=lambda: law(problem),
            fly={**covariance, "cbf_stop_line": True},
        ),
        dict(
            name=(
                "tube MPC + covariance-sized robust CBF with stop line + navigation filter "
                f"(1σ bounds, k={bounds.k_sigma:g})"
            ),
            make=lambda: TubeMPC(problem, bounds),
            fly={**covariance, "cbf_stop_line": True},
        ),
    ]
    if mpc_starts:
        out += [
            dict(name="MPC", make=lambda: RecedingHorizon(problem), fly={}, starts=mpc_starts),
            dict(
                name=f"robust MPC (1σ bounds, k={bounds.k_sigma:g})",
                make=lambda: RecedingHorizon.robust(problem, bounds),
                fly={},
                starts=mpc_starts,
            ),
        ]
    return out


def measure(problem, one_sigma: dict, row: dict, starts, goals, energy) -> dict:
    n = row.get("starts", len(starts))
    starts, goals, energy = starts[:n], goals[:n], energy[:n]
    out: dict = {"controller": row["name"], "starts": n}
    policy = row["make"]()
    flight = fly(problem, policy, starts, goals, **row["fly"])
    ratio = control_effort(flight.thrust, problem)[0] / energy
    out["nominal"] = {
        "success": float(flight.is_success.mean()),
        "energy_ratio": {
            "median": float(np.median(ratio)),
            "p99": float(np.percentile(ratio, 99)),
            "worst": float(ratio.max()),
        },
        **counters(policy),
    }
    for level, scale in (("1σ", 1.0), ("3σ", 3.0)):
        spreads = {k: v * scale for k, v in one_sigma.items()}
        policy = row["make"]()
        flight = fly(
            problem, policy, starts, goals, dispersions=spreads, dispersion_seed=DISPERSION_SEED, **row["fly"]
        )
        out[level] = {
            "success": float(flight.is_success.mean()),
            **violations(problem, flight),
            **counters(policy),
        }
    out["us_per_step"] = time_per_step(problem, row, starts, goals)
    return out


def violations(problem, flight) -> dict:
    out = {"breaking": {}, "deepest": {}}
    for name in CONSTRAINTS:
        depth = getattr(flight, f"{name}_depth")
        if depth is None:
            continue
        out["breaking"][name] = int((depth > 0).sum())
        out["deepest"][name] = float(depth.max())
    if flight.cone_depth is not None and flight.cone_depth.max() > 0:
        i = int(np.argmax(flight.cone_depth))
        depth = violation_depths(
            flight.states[i], np.tile(flight.goals[i], (len(flight.states[i]), 1)), problem
        )
        k = int(np.argmax(depth["cone"]))
        out["deepest_cone_from_port_m"] = float(np.linalg.norm(flight.states[i, k, :3] - flight.goals[i]))
    return out


def counters(policy) -> dict:
    if isinstance(policy, TubeMPC):
        return {"plans": dict(policy.counts)}
    if not isinstance(policy, RecedingHorizon):
        return {}
    return {
        "solves": int(policy.solves.sum()),
        "failed_hard": int(policy.infeasible.sum()),
        "soft": int(policy.soft.sum()),
        "unanswered": int(policy.fallbacks.sum()),
    }


def time_per_step(problem, row: dict, starts, goals) -> float:
    """Median over TIMED_STARTS starts, each flown alone, of its wall time per step, µs."""
    times = []
    for i in range(min(TIMED_STARTS, len(starts))):
        policy = row["make"]()
        began = time.perf_counter()
        fly(problem, policy, starts[i : i + 1], goals[i : i + 1], **row["fly"])
        times.append((time.perf_counter() - began) / problem.horizon * 1e6)
    return float(np.median(times))


def retimed_note(results: list[dict]) -> list[str]:
    """The line saying which rows' µs column a ``--retime`` measured again, and by which command."""
    by: dict[str, list[str]] = {}
    for r in results:
        if "retimed_by" in r:
            by.setdefault(r["retimed_by"], []).append(r["controller"])
    every = len(by) == 1 and all("retimed_by" in r for r in results)
    return [
        f"µs/step of {'every row' if every else ', '.join(names)} measured again, alone, by `{c}`."
        for c, names in by.items()
    ]


def markdown(task: str, results: list[dict]) -> str:
    commands = sorted({r["command"] for r in results})
    lines = [
        f"# Safety under dispersions: {task}, sealed split",
        "",
        "Measured on this machine (2 cores) by " + " and ".join(f"`{c}`" for c in commands) + " (each",
        "row's command in the JSON). The filter and MPC act on the navigation estimate; the env",
        "scores the true state. Dispersions: the families' `DISPERSIONS` (1σ) and the same ×3 (3σ).",
        "Fuel: energy over the shipped expert energy of the same start (nominal flight).",
        *retimed_note(results),
        "",
        "| controller | starts | nominal success | fuel median / p99 / worst | 1σ success | 1σ starts breaking k/s/c | 1σ deepest k m / s m/s / c m | 3σ success | 3σ starts breaking k/s/c | 3σ deepest k / s / c | µs/step |",
        "|---|---:|---:|---|---:|---|---|---:|---|---|---:|",
    ]
    for r in results:
        cells = [r["controller"], str(r["starts"]), f"{r['nominal']['success']:.1%}"]
        e = r["nominal"]["energy_ratio"]
        cells.append(f"{e['median']:.3f} / {e['p99']:.3f} / {e['worst']:.3f}")
        for level in ("1σ", "3σ"):
            m = r[level]
            cells.append(f"{m['success']:.1%}")
            cells.append(" / ".join(str(m["breaking"].get(c, "–")) for c in CONSTRAINTS))
            cells.append(
                " / ".join(f"{m['deepest'][c]:.3g}" if c in m["deepest"] else "–" for c in CONSTRAINTS)
            )
        cells.append(f"{r['us_per_step']:,.0f}")
        lines.append("| " + " | ".join(cells) + " |")
    mpc = [r for r in results if "solves" in r["nominal"]]
    if mpc:
        lines += ["", "MPC re-solves (hard failures / answered softly / unanswered, of all solves):", ""]
        for r in mpc:
            parts = [
                f"{level}: {r[level]['failed_hard']} / {r[level]['soft']} / {r[level]['unanswered']} of {r[level]['solves']}"
                for level in ("nominal", "1σ", "3σ")
            ]
            lines.append(f"- {r['controller']}: " + "; ".join(parts))
    tubes = [r for r in results if "plans" in r["nominal"]]
    if tubes:
        lines += ["", "Tube MPC plans, one per episode (how each was found; cwh_envs.tube_mpc.PLANS):", ""]
        for r in tubes:
            parts = [
                f"{level}: " + ", ".join(f"{n} {way}" for way, n in r[level]["plans"].items() if n)
                for level in ("nominal", "1σ", "3σ")
            ]
            lines.append(f"- {r['controller']}: " + "; ".join(parts))
    where = [
        (r["controller"], r[level].get("deepest_cone_from_port_m"), level)
        for r in results
        for level in ("1σ", "3σ")
    ]
    where = [w for w in where if w[1] is not None]
    if where:
        lines += ["", "Where the deepest cone violation sat (distance from the port):", ""]
        lines += [f"- {name}, {level}: {d:.3g} m" for name, d, level in where]
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    args = parse_args(argv)
    train = load_train(ROOT / "families" / args.task)  # the family's own constants
    problem, one_sigma = train.PROBLEM, train.DISPERSIONS
    split = splits.shipped_split("docking", problem, "test")
    n = len(split) if args.starts is None else args.starts
    starts, goals = split.first(n)
    bounds = ErrorBounds.from_dispersions(one_sigma, k_sigma=args.k_sigma)
    given = sys.argv[1:] if argv is None else argv
    command = ("python benchmarks/robust_safety.py " + " ".join(given)).strip()
    path = args.out / f"{args.task}.json"
    kept = {}
    if path.exists() and (
        args.rows or args.retime
    ):  # the rows not flown now, as their own commands measured them
        before = json.loads(path.read_text(encoding="utf-8"))
        kept = {r["controller"]: {"command": before["command"], **r} for r in before["rows"]}
    if args.retime and not args.rows:
        raise SystemExit("--retime needs --rows: the rows whose µs column to measure again")
    table = rows(problem, bounds, args.mpc_starts)
    named = [r for r in table if not args.rows or any(r["name"].startswith(p) for p in args.rows)]
    if args.retime and (missing := [r["name"] for r in named if r["name"] not in kept]):
        raise SystemExit(f"--retime keeps flights it has: no measured row {missing} in {path}")
    done = dict(kept)
    for row in named:
        began = time.perf_counter()
        if args.retime:
            n_row = kept[row["name"]]["starts"]
            us = time_per_step(problem, row, starts[:n_row], goals[:n_row])
            done[row["name"]] = {**kept[row["name"]], "us_per_step": us, "retimed_by": command}
        else:
            measured = measure(problem, one_sigma, row, starts, goals, split.energy[:n])
            done[row["name"]] = {**measured, "command": command}
        print(f"{row['name']}: {time.perf_counter() - began:.0f} s", flush=True)
        # Written after every row, each file replaced whole: hours of flights survive a stop.
        results = [done[r["name"]] for r in table if r["name"] in done]
        write(args.out, args.task, split.label, command, results)
    print(markdown(args.task, [done[r["name"]] for r in table if r["name"] in done]))


def write(out: Path, task: str, label: str, command: str, results: list[dict]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    payload = {"task": task, "split": label, "command": command, "rows": results}
    for name, text in (
        (f"{task}.md", markdown(task, results)),
        (f"{task}.json", json.dumps(payload, indent=1) + "\n"),
    ):
        partial = out / (name + ".partial")
        partial.write_text(text, encoding="utf-8")
        os.replace(partial, out / name)


if __name__ == "__main__":
    main()
