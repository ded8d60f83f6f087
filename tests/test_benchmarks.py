"""benchmarks/run_all.py's TPE-vs-random row, on hand-made arms and records (nothing is measured)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from loop_helpers import TOY_FAMILY

from autoresearch.family import Family

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from run_all import arm_runs, experiments_to_reach

MINIMIZE, MAXIMIZE = -1, +1


def test_feasible_runs_set_the_bar_and_failed_runs_still_count_as_experiments():
    random = [(5.0, True), (1.0, False), (None, False), (3.0, True), (4.0, True)]
    tpe = [(5.0, True), (None, False), (2.0, False), (3.5, True), (2.9, True)]
    reach = experiments_to_reach(tpe, random, MINIMIZE)
    # The infeasible 1.0 is not random's best; TPE's infeasible 2.0 does not reach 3.0.
    assert (reach.best, reach.random_at, reach.tpe_at, reach.fell_back) == (3.0, 4, 5, ())


def test_tpe_that_never_reaches_and_the_maximize_direction():
    random = [(0.2, True), (0.9, True)]
    assert experiments_to_reach([(0.5, True), (0.8, True)], random, MAXIMIZE).tpe_at is None
    assert experiments_to_reach([(0.95, True)], random, MAXIMIZE).tpe_at == 1
    assert experiments_to_reach([(0.95, True)], random, MINIMIZE).best == 0.2


def test_an_arm_without_a_feasible_run_falls_back_to_all_its_successful_runs():
    random = [(5.0, False), (2.0, False), (None, False)]
    tpe = [(3.0, False), (1.5, True)]
    reach = experiments_to_reach(tpe, random, MINIMIZE)
    assert (reach.best, reach.random_at, reach.tpe_at, reach.fell_back) == (2.0, 2, 2, ("random",))
    empty = experiments_to_reach(tpe, [(None, False)], MINIMIZE)
    assert empty.best is None and empty.tpe_at is None


def test_arm_runs_reads_proposals_with_the_feasibility_field(tmp_path):
    family = Family.load(TOY_FAMILY)
    config = family.baseline_config

    def record(iteration, status, metric=None, feasible=None, run_id=None):
        return {
            "iteration": iteration,
            "proposer": "baseline" if iteration == 1 else "random",
            "status": status,
            "config": {**config, "EPOCHS": 10 + iteration},
            "overrides": {},
            "run_id": run_id,
            "metric": metric,
            "feasible": True,  # the loop's own flag; arm_runs re-reads the family's field
            "record": None if metric is None else {"loss": metric, "feasible": feasible},
        }

    records = [
        record(1, "ran", 0.9, True, "it0001"),
        record(2, "invalid"),
        record(3, "failed", run_id="it0003"),
        record(4, "ran", 0.4, False, "it0004"),
    ]
    log = tmp_path / "proposals.jsonl"
    log.write_text("".join(json.dumps(r) + "\n" for r in records))
    assert arm_runs(family, tmp_path) == ([(0.9, True), (None, False), (0.4, False)], False)
    log.write_text(log.read_text() + json.dumps(record(5, "stopped")) + "\n")
    assert arm_runs(family, tmp_path)[1] is True
