"""Per-step compute of the learned robust row's flight path, numpy against compiled (issue 58's target:
at most 1/100 of the robust MPC's per-step compute, exported policy + filter).

    python benchmarks/bench_flight_path.py            # run alone: it prints times

The row is the leaderboard's "robust hand recipe (BC)" on constrained docking (trained by its
family's train.py under its budget at ``--seed``, as the leaderboard trains it; a fresh machine
trains it first, 600 s). Each of ``--starts`` sealed test starts is flown alone, nominally, through
its layers as the leaderboard flies it (the navigation filter, the policy on its estimate, the
robust filter sized by the navigation filter's covariance with its stop line), and each step's
compute is then timed again, per layer, on the recorded steps (the leaderboard's way):

- **numpy**: :class:`cwh_envs.navigation.NavigationFilter` (its update, ``sigma`` and the thrust
  command through ``G_hat^-1``), the family's torch policy, :func:`cwh_envs.robust_cbf.robust_safe_actions`;
- **compiled**: :mod:`cwh_envs.compiled_navigation`, the policy exported to ONNX by the family's
  export.py (onnxruntime, one thread), :mod:`cwh_envs.compiled_filter`.

Every compiled filter answer is checked against the numpy one on the same step. The robust MPC's
per-step compute is the leaderboard's tube MPC row, the controller alone (no navigation filter, no
CBF: the layers would cost it what they cost the learned row), timed here on the same starts: its
one plan per episode amortised over the episode (the mean) and its median step. The ratios are of
means: the learned path with its navigation filter, and the issue's "exported + filter" without it.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ROW = "robust hand recipe (BC)"
MPC_ROW = "tube MPC (robust)"  # the robust MPC's own compute: its plan and its feedback, no layers
TASK = "docking-constrained"
TOLERANCE = 1e-9  # N: the compiled filter's answer against numpy's on the same step


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--starts", type=int, default=8, help="sealed test starts, each flown alone")
    parser.add_argument(
        "--seed", type=int, default=1, help="the row's training seed (the leaderboard's first)"
    )
    parser.add_argument("--work", type=Path, default=ROOT / "runs" / "leaderboard")
    return parser.parse_args(argv)


def leaderboard():
    spec = importlib.util.spec_from_file_location("leaderboard", ROOT / "benchmarks" / "leaderboard.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def exported(run: Path, out: Path):
    """The run's policy, exported by its family's export.py (checked against torch there), in onnxruntime."""
    from cwh_envs.onnx_policy import OnnxPolicy

    family = ROOT / "families" / TASK
    subprocess.run(
        [sys.executable, "export.py", "--policy", str(run), "--onnx", str(out)],
        cwd=family,
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return OnnxPolicy(out, threads=1)


def record(task, entry, policy, start: int):
    """One start flown alone through the row's layers: the flight and the observation of each step."""
    from cwh_envs.rollout import fly

    seen = []

    def recorded(obs):
        seen.append(obs.copy())
        return policy(obs)

    held = task.held_out.take(start + 1)
    flight = fly(
        task.problem,
        recorded,
        held.starts[start : start + 1],
        held.goals[start : start + 1],
        cbf_margin=task.problem.margin,
        cbf_bounds=task.bounds_at(entry.k_sigma),
        navigation=task.bounds,
        cbf_navigation=entry.cbf_navigation,
        cbf_stop_line=entry.stop_line,
    )
    return flight, seen


def timed(call, *args):
    started = time.perf_counter()
    out = call(*args)
    return out, time.perf_counter() - started


def nav_numpy(navigator, commanded, state):
    """The numpy navigation filter's step on the measurement (the state: a nominal flight) and its sigma."""
    if commanded is None:
        navigator.start(np.ones(1, dtype=bool), state)
    else:
        navigator.step(commanded, state)
    return navigator.sigma()


def nav_compiled(navigator, commanded, state):
    """The same for the compiled filter, one chaser."""
    if commanded is None:
        navigator.start(state[0])
    else:
        navigator.step(commanded[0], state[0])
    return navigator.sigma()


