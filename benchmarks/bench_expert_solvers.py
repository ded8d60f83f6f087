"""The constrained docking expert's subproblem solver: Clarabel's second-order-cone program (what
``cwh_envs.experts`` uses) against the polyhedral alternative it replaced (the exact least-distance
NNLS of the keep-out, with proxsuite's box QP as fallback, meeting each cone by tangent-plane cuts).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_expert_solvers.py > results/logs/bench_expert_solvers.txt

On bench_constrained_docking.py's problem and the docking search split's first ``--solve`` starts:

1. Subproblems: every SCP subproblem met along the Clarabel expert's own iterates, solved by both
   from the same anchor. Agreement (relative cost, largest thrust difference) and how far each
   answer breaks the subproblem's exact constraints; time per subproblem.
2. The whole expert from each start, with each solver: time, SCP iterations, cost, and whether the
   verified trajectory came back.

Both run the same SCP (the same restrictions about each iterate: cwh_envs.socp.PathConstraints);
only the convex solver differs. Prints Markdown tables.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from unittest import mock

import numpy as np

from cwh_envs import experts, socp
from cwh_envs.constraints import APEX
from cwh_envs.datasets import evaluation_starts
from cwh_envs.problems import DockingProblem

PLAIN = DockingProblem()
PROBLEM = PLAIN.replace(
    speed_limit=(0.01, 2 * PLAIN.n), approach_cone=(30.0, 15.0)
)  # as bench_constrained_docking
CUT_TOLERANCE = 1e-9  # m/s and m: a point breaking a cone by more gets a tangent plane
CUT_ROUNDS = 400  # re-solves of one subproblem with added planes
WARM_BAND = 1e-3  # m/s and m: the previous answer's points this close to a limit seed the planes


class Polyhedral:
    """The replaced solver: the keep-out's half-spaces plus tangent planes of the speed limit's and
    the cone's second-order cones, added where the answer breaks them until none does. Seeded with
    the planes at the previous iterate's nearly tight points (it remembers its last answer; call
    :meth:`start` before each start, whose first iterate is the expert's waypoint path)."""

    def __init__(self):
        self.previous = None

    def start(self, x0, goal):
        model = experts.linear_model(PROBLEM)
        gap = model.terminal_gap(x0, np.concatenate([goal, np.zeros(3)]))
        self.previous = experts._waypoint_controls(model, x0, gap, goal, PROBLEM.approach_cone[1])

    def __call__(self, model, x0, goal, positions, radius, problem):
        path = socp.PathConstraints.about(
            positions, goal, problem, experts._approach_step(model), model.controllable
        )
        free_positions = model.powers[:, :3, :] @ x0
        free_velocities = model.powers[:, 3:, :] @ x0
        normals = experts._keepout_normals(positions)
        rows = np.einsum("ki,kij->kj", normals, model.position_response)
        rhs = radius - np.einsum("ki,ki->k", normals, free_positions)
        constrained = experts._keepout_steps(model)
        working = constrained & (np.linalg.norm(positions, axis=1) < radius + experts.WORKING_BAND)
        gap = model.terminal_gap(x0, np.concatenate([goal, np.zeros(3)]))

        def planes(controls, within):
            r = free_positions + model.position_response @ controls
            out_rows, out_rhs = [], []
            if path.speed is not None:
                v0, v1 = path.speed
                k = np.arange(1, model.horizon + 1)
                v = free_velocities[k] + model.velocity_response[k] @ controls
                speed = np.linalg.norm(v, axis=1)
                m = path.unit[k]
                bad = (v0 + v1 * np.einsum("ki,ki->k", m, r[k] - goal) - speed < within) & (speed > 0)
                k, w, m = k[bad], v[bad] / speed[bad, None], m[bad]
                # v0 + v1 m^T (r_k - g) - w^T v_k >= 0
                out_rows.append(
                    v1 * np.einsum("ki,kij->kj", m, model.position_response[k])
                    - np.einsum("ki,kij->kj", w, model.velocity_response[k])
                )
                out_rhs.append(
                    -v0
                    + v1 * np.einsum("ki,ki->k", m, goal - free_positions[k])
                    + np.einsum("ki,ki->k", w, free_velocities[k])
                )
            offset = r - goal
            distance = np.linalg.norm(offset, axis=1)
            bad = path.held & (offset @ path.axis - path.cosine * distance < within) & (distance > APEX)
            normal = path.axis - path.cosine * offset[bad] / distance[bad, None]  # the tangent plane
            out_rows.append(np.einsum("ki,kij->kj", normal, model.position_response[bad]))
            out_rhs.append(np.einsum("ki,ki->k", normal, goal - free_positions[bad]))
            bad = path.away & (np.einsum("ki,ki->k", path.unit, offset) - path.radius < within)
            out_rows.append(np.einsum("ki,kij->kj", path.unit[bad], model.position_response[bad]))
            out_rhs.append(path.radius + np.einsum("ki,ki->k", path.unit[bad], goal - free_positions[bad]))
            return np.concatenate(out_rows), np.concatenate(out_rhs)

        cut_rows, cut_rhs = planes(self.previous, WARM_BAND)
        for _ in range(CUT_ROUNDS):
            all_rows, all_rhs = (
                np.concatenate([rows[working], cut_rows]),
                np.concatenate([rhs[working], cut_rhs]),
            )
            controls = experts._min_norm_with_halfspaces(model, gap, all_rows, all_rhs)
            if np.abs(controls).max() > problem.u_max:
                controls = experts._primal_box_qp(model.terminal, gap, all_rows, all_rhs, problem.u_max)
            violated = constrained & ~working & (rows @ controls - rhs < -experts.HALFSPACE_TOLERANCE)
            new_rows, new_rhs = planes(controls, -CUT_TOLERANCE)
            if not violated.any() and len(new_rhs) == 0:
                self.previous = controls
                return controls
            working |= violated
            cut_rows, cut_rhs = np.concatenate([cut_rows, new_rows]), np.concatenate([cut_rhs, new_rhs])
        raise experts.Infeasible("cutting planes did not settle")


