"""Env throughput: env-steps per second, single env vs SyncVectorEnv vs the native vector env.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_envs.py [--seconds 2.0] [--start-pool 65536] [--safety]

Random actions from a pre-drawn pool. Each measurement runs for at least ``--seconds`` and at least
one full episode plus its reset, and reports env-steps per second (one transition of one
sub-environment; a vector step of N envs is N env-steps) twice: including the resets, which draw
screened starts from :mod:`cwh_envs.sampling` as in training, and stepping only (reset calls
excluded from the clock), the env's own cost. Ratios are per env-step against SyncVectorEnv of 16
single envs (of filtered single envs for the filtered rows); "resets cost" is stepping only over
incl. resets, the slowdown the resets bring (the aim for the pooled rows: at most 3x). The
``start_pool=`` rows reset from a cached pool of ``--start-pool`` screened starts
(cwh_envs.datasets.start_pool) instead of fresh draws; building it (once per machine, or loading
it) happens before the clock starts and is reported on stderr. Prints a Markdown table.

``--safety`` instead measures what the CBF filter prevents: 512 docking episodes per row of a
naive nominal policy (random thrust, or flying straight at the goal at a capped speed), with
and without the filter, from the sampled starts and from head-on starts (each start moved to
the antipode of its goal, so the straight path crosses the centre).
"""

from __future__ import annotations

import argparse
import platform
import sys
import time

import gymnasium as gym
import numpy as np

from cwh_envs import CBFSafetyFilter  # importing the package registers the ids
from cwh_envs.controllers import capped_speed_action

SYNC_ENVS = 16
NATIVE_ENVS = (1024, 8192)
START_POOL = 65_536  # the start_pool rows: a pool built once per machine and cached


def bench_single(env_id: str, seconds: float, **kwargs) -> tuple[float, float]:
    """(env-steps/s with resets, env-steps/s stepping only) for one env made by gym.make."""
    env = gym.make(env_id, **kwargs)
    env.reset(seed=0)
    pool = np.random.default_rng(0).uniform(-1, 1, (4096, 3)).astype(np.float32)
    steps, step_time, reset_time, resets = 0, 0.0, 0.0, 0
    while step_time + reset_time < seconds or resets == 0:
        t0 = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(pool[steps % len(pool)])
        t1 = time.perf_counter()
        step_time += t1 - t0
        steps += 1
        if terminated or truncated:
            env.reset()
            reset_time += time.perf_counter() - t1
            resets += 1
    return steps / (step_time + reset_time), steps / step_time


def bench_vector(env_id: str, num_envs: int, mode: str, seconds: float, **kwargs) -> tuple[float, float]:
    """As bench_single for a vector env; a next-step autoreset call yields no transition."""
    env = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode=mode, **kwargs)
    env.reset(seed=0)
    pool = np.random.default_rng(0).uniform(-1, 1, (16, num_envs, 3)).astype(np.float32)
    calls, transitions, step_time, reset_time, resets = 0, 0, 0.0, 0.0, 0
    resetting = np.zeros(num_envs, dtype=bool)
    while step_time + reset_time < seconds or resets == 0:
        t0 = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(pool[calls % len(pool)])
        elapsed = time.perf_counter() - t0
        calls += 1
        transitions += int(num_envs - resetting.sum())
        if resetting.any():  # every row ends together: fixed horizon, common reset
            reset_time += elapsed
            resets += 1
        else:
            step_time += elapsed
        resetting = terminated | truncated
    env.close()
    return transitions / (step_time + reset_time), transitions / step_time


def safety_episodes(policy, cbf_margin: float | None, head_on: bool, num_envs: int = 512, seed: int = 0):
    """(fraction of episodes with a step inside R, least clearance [m], infeasible filter steps)."""
    env = gym.make_vec(
        "CWHDockKOZ-v1", num_envs=num_envs, vectorization_mode="vector_entry_point", cbf_margin=cbf_margin
    )
    obs, _ = env.reset(seed=seed)
    if head_on:
        goals, distance = (
            env.unwrapped.goals,
            np.linalg.norm(env.unwrapped.states[:, :3], axis=1, keepdims=True),
        )
        far_side = -goals / np.linalg.norm(goals, axis=1, keepdims=True) * distance
        obs, _ = env.reset(
            options={"initial_state": np.hstack([far_side, np.zeros_like(far_side)]), "goal": goals}
        )
    rng = np.random.default_rng(seed)
    terminated, infeasible = np.zeros(num_envs, dtype=bool), 0
    while not terminated.all():
        action = (
            rng.uniform(-1, 1, (num_envs, 3))
            if policy == "random"
            else capped_speed_action(obs, policy, env.unwrapped.problem)
        )
        obs, _, terminated, _, info = env.step(action.astype(np.float32))
        infeasible += int(info.get("cbf_infeasible", np.zeros(1)).sum())
    return float(np.mean(info["violation_rate"] > 0)), float(info["min_clearance"].min()), infeasible


