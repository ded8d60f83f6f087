"""The multi-constraint CBF filter (cwh_envs.cbf_multi): exactness and speed against proxsuite, and
what it does for the PD law on the constrained docking problem.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_cbf_multi.py > results/logs/bench_cbf_multi.txt

1. One QP ``min ||u - u0||^2 s.t. G u >= h, |u| <= u_max`` with three barrier rows, batched exact
   (``project_polytope_box``) against one dense proxsuite QP per instance: random instances, and
   the filter's own QPs on states of PD flights. proxsuite is timed at the settings that match the
   exact answer to about 1e-9 (as bench_experts_cbf.py does) and compared at tighter ones.
2. The whole filter per action (its re-linearisations and fallbacks included) against one proxsuite
   QP per action.
3. The critically damped PD law through the filter on bench_constrained_docking.py's 128 search-split
   starts: the share of starts that break each constraint, and how often the filter gave one up.

Prints Markdown tables.
"""

from __future__ import annotations

import os
import platform

import numpy as np
from bench_experts_cbf import best_of  # a sibling script: benchmarks/ is on the path
from proxsuite import proxqp

from cwh_envs.cbf_multi import barrier_rows, project_polytope_box, safe_actions_multi
from cwh_envs.constraints import CONE_TOLERANCE, SPEED_TOLERANCE, cone_terms, speed_margin
from cwh_envs.controllers import pd_action
from cwh_envs.datasets import evaluation_starts
from cwh_envs.observations import docking_observation
from cwh_envs.problems import DockingProblem
from cwh_envs.rollout import fly

PLAIN = DockingProblem()
PROBLEM = PLAIN.replace(
    speed_limit=(0.01, 2 * PLAIN.n), approach_cone=(30.0, 15.0)
)  # as bench_constrained_docking
U_MAX = PLAIN.u_max
KWARGS = dict(
    koz_radius=PLAIN.koz_radius,
    margin=PLAIN.margin,
    speed_limit=PROBLEM.speed_limit,
    approach_cone=PROBLEM.approach_cone,
)