BREACHES = ("keep-out [m]", "speed limit [m/s]", "cone [m]", "port ball [m]", "terminal state", "box [N]")


def breaches(model, x0, goal, positions, radius, problem, controls) -> np.ndarray:
    """How far ``controls`` break each of the subproblem's constraints at ``positions`` (BREACHES;
    <= 0 where met; the terminal state's error is >= 0 by definition)."""
    path = socp.PathConstraints.about(
        positions, goal, problem, experts._approach_step(model), model.controllable
    )
    states = model.rollout(x0, controls)
    r, v = states[:, :3], states[:, 3:]
    offset = r - goal
    keepout = radius - np.einsum("ki,ki->k", experts._keepout_normals(positions), r)
    speed = -np.inf
    if path.speed is not None:
        v0, v1 = path.speed
        speed = (
            np.linalg.norm(v[1:], axis=1) - v0 - v1 * np.einsum("ki,ki->k", path.unit[1:], offset[1:])
        ).max()
    cone = path.cosine * np.linalg.norm(offset, axis=1) - offset @ path.axis
    ball = path.radius - np.einsum("ki,ki->k", path.unit, offset)
    return np.array(
        [
            keepout[experts._keepout_steps(model)].max(),
            speed,
            cone[path.held].max(initial=-np.inf),
            ball[path.away].max(initial=-np.inf),
            np.abs(states[-1] - np.concatenate([goal, np.zeros(3)])).max(),
            np.abs(controls).max() - problem.u_max,
        ]
    )


