"""Throughput of the CBF filter, the experts, the samplers and the dataset builders.

    .venv/bin/python benchmarks/bench_experts_cbf.py

Prints one row per measurement: name, value, target and ratio, where ratio >= 1 means the target
is met (value / target for "at least" targets, target / value for "at most" ones). Rows without
a target are context. Times are the best of a few repeats (the least disturbed by other
processes); dataset builds use a fresh temporary cache directory, so they are cold-cache builds.
"""

from __future__ import annotations

import os
import tempfile
import time
from typing import NamedTuple

import numpy as np
from proxsuite import proxqp

from cwh_envs.cbf import barrier_terms, safe_actions
from cwh_envs.datasets import demonstrations
from cwh_envs.experts import Infeasible, koz_active, linear_model, scp_docking, serial_openmp
from cwh_envs.problems import DockingProblem, RendezvousProblem
from cwh_envs.sampling import docking_candidates, docking_screen, sample_docking_starts, screened_rendezvous

DOCKING, RENDEZVOUS = DockingProblem(), RendezvousProblem()
RADIUS = DOCKING.koz_radius + DOCKING.margin


def best_of(repeats: int, function) -> float:
    """Smallest wall time [s] of ``repeats`` calls."""
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        function()
        times.append(time.perf_counter() - started)
    return min(times)


def proxsuite_filter(u_nominal, beta, rho, u_max) -> np.ndarray:
    """The same filter as one dense proxsuite QP per action (setup + solve), native box."""
    out = np.empty_like(u_nominal)
    limit = np.full(3, u_max)
    with serial_openmp():
        for i in range(len(u_nominal)):
            qp = proxqp.dense.QP(3, 0, 1, box_constraints=True)
            qp.settings.max_iter = 1000  # infeasible instances would otherwise grind for seconds
            # Equal accuracy: proxsuite's default (1e-5, no duality-gap test) stops up to 0.05 N
            # short of the optimum on these instances.
            qp.settings.eps_abs = 1e-9
            qp.settings.eps_rel = 0.0
            qp.settings.check_duality_gap = True
            qp.settings.eps_duality_gap_abs = 1e-9
            qp.settings.eps_duality_gap_rel = 0.0
            upper = np.array([np.inf])
            qp.init(
                np.eye(3), -u_nominal[i], None, None, beta[i : i + 1], rho[i : i + 1], upper, -limit, limit
            )
            qp.solve()
            out[i] = qp.results.x
    return out


class CBFMeasure(NamedTuple):
    batched_s: float  # best wall time of one batched exact call on all n actions
    proxsuite_s: float  # best wall time of n proxsuite QPs
    n: int
    active: float  # fraction of instances with the barrier active
    infeasible: float
    gap: float  # max |batched - proxsuite| over the feasible instances [N]


def cbf_measure(
    rng: np.random.Generator, n: int = 1024, repeats: int = 50, qp_repeats: int = 3
) -> CBFMeasure:
    """Batched exact filter vs one proxsuite QP per action, on n states 6-12 m out, thrust inwards."""
    a, b = DOCKING.matrices()
    positions = rng.normal(size=(n, 3))
    positions *= rng.uniform(6.0, 12.0, size=(n, 1)) / np.linalg.norm(positions, axis=1, keepdims=True)
    states = np.concatenate([positions, rng.normal(size=(n, 3)) * 0.05], axis=1)
    inward = -positions / np.linalg.norm(positions, axis=1, keepdims=True)
    nominal = inward * rng.uniform(0.0, DOCKING.u_max, size=(n, 1)) + rng.normal(size=(n, 3)) * 0.5
    kwargs = dict(koz_radius=DOCKING.koz_radius, margin=DOCKING.margin, u_max=DOCKING.u_max)
    result = safe_actions(nominal, states, a, b, **kwargs)
    batched = best_of(repeats, lambda: safe_actions(nominal, states, a, b, **kwargs))
    beta, rho = barrier_terms(states, a, b, RADIUS)
    per_qp = best_of(qp_repeats, lambda: proxsuite_filter(nominal, beta, rho, DOCKING.u_max))
    reference = proxsuite_filter(nominal, beta, rho, DOCKING.u_max)
    gap = np.abs(reference - result.u)[~result.infeasible].max()
    return CBFMeasure(batched, per_qp, n, result.active.mean(), result.infeasible.mean(), gap)


def cbf_rows(rng: np.random.Generator) -> list:
    m = cbf_measure(rng)
    return [
        ("CBF instances: barrier active [frac]", m.active, None, None),
        ("CBF instances: infeasible [frac]", m.infeasible, None, None),
        ("CBF max |batched - proxsuite|, feasible [N]", m.gap, None, None),
        ("CBF batched exact [actions/s]", m.n / m.batched_s, None, None),
        ("CBF proxsuite, 1 QP/action [actions/s]", m.n / m.proxsuite_s, None, None),
        ("CBF speed-up batched / proxsuite [x]", m.proxsuite_s / m.batched_s, 100.0, "higher"),
    ]


