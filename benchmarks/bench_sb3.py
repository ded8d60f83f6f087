"""PPO environment steps per second on SB3's VecEnvs: the native adapter vs DummyVecEnv vs SubprocVecEnv.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_sb3.py [--problem rendezvous|docking|docking+cbf]
        [--num-envs 16] [--timesteps 16384] [--start-pool 65536] [--no-subproc]

One PPO run per VecEnv in one invocation: the same env, num_envs, seed, start pool and
hyperparameters, each under VecMonitor (Monitor for make_vec_env's) and VecNormalize, torch on one
thread as the families train. Reported per run: env steps per second of the whole ``learn()``
(what training sees, gradient updates included) and of its rollout collection alone (the time
between SB3's rollout-start and rollout-end callbacks: the env steps plus the policy's forward
passes), each with its ratio to DummyVecEnv. The adapter runs twice: with ``info_keys=("is_success",)``
(all SB3's algorithms read, as examples/sb3_compare.py uses it) and converting every info key as
DummyVecEnv returns them. Every VecEnv resets from the same cached start pool, built (or loaded)
before any clock starts. SubprocVecEnv starts one process per env. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time

import gymnasium as gym
import numpy as np
import stable_baselines3
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import SubprocVecEnv, VecMonitor, VecNormalize

from cwh_envs import CBFSafetyFilter
from cwh_envs.sb3 import NativeVecEnv

PROBLEMS = {  # env id, CBF on
    "rendezvous": ("cwh_envs:CWHRendezvous-v0", False),
    "docking": ("cwh_envs:CWHDockKOZ-v1", False),
    "docking+cbf": ("cwh_envs:CWHDockKOZ-v1", True),
}
CBF_MARGIN = 0.5  # CBFSafetyFilter's default: the problem's margin
PPO_PARAMS = dict(
    n_steps=256, n_epochs=4, learning_rate=3e-4, gamma=0.99, policy_kwargs=dict(net_arch=[64, 64])
)


class RolloutClock(BaseCallback):
    """Seconds spent collecting rollouts (env steps and policy forward passes, no gradient updates)."""

    def __init__(self) -> None:
        super().__init__()
        self.seconds = 0.0

    def _on_rollout_start(self) -> None:
        self.began = time.perf_counter()

    def _on_rollout_end(self) -> None:
        self.seconds += time.perf_counter() - self.began

    def _on_step(self) -> bool:
        return True


def make_envs(kind: str, problem: str, num_envs: int, start_pool: int, seed: int):
    env_id, cbf = PROBLEMS[problem]
    pool = {"start_pool": start_pool} if start_pool else {}
    if kind.startswith("NativeVecEnv"):
        keys = ("is_success",) if "is_success" in kind else None
        margin = {"cbf_margin": CBF_MARGIN} if cbf else {}
        return VecMonitor(NativeVecEnv(env_id, num_envs, seed=seed, info_keys=keys, **pool, **margin))
    return make_vec_env(
        env_id,
        n_envs=num_envs,
        seed=seed,
        env_kwargs=pool,
        wrapper_class=CBFSafetyFilter if cbf else None,
        vec_env_cls=SubprocVecEnv if kind == "SubprocVecEnv" else None,
    )


def bench(kind: str, args) -> tuple[float, float, float]:
    """(learn env-steps/s, rollout env-steps/s, learn wall seconds) of one PPO run."""
    envs = VecNormalize(make_envs(kind, args.problem, args.num_envs, args.start_pool, args.seed))
    batch_size = PPO_PARAMS["n_steps"] * args.num_envs // 4  # four minibatches per epoch
    model = PPO("MlpPolicy", envs, batch_size=batch_size, seed=args.seed, device="cpu", **PPO_PARAMS)
    clock = RolloutClock()
    started = time.perf_counter()
    model.learn(args.timesteps, callback=clock)
    wall = time.perf_counter() - started
    envs.close()
    return model.num_timesteps / wall, model.num_timesteps / clock.seconds, wall


def prepare_pool(problem: str, size: int) -> None:
    if size:
        started = time.perf_counter()
        env_id, _ = PROBLEMS[problem]
        gym.make(env_id, start_pool=size).reset(seed=0)
        seconds = time.perf_counter() - started
        print(f"[bench_sb3] start pool of {size}: ready in {seconds:.1f} s", file=sys.stderr, flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problem", choices=sorted(PROBLEMS), default="rendezvous")
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--timesteps", type=int, default=16_384, help="env steps per PPO run")
    parser.add_argument(
        "--start-pool", type=int, default=65_536, help="pool size for every VecEnv; 0: fresh draws"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-subproc", action="store_true", help="skip SubprocVecEnv (one process per env)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    prepare_pool(args.problem, args.start_pool)
    kinds = ["NativeVecEnv, info_keys=('is_success',)", "NativeVecEnv, every info key", "DummyVecEnv"]
    if not args.no_subproc:
        kinds.append("SubprocVecEnv")
    print(
        f"SB3 {stable_baselines3.__version__}, torch {torch.__version__}, numpy {np.__version__}, "
        f"Python {platform.python_version()}; PPO on {args.problem}, {args.num_envs} envs, "
        f"{args.timesteps} env steps per run, n_steps {PPO_PARAMS['n_steps']}, start pool {args.start_pool or 'off'}"
    )
    print()
    print(
        "| VecEnv | envs | learn env-steps/s | vs Dummy | rollout env-steps/s | vs Dummy | learn wall [s] |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    measured = {}
    for kind in kinds:
        print(f"[bench_sb3] {kind} ...", file=sys.stderr, flush=True)
        measured[kind] = bench(kind, args)
    dummy_learn, dummy_rollout, _ = measured["DummyVecEnv"]
    for kind, (learn, rollout, wall) in measured.items():
        print(
            f"| {kind} | {args.num_envs} | {learn:,.0f} | {learn / dummy_learn:.2f}x "
            f"| {rollout:,.0f} | {rollout / dummy_rollout:.2f}x | {wall:.1f} |"
        )


if __name__ == "__main__":
    main()