def safety_table() -> None:
    print(
        "| starts | nominal policy | episodes entering, no filter | with CBF (0.5 m) | least clearance with CBF [m] | infeasible CBF steps |"
    )
    print("|---|---|---:|---:|---:|---:|")
    for head_on in (False, True):
        for policy in ("random", 0.03, 0.05, 0.1, 0.2, 0.3):
            plain, _, _ = safety_episodes(policy, None, head_on)
            safe, clearance, infeasible = safety_episodes(policy, 0.5, head_on)
            name = "random thrust" if policy == "random" else f"straight at the goal, <= {policy} m/s"
            starts = "head-on" if head_on else "sampled"
            print(
                f"| {starts} | {name} | {plain:.1%} | {safe:.1%} | {clearance:.3f} | {infeasible} |",
                flush=True,
            )


def prepare_pool(env_id: str, size: int) -> None:
    """Build (or load) the start pool outside every clock, and say how long it took."""
    started = time.perf_counter()
    gym.make_vec(env_id, num_envs=1, vectorization_mode="vector_entry_point", start_pool=size).reset(seed=0)
    print(
        f"[bench_envs] {env_id} start pool of {size}: ready in {time.perf_counter() - started:.1f} s",
        file=sys.stderr,
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="wall time per measurement")
    parser.add_argument("--start-pool", type=int, default=START_POOL, help="pool size of the start_pool rows")
    parser.add_argument("--safety", action="store_true", help="measure the CBF filter's effect instead")
    args = parser.parse_args()
    if args.safety:
        safety_table()
        return
    print(
        f"numpy {np.__version__}, gymnasium {gym.__version__}, Python {platform.python_version()}, {platform.machine()}"
    )
    print()
    print(
        "| env | configuration | env-steps/s incl. resets | vs Sync | env-steps/s stepping only | vs Sync "
        "| resets cost |"
    )
    print("|---|---|---:|---:|---:|---:|---:|")
    pool = {"start_pool": args.start_pool}
    for env_id in ("CWHRendezvous-v0", "CWHDockKOZ-v1"):
        prepare_pool(env_id, args.start_pool)
        sync = bench_vector(env_id, SYNC_ENVS, "sync", args.seconds)
        rows = [
            ("single env, gym.make", bench_single(env_id, args.seconds), sync),
            (f"SyncVectorEnv x{SYNC_ENVS}", sync, sync),
            (
                f"SyncVectorEnv x{SYNC_ENVS}, start_pool={args.start_pool}",
                bench_vector(env_id, SYNC_ENVS, "sync", args.seconds, **pool),
                sync,
            ),
        ]
        for n in NATIVE_ENVS:
            rows.append(
                (f"native vector x{n}", bench_vector(env_id, n, "vector_entry_point", args.seconds), sync)
            )
        for n in NATIVE_ENVS:
            rate = bench_vector(env_id, n, "vector_entry_point", args.seconds, **pool)
            rows.append((f"native vector x{n}, start_pool={args.start_pool}", rate, sync))
        if env_id == "CWHDockKOZ-v1":  # the filtered rows compare with SyncVectorEnv of filtered envs
            sync_cbf = bench_vector(env_id, SYNC_ENVS, "sync", args.seconds, wrappers=(CBFSafetyFilter,))
            rows.append((f"SyncVectorEnv x{SYNC_ENVS}, CBFSafetyFilter", sync_cbf, sync_cbf))
            for n in NATIVE_ENVS:
                rate = bench_vector(env_id, n, "vector_entry_point", args.seconds, cbf_margin=0.5)
                rows.append((f"native vector x{n}, cbf_margin=0.5", rate, sync_cbf))
            rate = bench_vector(
                env_id, NATIVE_ENVS[0], "vector_entry_point", args.seconds, cbf_margin=0.5, **pool
            )
            rows.append(
                (
                    f"native vector x{NATIVE_ENVS[0]}, cbf_margin=0.5, start_pool={args.start_pool}",
                    rate,
                    sync_cbf,
                )
            )
        for name, (total, stepping), (base_total, base_stepping) in rows:
            print(
                f"| {env_id} | {name} | {total:,.0f} | {total / base_total:.0f}x "
                f"| {stepping:,.0f} | {stepping / base_stepping:.0f}x | {stepping / total:.1f}x |",
                flush=True,
            )


if __name__ == "__main__":
    main()