def docking_demos(starts, goals):
    """SCP solutions and wall time per attempted start; failures are counted, not raised."""
    started = time.perf_counter()
    solutions = []
    for x0, goal in zip(starts, goals, strict=True):
        try:
            solutions.append(scp_docking(x0, goal, DOCKING))
        except Infeasible:
            solutions.append(None)
    return solutions, (time.perf_counter() - started) / len(starts)


def rendezvous_expert_time(n: int = 384, repeats: int = 3) -> float:
    """Wall seconds per accepted rendezvous demonstration (best of ``repeats`` batches of n), warm."""
    screened_rendezvous(np.random.default_rng(1), 8, RENDEZVOUS)  # build the cached model and QP
    return best_of(repeats, lambda: screened_rendezvous(np.random.default_rng(2), n, RENDEZVOUS)) / n


def docking_expert_run(n: int = 128):
    """(starts, goals, solutions, wall seconds per demonstration) of the SCP expert on n screened starts."""
    starts, goals = sample_docking_starts(np.random.default_rng(3), n, DOCKING)
    docking_demos(starts[:1], goals[:1])  # untimed warm-up: the first solve builds the cached model
    return starts, goals, *docking_demos(starts, goals)


def expert_rows() -> list:
    rendezvous_time = rendezvous_expert_time()
    starts, goals, solutions, docking_time = docking_expert_run()
    solved = [s for s in solutions if s is not None]
    trajectories = np.stack([s.states for s in solved])
    clearance = np.linalg.norm(trajectories[:, :, :3], axis=2)
    model = linear_model(DOCKING)
    free_cost = [
        np.sum(model.min_energy(x, np.r_[g, 0, 0, 0]) ** 2) for x, g in zip(starts, goals, strict=True)
    ]
    cost_ratio = [s.cost / c for s, c in zip(solutions, free_cost, strict=True) if s is not None]
    naive_starts, naive_goals = (
        block[:128] for block in docking_candidates(np.random.default_rng(5), DOCKING)
    )
    naive = [s for s in docking_demos(naive_starts, naive_goals)[0] if s is not None]
    candidates = [docking_candidates(np.random.default_rng(6 + i), DOCKING) for i in range(8)]
    acceptance = np.mean([docking_screen(*block, DOCKING).mean() for block in candidates])
    screen = best_of(3, lambda: sample_docking_starts(np.random.default_rng(4), 1024, DOCKING))
    return [
        ("rendezvous expert [ms/accepted demo]", 1e3 * rendezvous_time, 2.0, "lower"),
        ("docking expert (SCP) [ms/demo]", 1e3 * docking_time, 58.0, "lower"),
        ("docking SCP failures on screened starts [frac]", 1 - len(solved) / len(solutions), None, None),
        ("docking SCP iterations [mean]", np.mean([s.iterations for s in solved]), None, None),
        ("docking SCP iterations [max]", max(s.iterations for s in solved), None, None),
        ("screened: keep-out active [frac]", koz_active(trajectories, DOCKING).mean(), 0.8, "higher"),
        (
            "screened: steps within 1 mm of R+delta [mean]",
            np.mean((clearance <= RADIUS + 1e-3).sum(1)),
            None,
            None,
        ),
        ("screened: cost / unconstrained cost [median]", np.median(cost_ratio), None, None),
        (
            "unscreened far side: keep-out active [frac]",
            koz_active(np.stack([s.states for s in naive]), DOCKING).mean(),
            None,
            None,
        ),
        ("docking screen acceptance [frac]", acceptance, None, None),
        ("docking screen, 1024 starts [s]", screen, 2.0, "lower"),
    ]


def dataset_rows() -> list:
    with tempfile.TemporaryDirectory() as cache:
        started = time.perf_counter()
        demonstrations("rendezvous", 384, seed=0, cache_dir=cache)
        rendezvous_time = time.perf_counter() - started
        started = time.perf_counter()
        demos = demonstrations("docking", 256, seed=0, cache_dir=cache)
        docking_time = time.perf_counter() - started
    trajectories = demos.observations[:, :6].reshape(256, DOCKING.horizon, 6)
    return [
        ("384 rendezvous demos, cold cache [s]", rendezvous_time, 1.5, "lower"),
        ("256 docking demos, cold cache [s]", docking_time, 15.0, "lower"),
        (
            "256 docking demos: keep-out active [frac]",
            koz_active(trajectories, DOCKING).mean(),
            0.8,
            "higher",
        ),
    ]


def main() -> None:
    rows = cbf_rows(np.random.default_rng(0)) + expert_rows() + dataset_rows()
    threads = os.environ.get("OMP_NUM_THREADS", "unset")
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}, OMP_NUM_THREADS={threads}")
    print(f"{'name':48s} {'value':>11s} {'target':>8s} {'ratio':>7s}")
    for name, value, target, direction in rows:
        if target is None:
            print(f"{name:48s} {value:11.4g}")
            continue
        ratio = value / target if direction == "higher" else target / value
        bound = (">=" if direction == "higher" else "<=") + format(target, "g")
        print(f"{name:48s} {value:11.4g} {bound:>8s} {ratio:7.2f}")


if __name__ == "__main__":
    main()