def layers(task, entry, flight, seen, torch_policy, onnx_policy) -> dict[str, list[float]]:
    """Seconds per step of each layer, numpy and compiled, on one recorded flight; checks the filters agree."""
    from cwh_envs.compiled_filter import CompiledRobustFilter
    from cwh_envs.compiled_navigation import CompiledNavigationFilter
    from cwh_envs.navigation import NavigationFilter
    from cwh_envs.robust_cbf import robust_safe_actions

    problem, bounds = task.problem, task.bounds_at(entry.k_sigma)
    navigator, fast_navigator = (
        NavigationFilter(problem, task.bounds),
        CompiledNavigationFilter(problem, task.bounds),
    )
    fast_filter = CompiledRobustFilter(problem, bounds, stop_line=entry.stop_line)
    goal = flight.goals[0]
    out = {
        key: []
        for key in (
            "nav numpy",
            "nav compiled",
            "policy torch",
            "policy onnx",
            "filter numpy",
            "filter compiled",
        )
    }
    for k, obs in enumerate(seen):
        state, commanded = flight.states[:, k], flight.thrust[:, k - 1] if k else None

        sigma, seconds = timed(nav_numpy, navigator, commanded, state)
        out["nav numpy"].append(seconds)
        fast_sigma, seconds = timed(nav_compiled, fast_navigator, commanded, state)
        out["nav compiled"].append(seconds)
        action, seconds = timed(torch_policy, obs)
        out["policy torch"].append(seconds)
        _, seconds = timed(onnx_policy, obs)
        out["policy onnx"].append(seconds)
        u = np.clip(np.asarray(action, dtype=np.float64)[0], -1.0, 1.0) * problem.u_max
        result, seconds = timed(
            robust_safe_actions, u[None], state, flight.goals, problem, bounds, None, sigma, entry.stop_line
        )
        _, commanding = timed(np.linalg.solve, navigator.thrust_gain(), result.u[:, :, None] / problem.u_max)
        out["filter numpy"].append(seconds)
        out["nav numpy"][-1] += commanding
        fast, seconds = timed(fast_filter, u, state[0], goal, fast_sigma)
        _, commanding = timed(fast_navigator.command, fast.u / problem.u_max)
        out["filter compiled"].append(seconds)
        out["nav compiled"][-1] += commanding
        if np.abs(fast.u - result.u[0]).max() > TOLERANCE or fast.margin_scale != result.margin_scale[0]:
            raise SystemExit(f"step {k}: the compiled filter answered {fast.u}, numpy {result.u[0]}")
    return out


def main(argv=None) -> None:
    args = parse_args(argv)
    import torch

    torch.set_num_threads(1)
    board = leaderboard()
    task = board.Task.load(TASK, args.starts)
    entries = {e.name: e for e in board.entries(task, args.work, [args.seed])}
    entry, mpc = entries[ROW], entries[MPC_ROW]
    torch_policy = entry.make(args.seed)  # trained by its family's train.py if not yet (as the leaderboard)
    run = args.work / TASK / board.slug(ROW) / f"s{args.seed}-budget{entry.time_budget:g}"
    with tempfile.TemporaryDirectory() as tmp:
        onnx_policy = exported(run, Path(tmp) / "policy.onnx")
        samples: dict[str, list[float]] = {}
        # once untimed: the first calls load numba's compiled code and onnxruntime's session
        layers(task, entry, *record(task, entry, torch_policy, 0), torch_policy, onnx_policy)
        for start in range(args.starts):
            flight, seen = record(task, entry, torch_policy, start)
            for key, seconds in layers(task, entry, flight, seen, torch_policy, onnx_policy).items():
                samples.setdefault(key, []).extend(seconds)
    us = {key: np.array(values) * 1e6 for key, values in samples.items()}
    numpy_path = us["nav numpy"] + us["policy torch"] + us["filter numpy"]
    compiled = us["nav compiled"] + us["policy onnx"] + us["filter compiled"]
    paths = {"numpy (the leaderboard's path)": numpy_path, "compiled (ONNX policy)": compiled}
    print(f"[bench] {ROW} on {args.starts} sealed {TASK} starts, {len(us['nav numpy'])} steps, µs a step")
    print(f"{'layer or path':<34}{'p50':>10}{'p99':>10}{'mean':>10}")
    for key, values in (*us.items(), *paths.items()):
        print(
            f"{key:<34}{np.percentile(values, 50):>10.1f}{np.percentile(values, 99):>10.1f}{values.mean():>10.1f}"
        )
    mpc_timing = board.time_per_step(task, mpc, None)
    print(
        f"{'robust MPC (' + MPC_ROW.split(' +')[0] + ')':<34}{mpc_timing['p50']:>10.1f}{mpc_timing['p99']:>10.1f}"
        f"{mpc_timing['mean']:>10.1f}   (one {mpc_timing['plan_s_median']:.2f} s plan per episode, amortised in the mean)"
    )
    exported_filter = us["policy onnx"] + us["filter compiled"]
    print(
        f"[bench] compiled path / numpy path: {compiled.mean() / numpy_path.mean():.3f}; against the robust "
        f"MPC's mean step: compiled path {compiled.mean() / mpc_timing['mean']:.4f}, exported policy + "
        f"compiled filter {exported_filter.mean() / mpc_timing['mean']:.4f} (target <= 0.01); every "
        f"compiled filter answer within {TOLERANCE:g} N of numpy's"
    )


if __name__ == "__main__":
    main()
