"""Where the tube MPC + robust CBF spends its extra energy (issue 58's 1.2x target for the robust MPC).

    OMP_NUM_THREADS=1 .venv/bin/python results/robust-safety/where_tube_energy_goes.py > results/robust-safety/where_tube_energy_goes.txt

Nominal flights (no dispersion: the navigation filter's estimate is the state) of the first 16
constrained-docking search starts: the tube MPC on the navigation filter alone, and the tube MPC under
the robust CBF (k = 3) on fly's navigation filter with the CBF's bounds whole, navigation only and
thrust only; then the tube MPC planned inside the CBF's margins (its speed limit shrunk by the CBF's
speed margin, its standoff grown by the CBF's position margin). Per variant: energy over the expert's
(median), the energy spent at each distance from the port (mean over starts, sum of |u|^2 per step),
the share of steps the CBF changed the action, and at those steps how far inside the scored speed
limit the chaser flew.
"""

import dataclasses

import numpy as np

from cwh_envs.datasets import evaluation_set
from cwh_envs.prepare import load_train
from cwh_envs.robust_cbf import ErrorBounds
from cwh_envs.rollout import control_effort, fly
from cwh_envs.tube_mpc import TubeMPC

BANDS = ((0, 0.3), (0.3, 1), (1, 3), (3, 10), (10, np.inf))  # m from the port
train = load_train("families/docking-constrained")
problem = train.PROBLEM
held = evaluation_set(train.TASK, 16, problem=problem, split="search")
expert = control_effort(held.trajectory_thrust(), problem)[0]
bounds = ErrorBounds.from_dispersions(train.DISPERSIONS, k_sigma=3.0)
a, _ = problem.matrices()
half_angle = np.radians(problem.approach_cone[0])
eps = bounds.position_margin(a)
setback = problem.capture_radius / np.tan(half_angle) - eps / np.sin(half_angle)
v0, v1 = problem.speed_limit
filter_speed_shrink = bounds.speed_margin(a, v1) + v1 * abs(setback)  # robust_cbf._Tightened's


def inside_filter() -> TubeMPC:
    mpc = TubeMPC(problem, bounds)
    planned_v0, _ = mpc.planned.speed_limit
    mpc.planned = mpc.planned.replace(
        speed_limit=(planned_v0 - filter_speed_shrink, v1), margin=mpc.planned.margin + eps
    )
    return mpc


tube = TubeMPC(problem, bounds)
print(
    f"tube MPC's planned speed limit v0 = {tube.planned.speed_limit[0]:.5f} m/s (scored {v0:g}); the "
    f"robust CBF's tightened v0 = {v0 - filter_speed_shrink:.5f} m/s; CBF position margin {eps:.3f} m"
)
variants = {
    "tube MPC + navigation filter (no CBF)": (lambda: TubeMPC(problem, bounds, navigation=True), None),
    "tube MPC + robust CBF + navigation filter": (lambda: TubeMPC(problem, bounds), bounds),
    "... CBF bounds: navigation only": (
        lambda: TubeMPC(problem, bounds),
        dataclasses.replace(bounds, thrust_scale=0.0, mass=0.0, misalignment_deg=0.0),
    ),
    "... CBF bounds: thrust error only": (
        lambda: TubeMPC(problem, bounds),
        dataclasses.replace(bounds, nav_position=0.0, nav_velocity=0.0),
    ),
    "tube MPC planned inside the CBF's margins + robust CBF": (inside_filter, bounds),
}
for name, (make, cbf_bounds) in variants.items():
    policy = make()
    kwargs = (
        {}
        if cbf_bounds is None
        else dict(cbf_margin=problem.margin, cbf_bounds=cbf_bounds, navigation=bounds)
    )
    flight = fly(problem, policy, held.starts, held.goals, **kwargs)
    ratio = control_effort(flight.thrust, problem)[0] / expert
    energy = (flight.thrust**2).sum(-1)
    r, v = flight.states[:, :-1, :3], flight.states[:, :-1, 3:]
    distance = np.linalg.norm(r - flight.goals[:, None, :], axis=-1)
    slack = v0 + v1 * distance - np.linalg.norm(v, axis=-1)
    bands = [(distance >= lo) & (distance < hi) for lo, hi in BANDS]
    print(
        f"\n{name}: success {flight.is_success.mean():.1%}, energy / expert median {np.median(ratio):.3f}, "
        f"p99 {np.percentile(ratio, 99):.2f}; plans {policy.counts}"
    )
    print(
        "  energy by distance from the port: "
        + ", ".join(
            f"{lo:g}-{hi:g} m {energy[m].sum() / len(energy):.4f}"
            for (lo, hi), m in zip(BANDS, bands, strict=True)
        )
    )
    if flight.cbf_active is not None:
        active = flight.cbf_active
        print(
            "  share of steps the CBF changed the action: "
            + ", ".join(
                f"{lo:g}-{hi:g} m {active[m].mean():.2f}" for (lo, hi), m in zip(BANDS, bands, strict=True)
            )
        )
        far = slack[active & bands[-1]]
        if len(far):
            print(
                f"  at those steps beyond 10 m, inside the scored speed limit by (m/s): min "
                f"{far.min():.5f}, median {np.median(far):.5f}"
            )