def proxsuite_qps(u0, rows, rhs, applies, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """One dense proxsuite QP per instance (setup + solve), native box; (x, solved)."""
    x, solved = np.empty_like(u0), np.zeros(len(u0), dtype=bool)
    for i in range(len(u0)):
        on = applies[i]
        qp = proxqp.dense.QP(3, 0, int(on.sum()), True)
        qp.settings.max_iter = 1000  # infeasible instances would otherwise grind for seconds
        qp.settings.eps_abs = eps
        qp.settings.eps_rel = 0.0
        qp.settings.check_duality_gap = True
        qp.settings.eps_duality_gap_abs = eps
        qp.settings.eps_duality_gap_rel = 0.0
        some = bool(on.any())
        qp.init(
            np.eye(3),
            -u0[i],
            None,
            None,
            rows[i][on] if some else None,
            rhs[i][on] if some else None,
            np.full(int(on.sum()), 1e20) if some else None,
            np.full(3, -U_MAX),
            np.full(3, U_MAX),
        )
        qp.solve()
        x[i], solved[i] = qp.results.x, qp.results.info.status == proxqp.QPSolverOutput.PROXQP_SOLVED
    return x, solved


def qp_row(name: str, u0, rows, rhs, applies) -> tuple[str, float]:
    """The table row, and proxsuite's seconds per QP. Both are timed on the feasible instances only:
    on an infeasible one proxsuite runs to its iteration cap, which would flatter the ratio."""
    u, feasible = project_polytope_box(u0, rows, rhs, applies, U_MAX)
    reference, solved = proxsuite_qps(u0, rows, rhs, applies, 1e-12)
    gap = np.max(np.abs(u - reference)[feasible & solved])
    f = feasible
    ours = best_of(200, lambda: project_polytope_box(u0[f], rows[f], rhs[f], applies[f], U_MAX))
    theirs = best_of(5, lambda: proxsuite_qps(u0[f], rows[f], rhs[f], applies[f], 1e-9))
    n = int(f.sum())
    row = (
        f"| {name} | {len(u0)} | {np.mean(~feasible):.2f} | {np.mean(feasible == solved):.4f} | {gap:.1e} | "
        f"{n / ours:,.0f} | {n / theirs:,.0f} | {theirs / ours:.0f}x |"
    )
    return row, theirs / n


def main() -> None:
    rng = np.random.default_rng(0)
    n = 1024
    u0 = rng.normal(0.0, U_MAX, (n, 3))
    rows = rng.normal(size=(n, 3, 3)) * rng.uniform(0.01, 10.0, (n, 3, 1))
    rhs = rng.normal(0.0, 1.5, (n, 3)) * np.linalg.norm(rows, axis=2)
    applies = rng.random((n, 3)) < 0.85

    starts, goals = evaluation_starts("docking", 128, PLAIN)
    law = lambda obs: pd_action(obs, PLAIN)  # noqa: E731
    flight = fly(PROBLEM, law, starts, goals, cbf_margin=PLAIN.margin)
    pick, step = rng.integers(0, len(starts), n), rng.integers(0, PROBLEM.horizon, n)
    states, at = flight.states[pick, step], goals[pick]
    nominal = np.clip(pd_action(docking_observation(states, at, step, PROBLEM.horizon), PLAIN), -1, 1) * U_MAX
    a, b = PROBLEM.matrices()
    own_rows, own_rhs, own_applies = barrier_rows(states, at, nominal, a, b, **KWARGS)

    print(
        f"Python {platform.python_version()}, {os.cpu_count()} CPUs (load average {os.getloadavg()[0]:.2f}), "
        f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}; speed_limit={PROBLEM.speed_limit[0]:g} m/s "
        f"+ {PROBLEM.speed_limit[1]:.5f}/s x distance, approach_cone={PROBLEM.approach_cone[0]:g} deg within "
        f"{PROBLEM.approach_cone[1]:g} m\n"
    )
    print(
        "| QP instances | n | infeasible | feasibility agrees | max abs u gap [N] | exact batched QPs/s, feasible | proxsuite QPs/s, feasible | speed-up (target >= 50x) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    print(qp_row("random (three rows, 85 % applied, mixed scales)", u0, rows, rhs, applies)[0])
    row, per_qp = qp_row("the filter's own, on PD-flight states", nominal, own_rows, own_rhs, own_applies)
    print(row)

    whole = best_of(50, lambda: safe_actions_multi(nominal, states, at, a, b, u_max=U_MAX, **KWARGS))
    print(
        "\n| whole filter (re-linearisation and fallbacks included) | actions/s | vs one proxsuite QP per action |"
    )
    print("|---|---|---|")
    print(f"| safe_actions_multi, {n} PD-flight states | {n / whole:,.0f} | {per_qp * n / whole:.1f}x |")

    after = flight.states[:, 1:]
    flat, flat_goals = after.reshape(-1, 6), np.repeat(goals, after.shape[1], axis=0)
    region, slack, _ = cone_terms(flat, flat_goals, PROBLEM.approach_cone)
    shape = after.shape[:2]
    broken = {
        "keep-out": (np.linalg.norm(flat[:, :3], axis=1) < PLAIN.koz_radius).reshape(shape),
        "speed limit": (speed_margin(flat, flat_goals, PROBLEM.speed_limit) < -SPEED_TOLERANCE).reshape(
            shape
        ),
        "approach cone": (region & (slack < -CONE_TOLERANCE)).reshape(shape),
    }
    dropped = {
        "keep-out": None,
        "speed limit": flight.cbf_dropped[..., 1],
        "approach cone": flight.cbf_dropped[..., 2],
    }
    print(
        f"\n| PD law + multi-constraint CBF, {len(starts)} starts | starts that break it | steps broken | steps the filter gave it up |"
    )
    print("|---|---|---|---|")
    for name, steps in broken.items():
        gave_up = "never (highest priority)" if dropped[name] is None else f"{dropped[name].mean():.1%}"
        print(f"| {name} | {steps.any(axis=1).mean():.1%} | {steps.mean():.1%} | {gave_up} |")
    print(
        f"| (all) success: docked with every constraint met | {flight.is_success.mean():.1%} | | "
        f"infeasible steps {flight.cbf_infeasible.mean():.1%} |"
    )


if __name__ == "__main__":
    main()