def timed(solve, *args) -> tuple[np.ndarray, float]:
    started = time.perf_counter()
    controls = solve(*args)
    return controls, time.perf_counter() - started


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--solve", type=int, default=16, help="search-split starts")
    args = parser.parse_args()
    starts, goals = evaluation_starts("docking", args.solve, PLAIN)
    clarabel_path = experts._path_subproblem
    polyhedral = Polyhedral()

    # 1. The subproblems along the Clarabel expert's iterates, each solved by both from one anchor.
    met = []  # (start, subproblem)
    whole = {"Clarabel SOCP": [], "polyhedral cuts": []}
    for index, (x0, goal) in enumerate(zip(starts, goals, strict=True)):

        def record(*subproblem, index=index):
            met.append((index, subproblem))
            return clarabel_path(*subproblem)

        with mock.patch.object(experts, "_path_subproblem", record):
            whole["Clarabel SOCP"].append(expert(x0, goal))
    rows = {"Clarabel SOCP": [], "polyhedral cuts": []}
    for i, (index, subproblem) in enumerate(met):
        conic, conic_s = timed(clarabel_path, *subproblem)
        if i == 0 or met[i - 1][0] != index:
            polyhedral.start(starts[index], goals[index])
        else:  # seeded as in the whole expert: the planes about the anchor's own iterate
            polyhedral.previous = rows["Clarabel SOCP"][-1][0]
        cuts, cuts_s = timed(polyhedral, *subproblem)
        for name, controls, seconds in (("Clarabel SOCP", conic, conic_s), ("polyhedral cuts", cuts, cuts_s)):
            rows[name].append((controls, seconds, breaches(*subproblem, controls)))
    pairs = list(zip(rows["Clarabel SOCP"], rows["polyhedral cuts"], strict=True))
    relative = [abs(a @ a - b @ b) / (b @ b) for (a, *_), (b, *_) in pairs]
    apart = [np.abs(a - b).max() for (a, *_), (b, *_) in pairs]

    # 2. The whole expert with the polyhedral solver (the Clarabel runs were timed in 1 while recording).
    for x0, goal in zip(starts, goals, strict=True):
        polyhedral.start(x0, goal)
        with mock.patch.object(experts, "_path_subproblem", polyhedral):
            whole["polyhedral cuts"].append(expert(x0, goal))

    print(
        f"Python {platform.python_version()}, {os.cpu_count()} CPUs (load average {os.getloadavg()[0]:.2f}); "
        f"speed_limit={PROBLEM.speed_limit[0]:g} m/s + {PROBLEM.speed_limit[1]:.5f}/s x distance, "
        f"approach_cone={PROBLEM.approach_cone[0]:g} deg within {PROBLEM.approach_cone[1]:g} m; "
        f"docking search split, first {args.solve} starts\n"
    )
    print(f"1. The {len(met)} SCP subproblems along the Clarabel expert's iterates, each solved by both\n")
    print("| solver | time per subproblem, median | p90 | max |")
    print("|---|---:|---:|---:|")
    for name, results in rows.items():
        seconds = np.array([r[1] for r in results]) * 1e3
        print(
            f"| {name} | {np.median(seconds):.1f} ms | {np.percentile(seconds, 90):.1f} ms | {seconds.max():.0f} ms |"
        )
    print("\nThe most an answer breaks each constraint of its subproblem by (negative: never reaches it):\n")
    print(f"| solver | {' | '.join(BREACHES)} |")
    print("|---|" + "---:|" * len(BREACHES))
    for name, results in rows.items():
        worst = np.max([r[2] for r in results], axis=0)
        print(f"| {name} | {' | '.join(f'{w:.1e}' for w in worst)} |")
    print(
        f"\nAgreement: cost within {max(relative):.1e} relative (median {np.median(relative):.1e}); "
        f"thrust within {max(apart):.1e} N (median {np.median(apart):.1e} N).\n"
    )
    print("2. The whole expert, start by start\n")
    print("| solver | verified | time per start, median | max | total | SCP iterations, median |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, runs in whole.items():
        ok = [r for r in runs if r[0] is not None]
        seconds = [r[1] for r in runs]
        print(
            f"| {name} | {len(ok)} of {len(runs)} | {statistics.median(seconds):.2f} s | {max(seconds):.1f} s "
            f"| {sum(seconds):.0f} s | {statistics.median(r[2] for r in ok):.0f} |"
        )
    paired = list(zip(whole["Clarabel SOCP"], whole["polyhedral cuts"], strict=True))
    gaps = [abs(a[0] - b[0]) / b[0] for a, b in paired if a[0] and b[0]]
    ratio = statistics.median(b[1] / a[1] for a, b in paired)
    print(
        f"\nOn the {len(gaps)} starts both solved, the final costs agree within {max(gaps):.1e} relative; "
        f"time per start, polyhedral over Clarabel: median {ratio:.1f}x."
    )
    return 0


def expert(x0, goal) -> tuple[float | None, float, int]:
    """(cost or None where it raised Infeasible, seconds, SCP iterations) of one constrained solve."""
    started = time.perf_counter()
    try:
        solution = experts.scp_docking(x0, goal, PROBLEM)
    except experts.Infeasible as error:
        print(f"[bench_expert_solvers] infeasible: {error}", file=sys.stderr)
        return None, time.perf_counter() - started, 0
    return solution.cost, time.perf_counter() - started, solution.iterations


if __name__ == "__main__":
    sys.exit(main())
