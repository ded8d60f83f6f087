"""The 3-sigma flight of robust_safety's row "tube MPC + covariance-sized robust CBF with stop line +
navigation filter" on all 1024 sealed constrained starts, flown alone (the same draws and keywords as
the row; the row's nominal and 1-sigma flights are not flown here).

    OMP_NUM_THREADS=1 .venv/bin/python results/robust-safety/tube_stop_line_3sigma.py > results/robust-safety/tube_stop_line_3sigma.txt
"""

import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

import robust_safety  # noqa: E402

from cwh_envs import splits  # noqa: E402
from cwh_envs.prepare import load_train  # noqa: E402
from cwh_envs.robust_cbf import ErrorBounds  # noqa: E402
from cwh_envs.rollout import fly  # noqa: E402

train = load_train(ROOT / "families" / "docking-constrained")
problem, one_sigma = train.PROBLEM, train.DISPERSIONS
split = splits.shipped_split("docking", problem, "test")
starts, goals = split.first(len(split))
bounds = ErrorBounds.from_dispersions(one_sigma, k_sigma=3.0)
row = next(
    r
    for r in robust_safety.rows(problem, bounds, 0)
    if r["name"].startswith("tube MPC + covariance-sized robust CBF with stop line")
)
began = time.time()
policy = row["make"]()
flight = fly(
    problem,
    policy,
    starts,
    goals,
    dispersions={name: 3 * value for name, value in one_sigma.items()},
    dispersion_seed=robust_safety.DISPERSION_SEED,
    **row["fly"],
)
out = {
    "controller": row["name"],
    "split": split.label,
    "starts": len(starts),
    "3σ": {
        "success": float(flight.is_success.mean()),
        **robust_safety.violations(problem, flight),
        **robust_safety.counters(policy),
    },
    "mean_terminal_distance": float(flight.terminal_distance.mean()),
    "seconds": time.time() - began,
}
print(json.dumps(out, indent=1, ensure_ascii=False))
