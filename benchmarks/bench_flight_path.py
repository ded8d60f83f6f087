"""Per-step compute of the learned robust row's flight path, numpy against compiled (issue 58's target:
at most 1/100 of the robust MPC's per-step compute, exported policy + filter).

    python benchmarks/bench_flight_path.py            # run alone: it prints times

The row is the leaderboard's "robust hand recipe (BC)" on constrained docking (trained by its
family's train.py under its budget at ``--seed``, as the leaderboard trains it; a fresh machine
trains it first, 600 s). Each of ``--starts`` sealed test starts is flown alone, nominally, through
its layers as the leaderboard flies it (the navigation filter, the policy on its estimate, the
robust filter sized by the navigation filter's covariance with its stop line), and each step's
compute is then timed again, per layer, on the recorded steps (the leaderboard's way), each path in
a pass of its own, its layers back to back as they would fly:

- **numpy**: :class:`cwh_envs.navigation.NavigationFilter` (its update, ``sigma`` and the thrust
  command through ``G_hat^-1``), the family's torch policy, :func:`cwh_envs.robust_cbf.robust_safe_actions`;
- **compiled, ONNX policy**: :mod:`cwh_envs.compiled_navigation`, the policy exported to ONNX by
  the family's export.py (onnxruntime, one thread), :mod:`cwh_envs.compiled_filter`;
- **compiled, compiled policy**: the same with the policy export.py writes for
  :mod:`cwh_envs.compiled_policy` (numba).

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
# The paths timed: numpy (the leaderboard's: numpy filters, the torch policy), then the compiled
# filters with the policy exported to ONNX (onnxruntime) or compiled (cwh_envs.compiled_policy).
PATHS = ("numpy", "compiled, ONNX policy", "compiled, compiled policy")
LAYERS = ("navigation", "policy", "filter")


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


def exported(run: Path, directory: Path):
    """The run's policy exported by its family's export.py (each file checked against torch there):
    the ONNX file in onnxruntime, and the compiled policy."""
    from cwh_envs.compiled_policy import CompiledPolicy
    from cwh_envs.onnx_policy import OnnxPolicy

    family = ROOT / "families" / TASK
    onnx, compiled = directory / "policy.onnx", directory / "policy.npz"
    subprocess.run(
        [sys.executable, "export.py", "--policy", str(run), "--onnx", str(onnx), "--compiled", str(compiled)],
        cwd=family,
        check=True,
        stdout=subprocess.DEVNULL,
    )
    fast = CompiledPolicy.load(compiled)
    return OnnxPolicy(onnx, threads=1), lambda obs: fast(obs[0])


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


def layers(task, entry, flight, seen, policies: dict) -> dict[str, list[float]]:
    """Seconds per step of each path's layers on one recorded flight; checks the filters agree.

    ``policies``: {path: policy}, the numpy path's first (the torch policy)."""
    from cwh_envs.compiled_filter import CompiledRobustFilter
    from cwh_envs.compiled_navigation import CompiledNavigationFilter
    from cwh_envs.navigation import NavigationFilter
    from cwh_envs.robust_cbf import robust_safe_actions

    problem, bounds = task.problem, task.bounds_at(entry.k_sigma)
    fast_filter = CompiledRobustFilter(problem, bounds, stop_line=entry.stop_line)
    goal = flight.goals[0]
    out: dict[str, list[float]] = {}

    def add(key, seconds, to_last=False):
        if to_last:
            out[key][-1] += seconds
        else:
            out.setdefault(key, []).append(seconds)

    # Each path is timed in a pass of its own over the flight, its layers back to back as they
    # would fly: timed interleaved, torch's policy call between them doubled onnxruntime's time (its
    # caches evicted). The compiled filter is given the numpy path's policy action (the torch one;
    # the exported ones differ by up to 1e-6) so that its answer can be held to numpy's on each step.
    (numpy_path, torch_policy), *compiled_paths = policies.items()
    navigator, commands, answers = NavigationFilter(problem, task.bounds), [], []
    for k, obs in enumerate(seen):
        state, commanded = flight.states[:, k], flight.thrust[:, k - 1] if k else None
        sigma, seconds = timed(nav_numpy, navigator, commanded, state)
        add(f"{numpy_path}: navigation", seconds)
        action, seconds = timed(torch_policy, obs)
        add(f"{numpy_path}: policy", seconds)
        u = np.clip(np.asarray(action, dtype=np.float64)[0], -1.0, 1.0) * problem.u_max
        result, seconds = timed(
            robust_safe_actions, u[None], state, flight.goals, problem, bounds, None, sigma, entry.stop_line
        )
        add(f"{numpy_path}: filter", seconds)
        _, seconds = timed(np.linalg.solve, navigator.thrust_gain(), result.u[:, :, None] / problem.u_max)
        add(f"{numpy_path}: navigation", seconds, to_last=True)
        commands.append(u)
        answers.append(result)
    for path, policy in compiled_paths:
        navigator = CompiledNavigationFilter(problem, task.bounds)
        for k, obs in enumerate(seen):
            state, commanded = flight.states[:, k], flight.thrust[:, k - 1] if k else None
            sigma, seconds = timed(nav_compiled, navigator, commanded, state)
            add(f"{path}: navigation", seconds)
            _, seconds = timed(policy, obs)
            add(f"{path}: policy", seconds)
            fast, seconds = timed(fast_filter, commands[k], state[0], goal, sigma)
            add(f"{path}: filter", seconds)
            _, seconds = timed(navigator.command, fast.u / problem.u_max)
            add(f"{path}: navigation", seconds, to_last=True)
            result = answers[k]
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
        onnx_policy, compiled_policy = exported(run, Path(tmp))
        policies = {PATHS[0]: torch_policy, PATHS[1]: onnx_policy, PATHS[2]: compiled_policy}
        samples: dict[str, list[float]] = {}
        # once untimed: the first calls load numba's compiled code and onnxruntime's session
        layers(task, entry, *record(task, entry, torch_policy, 0), policies)
        for start in range(args.starts):
            flight, seen = record(task, entry, torch_policy, start)
            for key, seconds in layers(task, entry, flight, seen, policies).items():
                samples.setdefault(key, []).extend(seconds)
    us = {key: np.array(values) * 1e6 for key, values in samples.items()}
    totals = {path: sum(us[f"{path}: {layer}"] for layer in LAYERS) for path in PATHS}
    print(f"[bench] {ROW} on {args.starts} sealed {TASK} starts, {len(totals[PATHS[0]])} steps, µs a step")
    print(f"{'path: layer':<44}{'p50':>10}{'p99':>10}{'mean':>10}")
    for path in PATHS:
        for key, values in (
            *((f"{path}: {layer}", us[f"{path}: {layer}"]) for layer in LAYERS),
            (path, totals[path]),
        ):
            print(
                f"{key:<44}{np.percentile(values, 50):>10.1f}{np.percentile(values, 99):>10.1f}{values.mean():>10.1f}"
            )
    mpc_timing = board.time_per_step(task, mpc, None)
    print(
        f"{'robust MPC (' + MPC_ROW + ')':<44}{mpc_timing['p50']:>10.1f}{mpc_timing['p99']:>10.1f}"
        f"{mpc_timing['mean']:>10.1f}   (one {mpc_timing['plan_s_median']:.2f} s plan per episode, amortised in the mean)"
    )
    mpc_mean = mpc_timing["mean"]
    ratios = []
    for path in PATHS[1:]:
        exported_filter = us[f"{path}: policy"] + us[f"{path}: filter"]
        ratios.append(
            f"{path}: {totals[path].mean() / totals[PATHS[0]].mean():.3f} of the numpy path; of the robust "
            f"MPC's mean step, {totals[path].mean() / mpc_mean:.4f} with navigation, exported policy + "
            f"filter {exported_filter.mean() / mpc_mean:.4f}"
        )
    print(
        "[bench] "
        + "; ".join(ratios)
        + f" (target <= 0.01); every compiled filter answer within {TOLERANCE:g} N of numpy's"
    )


if __name__ == "__main__":
    main()
