"""The classical baselines through gym.make: closed-form feedback, MPC and a PD law, one start each.

    .venv/bin/python examples/baselines.py [--seed 0] [--constrained]

For CWHRendezvous-v0 and CWHDockKOZ-v1 (``--constrained``: with the docking-constrained family's
speed limit and approach cone), one start drawn by ``reset(seed=...)`` is flown by

- ``MinEnergyFeedback``: the optimal-control expert's unconstrained minimum-energy solution
  re-planned from the observed state at every step, in closed form (a 3 x 6 gain pair per step);
- ``RecedingHorizon``: MPC, the task's own expert re-solved from the observed state over the steps
  left at every step (the box QP, the keep-out SCP, the SOCP with every constraint);
- ``pd_action``: a critically damped PD law toward the target;

each through ``CBFSafetyFilter`` on docking where it ignores the keep-out (the law and the PD law),
then compared with the open-loop expert from the same start. Every controller is a plain callable
on observations, so the loop is the Gymnasium one: ``action = controller(obs)``.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import cwh_envs
from cwh_envs.controllers import MinEnergyFeedback, pd_action
from cwh_envs.experts import solve_docking, solve_rendezvous
from cwh_envs.mpc import RecedingHorizon

CONSTRAINTS = {"speed_limit": (0.01, 2 * 1.13e-3), "approach_cone": (30.0, 15.0)}  # the family's


def fly(env, controller, seed: int) -> dict:
    """One episode from ``reset(seed=seed)``; the final info, Σ|u|²dt and the controller's µs per step."""
    obs, _ = env.reset(seed=seed)
    problem = env.unwrapped.problem
    energy, seconds, terminated = 0.0, [], False
    while not terminated:
        started = time.perf_counter()
        action = controller(obs)
        seconds.append(time.perf_counter() - started)
        # what the env applies: the filter's edit (a pure function of the state), else the clip
        applied = env.action(action) if isinstance(env, cwh_envs.CBFSafetyFilter) else np.clip(action, -1, 1)
        energy += float(np.sum((applied * problem.u_max) ** 2)) * problem.dt
        obs, _, terminated, _, info = env.step(action)
    return {**info, "energy": energy, "us_per_step": 1e6 * float(np.median(seconds))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--constrained", action="store_true", help="docking with a speed limit and a cone")
    args = parser.parse_args()
    print(
        "| env | controller | terminal distance [m] | success | violation rate | energy / expert | µs per step |"
    )
    print("|---|---|---:|---|---:|---:|---:|")
    for env_id in ("CWHRendezvous-v0", "CWHDockKOZ-v1"):
        kwargs = CONSTRAINTS if env_id == "CWHDockKOZ-v1" and args.constrained else {}
        docking = env_id == "CWHDockKOZ-v1"
        plain = gym.make(env_id, **kwargs)
        plain.reset(seed=args.seed)
        problem, start = plain.unwrapped.problem, plain.unwrapped.state
        if docking:
            _, thrust = solve_docking(start, plain.unwrapped.goal, problem)
        else:
            _, thrust = solve_rendezvous(start, problem)
        expert_energy = float(np.sum(thrust**2)) * problem.dt
        free = problem.replace(speed_limit=None, approach_cone=None) if docking else problem
        rows = {
            "closed-form feedback": (MinEnergyFeedback(free), docking),
            "MPC": (RecedingHorizon(problem), False),
            "PD": (lambda obs, free=free: pd_action(obs, free), docking),
        }
        for name, (controller, filtered) in rows.items():
            env = gym.make(env_id, **kwargs)
            if filtered:
                env = cwh_envs.CBFSafetyFilter(env, margin=problem.margin)
            info = fly(env, controller, args.seed)
            label = name + (" + CBF" if filtered else "")
            # the share of steps breaking the keep-out, plus the speed limit and the cone where present
            broken = sum(
                info.get(k, 0.0) for k in ("violation_rate", "speed_violation_rate", "cone_violation_rate")
            )
            violation = f"{broken:.1%}" if docking else "-"
            print(
                f"| {env_id} | {label} | {info['terminal_distance']:.3g} | {info['is_success']} | {violation} | "
                f"{info['energy'] / expert_energy:.3g} | {info['us_per_step']:.0f} |"
            )


if __name__ == "__main__":
    main()
