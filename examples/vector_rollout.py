"""Thousands of episodes at once through the native vector env: throughput and episode statistics.

    .venv/bin/python examples/vector_rollout.py --env docking --num-envs 4096 --policy pd --cbf
    .venv/bin/python examples/vector_rollout.py --env rendezvous --num-envs 1024 --policy random

``gym.make_vec(..., vectorization_mode="vector_entry_point")`` builds the batched env (numpy over
all episodes, Gymnasium's NEXT_STEP autoreset). A random policy or a saturated proportional-
derivative (PD) law on the observed error flies it for --episodes episodes per sub-env; the
script prints env-steps per second (with the autoresets, which for rendezvous dominate: its start
sampler screens every draw with the expert) and the end-of-episode statistics from ``info``.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

from cwh_envs.controllers import pd_action

ENV_IDS = {"rendezvous": "cwh_envs:CWHRendezvous-v0", "docking": "cwh_envs:CWHDockKOZ-v1"}


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", choices=sorted(ENV_IDS), default="docking")
    parser.add_argument("--num-envs", type=int, default=4096)
    parser.add_argument("--policy", choices=["random", "pd"], default="pd")
    parser.add_argument("--episodes", type=int, default=2, help="episodes per sub-env")
    parser.add_argument(
        "--cbf", action="store_true", help="docking: the CBF filter on the batch (cbf_margin=0.5)"
    )
    parser.add_argument("--seed", type=int, default=0)
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    kwargs = {"cbf_margin": 0.5} if args.cbf else {}
    envs = gym.make_vec(
        ENV_IDS[args.env], num_envs=args.num_envs, vectorization_mode="vector_entry_point", **kwargs
    )
    problem = envs.unwrapped.problem
    envs.action_space.seed(args.seed)

    began = time.perf_counter()
    obs, _ = envs.reset(seed=args.seed)
    reset_seconds = time.perf_counter() - began

    # H steps end an episode; one more per episode is the NEXT_STEP autoreset (its action is ignored).
    n_steps = args.episodes * (problem.horizon + 1) - 1
    finished = {"terminal_distance": [], "terminal_speed": [], "is_success": [], "violation_rate": []}
    began = time.perf_counter()
    for _ in range(n_steps):
        actions = envs.action_space.sample() if args.policy == "random" else pd_action(obs, problem)
        obs, _, terminated, _, info = envs.step(actions)
        if terminated.any():
            for key, values in finished.items():
                if key in info:
                    values.append(info[key][info[f"_{key}"]])
    step_seconds = time.perf_counter() - began
    envs.close()

    stats = {key: np.concatenate(values) for key, values in finished.items() if values}
    env_steps = args.num_envs * n_steps
    cbf = " + CBF" if args.cbf else ""
    print(f"{args.env}{cbf}, {args.policy} policy, {args.num_envs} envs x {n_steps} steps:")
    print(f"  reset {reset_seconds:.2f} s; {env_steps:,} env-steps in {step_seconds:.2f} s")
    print(f"  {env_steps / step_seconds:,.0f} env-steps/s (autoresets included)")
    distance = stats["terminal_distance"]
    print(
        f"  {len(distance)} episodes: terminal distance median {np.median(distance):.3g} m "
        f"(mean {distance.mean():.3g}), terminal speed median {np.median(stats['terminal_speed']):.3g} m/s, "
        f"success {stats['is_success'].mean():.1%}"
    )
    if "violation_rate" in stats:
        violation = stats["violation_rate"]
        print(
            f"  keep-out: violation rate {violation.mean():.2%}, episodes entering {np.mean(violation > 0):.1%}"
        )


if __name__ == "__main__":
    main()
