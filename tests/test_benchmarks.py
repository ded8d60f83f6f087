"""benchmarks/run_all.py's key-free rows (experiments to target per arm), on hand-made groups."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from loop_helpers import TOY_FAMILY

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import run_all

from autoresearch.campaign import Campaign, CampaignMeta, Record, Status


def committed_log(tmp_path, monkeypatch, rows, log: str, text: str) -> None:
    """``rows()`` says "not run" until ``log`` (the path of a benchmark's committed output) exists;
    then the log holds ``text``, for the caller to read back through ``rows()``."""
    monkeypatch.setattr(run_all, "ROOT", tmp_path)
    assert rows()[0][1] == "not run"
    path = tmp_path / log
    path.parent.mkdir(parents=True)
    path.write_text(text)


def make_group(root: Path, proposer: str, space: str | None, repeats: list[list[float | None]]) -> None:
    """A group of repeats whose campaigns ran these metrics (None: a failed run), toy family (minimize),
    written through the campaign store."""
    registry = {**json.loads((TOY_FAMILY / "family.json").read_text()), "target": 0.5}
    registry["seed_noise"] = {"mean": 1.0, "std": 0.1}
    settings = {"space": space} if space else {}
    root.mkdir(parents=True)
    (root / "repeats.json").write_text(json.dumps({"proposer": proposer, "settings": settings}))
    for i, metrics in enumerate(repeats):
        store = Campaign(root / f"repeat-{i:02d}")
        store.root.mkdir()
        CampaignMeta(str(TOY_FAMILY), registry["name"], proposer, settings, "2025-01-01").write(store.root)
        store.write_registry(registry)
        for it, m in enumerate(metrics, start=1):
            status = Status.FAILED if m is None else Status.RAN
            store.append(Record(it, status, metric=m, feasible=None if m is None else True, elapsed_s=it))
        store.append(Record(len(metrics) + 1, Status.STOPPED, trigger="max_iters", elapsed_s=9.0))


def test_experiments_to_target_per_arm_with_the_space_each_searched(tmp_path, monkeypatch):
    where = tmp_path / "results" / "cmp"
    make_group(where / "toy-gp", "gp", "random-range", [[1.0, 0.7, 0.4], [1.0, None, 0.8], [1.0, 0.45, 0.3]])
    make_group(where / "toy-random", "random", None, [[1.0, 0.9, 0.85], [1.0, 0.6, 0.9], [1.0, 0.9, 0.9]])
    monkeypatch.setattr(run_all, "ROOT", tmp_path)
    monkeypatch.setattr(
        run_all, "COMPARE_GROUPS", {"toy": ("results/cmp", "toy"), "none": ("results/x", "x")}
    )
    rows = run_all.compare_rows()
    target, gate, missing = rows
    # Target 0.5: gp's repeats reach it at experiments 3 and 2 and never: median 3; random never
    # within the budget of 3 experiments.
    assert target[0].endswith("target 0.5") and target[1] == "gp 3 (2/3); random >3 (0/3)"
    # The gate (1.0 - 2 x 0.1 = 0.8): gp at 2, 3, 2; random at never, 2, never: the median is censored,
    # and the one repeat that got there did at its 2nd experiment.
    assert gate[1] == "gp 2 (3/3); random >3 (1/3, at 2)"
    assert "all over random-range" in target[3]  # random's default space is random-range
    assert missing[1] == "not run"


def test_arms_over_different_spaces_are_flagged(tmp_path, monkeypatch):
    where = tmp_path / "results" / "cmp"
    make_group(where / "toy-tpe", "tpe", None, [[1.0, 0.4]])
    make_group(where / "toy-random", "random", None, [[1.0, 0.9]])
    monkeypatch.setattr(run_all, "ROOT", tmp_path)
    monkeypatch.setattr(run_all, "COMPARE_GROUPS", {"toy": ("results/cmp", "toy")})
    assert "spaces differ: random random-range, tpe bounds" in run_all.compare_rows()[0][3]


def make_campaign(root: Path, runs: list[tuple[str, float | None, float]], early_stop: str = "none") -> None:
    """A campaign of (status, metric, wall seconds) runs after a baseline, toy family (minimize)."""
    root.mkdir(parents=True)
    registry = json.loads((TOY_FAMILY / "family.json").read_text())
    CampaignMeta(str(TOY_FAMILY), registry["name"], "tpe", {"early_stop": early_stop}, "2025-01-01").write(
        root
    )
    store = Campaign(root)
    store.write_registry(registry)
    store.append(Record(1, Status.RAN, proposer="baseline", metric=9.0, wall_seconds=100.0))
    for it, (status, metric, wall) in enumerate(runs, start=2):
        store.append(Record(it, Status(status), proposer="tpe", metric=metric, wall_seconds=wall))
    store.append(Record(len(runs) + 2, Status.STOPPED, proposer="tpe"))


def test_early_stop_row_compares_run_seconds_per_experiment_and_best(tmp_path, monkeypatch):
    make_campaign(tmp_path / "none", [("ran", 0.5, 80.0), ("failed", None, 150.0), ("ran", 0.4, 70.0)])
    make_campaign(
        tmp_path / "asha",
        [("early_stopped", None, 10.0), ("ran", 0.6, 40.0), ("early_stopped", None, 10.0)],
        "asha",
    )
    monkeypatch.setattr(run_all, "ROOT", tmp_path)
    monkeypatch.setattr(run_all, "EARLY_STOP_PAIRS", [("toy", "none", "asha"), ("missing", "none", "nope")])
    row, missing = run_all.early_stop_rows()
    # 60 / 3 = 20 s against 300 / 3 = 100 s (the baseline left out); a stopped run is never best.
    assert row[0].endswith("asha vs none") and row[1] == "20.0 s vs 100.0 s" and row[2] == "0.20x"
    assert row[3].startswith("best 0.6 vs 0.4; runs finished 1/3 vs 2/3")
    assert missing[1] == "not run"


def test_parallel_row_reads_the_committed_measurement(tmp_path, monkeypatch):
    log = tmp_path / "results" / "logs" / "bench_loop_parallel.txt"
    log.parent.mkdir(parents=True)
    log.write_text(
        "measure  value  note\n"
        "docking random, --max-runs 8, --workers 1          150.0 s  8 runs ok\n"
        "docking random, --max-runs 8, --workers 2           90.0 s  8 runs ok\n"
        "wall time ratio, --workers 2 / 1                     0.60x  target <= 0.6x\n"
    )
    monkeypatch.setattr(run_all, "ROOT", tmp_path)
    row = run_all.parallel_row(False, tmp_path)
    assert row[1:3] == ("90.0 s vs 150.0 s", "0.60x (target <= 0.6x)") and "results/logs" in row[3]
    log.unlink()
    assert run_all.parallel_row(False, tmp_path)[1] == "not run"


def test_main_job_row_reads_the_fresh_clone_log(tmp_path, monkeypatch):
    monkeypatch.setattr(run_all, "ROOT", tmp_path)
    assert run_all.main_job_row()[1] == "not run"
    log = tmp_path / run_all.MAIN_JOB_LOG
    log.parent.mkdir(parents=True)
    log.write_text(
        "[fresh clone] commit abc1234, 2 CPUs, 2026-11-25 00:40 UTC, install: 61 s\n"
        "[main] headline: candidate 2b93d51f reseeded 1.734 +- 0.036 (n=3), m = 6.18 sigma: PASS\n"
        "[main] wall time: 246 s\n"
    )
    what, measured, target, note = run_all.main_job_row()
    assert what.startswith("main job")
    assert (measured, target) == ("246 s", "target <= 600 s")
    assert note.startswith("candidate 2b93d51f reseeded 1.734") and "install 61 s before it" in note


def test_sb3_and_evaluation_rows_read_the_committed_tables(tmp_path, monkeypatch):
    monkeypatch.setattr(run_all, "ROOT", tmp_path)
    assert run_all.sb3_rows()[0][1] == run_all.evaluation_rows()[0][1] == "not run"
    logs = tmp_path / "results" / "logs"
    logs.mkdir(parents=True)
    header = (
        "| VecEnv | envs | learn env-steps/s | vs Dummy | rollout env-steps/s | vs Dummy | learn wall [s] |\n"
    )
    (logs / "bench_sb3.txt").write_text(
        "SB3 2.9; PPO on rendezvous, 16 envs, 16384 env steps per run\n\n"
        + header
        + "| NativeVecEnv, info_keys=('is_success',) | 16 | 20,000 | 2.00x | 30,000 | 3.00x | 0.6 |\n"
        "| NativeVecEnv, every info key | 16 | 19,000 | 1.90x | 29,000 | 2.90x | 0.6 |\n"
        "| DummyVecEnv | 16 | 10,000 | 1.00x | 10,000 | 1.00x | 1.3 |\n"
        "SB3 2.9; PPO on docking+cbf, 8 envs, 16384 env steps per run\n\n"
        + header
        + "| NativeVecEnv, info_keys=('is_success',) | 8 | 9,000 | 4.50x | 12,000 | 6.00x | 0.7 |\n"
        "| DummyVecEnv | 8 | 2,000 | 1.00x | 2,000 | 1.00x | 3.3 |\n"
    )
    (logs / "bench_evaluation.txt").write_text(
        "Python 3.11\n\n| family | build search (128) | build test (1024) | evaluate search | evaluate test |"
        " test / search |\n|---|---:|---:|---:|---:|---:|\n| rendezvous | 0.1 s | 0.3 s | 0.05 s | 0.40 s | 8.0x |\n"
    )
    rdv, dock = run_all.sb3_rows()
    assert rdv[0].endswith("rendezvous") and rdv[1:3] == ("20,000 vs 10,000", "2.00x (rollout alone 3.00x)")
    assert dock[0].endswith("docking+cbf") and dock[1] == "9,000 vs 2,000" and dock[3].startswith("8 envs")
    (row,) = run_all.evaluation_rows()
    assert row[0].endswith("search split (128), rendezvous") and row[1:3] == ("0.40 s vs 0.05 s", "8.0x")
    assert "0.3 s" in row[3]


def test_install_rows_read_the_committed_table(tmp_path, monkeypatch):
    text = (
        "Python 3.11\n\n| measure | value | comparison |\n|---|---:|---|\n"
        "| install size, base | 400 MB | 1.0x base |\n| install size, [all] | 2,000 MB | 5.0x base |\n"
        "| start-up, import cwh_envs | 0.300 s | +0.100 s over gymnasium (target <= 0.15 s) |\n"
    )
    committed_log(tmp_path, monkeypatch, run_all.install_rows, "results/logs/bench_install.txt", text)
    rows = run_all.install_rows()
    assert [r[:3] for r in rows] == [
        ("install size, base", "400 MB", "1.0x base"),
        ("install size, [all]", "2,000 MB", "5.0x base"),
        ("start-up, import cwh_envs", "0.300 s", "+0.100 s over gymnasium (target <= 0.15 s)"),
    ]
    assert rows[0][3] == "from results/logs/bench_install.txt"


def test_ray_rows_read_the_committed_tables(tmp_path, monkeypatch):
    text = (
        "Python 3.11\n\n| Ray workers | campaign wall | vs 1 worker | audit wall | vs 1 worker |\n"
        "|---:|---:|---:|---:|---:|\n| 1 | 20.0 s | 1.00x | 24.0 s | 1.00x |\n"
        "| 4 | 8.0 s | 0.40x | 6.0 s | 0.25x |\n\n"
        "| one run at a time, no sleep | seconds per run | Ray overhead per run |\n|---|---:|---:|\n"
        "| local subprocess | 0.500 | reference |\n| Ray task, --ray-files ship | 0.510 | +0.010 |\n"
    )
    committed_log(tmp_path, monkeypatch, run_all.ray_rows, "results/logs/bench_ray_scaling.txt", text)
    scaling, ship = run_all.ray_rows()
    assert scaling[0].endswith("4 vs 1 worker(s)") and scaling[1:3] == ("8.0 s / 6.0 s", "0.40x / 0.25x")
    assert ship[:3] == ("Ray overhead per run, --ray-files ship", "0.510 s per run", "+0.010 s vs local")


def test_evidence_rows_read_the_committed_campaigns():
    rows = run_all.evidence_rows()
    assert [row[0].split(",")[1].split(":")[0].strip() for row in rows] == ["rendezvous", "docking"]
    for what, measured, verdict, note in rows:
        assert "gp over" in what and measured.startswith("target ") and "reseeded" in verdict
        assert note.endswith(tuple(run_all.EVIDENCE_CAMPAIGNS))


def test_cbf_multi_rows_read_the_committed_table(tmp_path, monkeypatch):
    text = (
        "Python 3.11\n\n| QP instances | n | infeasible | feasibility agrees | max abs u gap [N] | exact | prox | x |\n"
        "|---|---|---|---|---|---|---|---|\n"
        "| random (three rows) | 1024 | 0.18 | 1.0000 | 5.1e-12 | 700,000 | 14,000 | 50x |\n"
        "| the filter's own, on PD-flight states | 1024 | 0.31 | 1.0000 | 7.0e-12 | 900,000 | 15,000 | 60x |\n\n"
        "| whole filter | actions/s | vs one proxsuite QP per action |\n|---|---|---|\n"
        "| safe_actions_multi, 1024 PD-flight states | 100,000 | 5.0x |\n"
        "\n| PD law + multi-constraint CBF, 128 starts | starts that break it | steps broken | gave up |\n"
        "| keep-out | 0.0% | 0.0% | never |\n"
    )
    committed_log(tmp_path, monkeypatch, run_all.cbf_multi_rows, "results/logs/bench_cbf_multi.txt", text)
    random, own, whole = run_all.cbf_multi_rows()
    assert random[1:3] == ("700,000 vs 14,000", "50x (target >= 50x)") and "5.1e-12" in random[3]
    assert own[0].endswith("the filter's own, on PD-flight states instances") and own[2].startswith("60x")
    assert whole[1:3] == ("100,000", "5.0x one proxsuite QP")


def test_expert_solver_rows_read_the_committed_table(tmp_path, monkeypatch):
    text = (
        "Python 3.11\n\n| solver | time per subproblem, median | p90 | max |\n|---|---:|---:|---:|\n"
        "| Clarabel SOCP | 36.0 ms | 45.2 ms | 63 ms |\n\n"
        "| solver | verified | time per start, median | max | total | SCP iterations, median |\n"
        "|---|---:|---:|---:|---:|---:|\n"
        "| Clarabel SOCP | 16 of 16 | 0.86 s | 3.6 s | 17 s | 25 |\n"
        "| polyhedral cuts | 15 of 16 | 4.70 s | 196.4 s | 368 s | 25 |\n\n"
        "On the 15 starts both solved, the final costs agree within 5.8e-09 relative; time ...\n"
    )
    committed_log(
        tmp_path, monkeypatch, run_all.expert_solver_rows, "results/logs/bench_expert_solvers.txt", text
    )
    ((what, measured, ratio, note),) = run_all.expert_solver_rows()
    assert what.startswith("constrained docking expert")
    assert measured == "0.86 s vs 4.70 s; max 3.6 s vs 196.4 s" and ratio == "in all 17 s vs 368 s"
    assert note.startswith("verified 16 of 16 vs 15 of 16; final costs within 5.8e-09")


def test_flight_path_rows_read_the_committed_table(tmp_path, monkeypatch):
    text = (
        "[bench] robust hand recipe (BC) on 8 sealed docking-constrained starts, 1920 steps, µs a step\n"
        "path: layer                                        p50       p99      mean\n"
        "numpy: navigation                                102.2     190.1     109.1\n"
        "numpy: policy                                    410.8     695.4     434.1\n"
        "numpy: filter                                    590.3    1395.9     712.5\n"
        "numpy                                           1133.5    2052.0    1255.7\n"
        "compiled, ONNX policy: navigation                  9.7      24.5      10.4\n"
        "compiled, ONNX policy: policy                     58.0     119.6      61.9\n"
        "compiled, ONNX policy: filter                     21.8      53.8      23.7\n"
        "compiled, ONNX policy                             89.8     173.5      95.9\n"
        "compiled, compiled policy: navigation              7.7      16.0       8.3\n"
        "compiled, compiled policy: policy                  9.7      19.7      10.5\n"
        "compiled, compiled policy: filter                 13.1      34.3      14.7\n"
        "compiled, compiled policy                         30.6      82.0      33.5\n"
        "robust MPC (tube MPC (robust))                    15.5      67.9    6490.4   (one 1.10 s plan ...)\n"
        "[bench] compiled, ONNX policy: 0.076 of the numpy path; of the robust MPC's mean step, 0.0148 with "
        "navigation, exported policy + filter 0.0132; compiled, compiled policy: 0.027 of the numpy path; of "
        "the robust MPC's mean step, 0.0052 with navigation, exported policy + filter 0.0039 (target <= "
        "0.01); every compiled filter answer within 1e-09 N of numpy's\n"
    )
    committed_log(tmp_path, monkeypatch, run_all.flight_path_rows, "results/logs/bench_flight_path.txt", text)
    ((what, measured, ratio, note),) = run_all.flight_path_rows()
    assert what.startswith("learned robust row")
    assert measured == "1133.5 vs 30.6"
    assert ratio == (
        "0.027 (means); exported policy + filter 0.0039 of the robust MPC's mean step (target <= 0.01; "
        "ONNX policy: 0.0132)"
    )
    assert note.startswith(
        "policy 410.8 (torch) vs 9.7 (ONNX 58.0), filter 590.3 vs 13.1, navigation filter 102.2 vs 7.7; "
    )
