"""Quickstart: both Gymnasium envs, flown by the optimal-control expert and by random thrust.

    .venv/bin/python examples/quickstart.py --out results/quickstart

For each env: reset with a seed to draw a start, solve the minimum-energy expert from it, fly the
expert's thrust open-loop from that same start (passed back through reset options), fly uniform
random actions from it too, print the end-of-episode metrics from ``info`` and save each rendered
trajectory (``render_mode="rgb_array"``) as a PNG.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import matplotlib.image
import numpy as np

from cwh_envs.experts import solve_docking, solve_rendezvous


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("results/quickstart"))
    return parser.parse_args()


def expert_actions(env: gym.Env) -> np.ndarray:
    """The expert's thrust (H, 3) from the env's current start, as the env's normalised actions."""
    base = env.unwrapped
    if base.spec.id == "CWHRendezvous-v0":
        _, thrust = solve_rendezvous(base.state, base.problem)
    else:
        _, thrust = solve_docking(base.state, base.goal, base.problem)
    return thrust / base.problem.u_max  # float64: a float32 round trip would cost ~1e-7 m at the end


def fly(env: gym.Env, options: dict, actions: np.ndarray | None) -> dict:
    """One episode from the given start, replaying ``actions`` (H, 3) or, if None, random ones.

    Returns the final info, where the end-of-episode metrics live.
    """
    env.reset(options=options)
    terminated, step = False, 0
    while not terminated:
        action = env.action_space.sample() if actions is None else actions[step]
        _, _, terminated, _, info = env.step(action)
        step += 1
    return info


def main() -> None:
    args = parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    print("| env | policy | terminal distance [m] | terminal speed [m/s] | success | violation rate |")
    print("|---|---|---:|---:|---|---:|")
    for env_id in ("CWHRendezvous-v0", "CWHDockKOZ-v1"):
        env = gym.make(f"cwh_envs:{env_id}", render_mode="rgb_array")
        env.reset(seed=args.seed)
        env.action_space.seed(args.seed)
        # Pin the sampled start (and docking point) so both policies fly the same episode.
        options = {"initial_state": env.unwrapped.state.copy()}
        if env_id == "CWHDockKOZ-v1":
            options["goal"] = env.unwrapped.goal.copy()
        for name, actions in (("expert", expert_actions(env)), ("random", None)):
            info = fly(env, options, actions)
            violation = f"{info['violation_rate']:.1%}" if "violation_rate" in info else "-"
            print(
                f"| {env_id} | {name} | {info['terminal_distance']:.3g} | {info['terminal_speed']:.3g} "
                f"| {bool(info['is_success'])} | {violation} |"
            )
            matplotlib.image.imsave(args.out / f"{env_id}_{name}.png", env.render())
        env.close()
    print(f"wrote the trajectory images to {args.out}")


if __name__ == "__main__":
    main()
