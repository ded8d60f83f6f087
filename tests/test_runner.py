import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from loop_helpers import copy_toy, snapshot

from autoresearch.execution.processes import stop_orphaned_run
from autoresearch.execution.protocol import parse_final_metric
from autoresearch.execution.runner import run_locally, run_prepare_check
from autoresearch.execution.spec import RunHooks, RunSpec
from autoresearch.family import Family
from autoresearch.journal import read_jsonl

HEADER = """# ===== Editable Configuration =====
X = 1  # a knob
# ===== Fixed Configuration =====
import argparse, json, os, subprocess, sys, time
p = argparse.ArgumentParser()
for flag in ("--seed", "--run-id", "--runs-log", "--out"):
    p.add_argument(flag)
args = p.parse_args()
"""
GOOD = 'print("FINAL_METRIC: " + json.dumps({"run_id": args.run_id, "score": X * 1.5, "seed": args.seed}))\n'


def mini_family(root: Path, body: str, prepare: str = "import sys; sys.exit(0)\n") -> Family:
    """A one-parameter family whose train.py runs ``body`` after parsing its arguments."""
    root.mkdir(parents=True)
    registry = {
        "name": "mini",
        "metric": "score",
        "direction": "maximize",
        "target": None,
        "feasibility_field": None,
        "axes": ["a"],
        "search_space": {"X": {"type": "int", "low": 0, "high": 10, "axis": "a"}},
        "baseline": {"config": {"X": 1}, "metric": None, "seed": 0},
        "seed_noise": None,
        "best": None,
    }
    (root / "family.json").write_text(json.dumps(registry))
    (root / "train.py").write_text(HEADER + body)
    (root / "prepare.py").write_text(prepare)
    (root / "program.md").write_text("mini\n")
    (root / "program_blind.md").write_text("mini\n")
    return Family.load(root)


def run(family: Family, tmp_path: Path, config=None, run_id="r1", timeout=30.0):
    run_dir, runs_log = tmp_path / "c" / "runs" / run_id, tmp_path / "c" / "runs.jsonl"
    return run_locally(
        RunSpec(family, config or family.baseline_config, run_id, 3, run_dir, runs_log, timeout)
    )


def alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2] != "Z"


def test_toy_run_patches_a_copy_and_parses_the_metric(tmp_path):
    family_dir = copy_toy(tmp_path)
    before = snapshot(family_dir)
    family = Family.load(family_dir)
    config = {**family.baseline_config, "LEARNING_RATE": 0.003, "USE_NORM": True}
    ticks = []
    run_dir, runs_log = tmp_path / "c" / "runs" / "it0001", tmp_path / "c" / "runs.jsonl"
    result = run_locally(RunSpec(family, config, "it0001", 0, run_dir, runs_log, 30), RunHooks(ticks.append))
    assert result.status == "ok" and result.returncode == 0 and result.reason is None
    assert result.final_metric["config"] == config and result.metric == result.final_metric["loss"]
    run_dir = tmp_path / "c" / "runs" / "it0001"
    copy = (run_dir / "train.py").read_text()
    assert "LEARNING_RATE = 0.003  # step size" in copy and "USE_NORM = True  # layer" in copy
    assert (run_dir / "out" / "policy.json").exists() and (run_dir / "result.json").exists()
    assert read_jsonl(tmp_path / "c" / "runs.jsonl") == [result.final_metric]
    assert snapshot(family_dir) == before


def test_failing_run_reports_stderr(tmp_path):
    family = Family.load(copy_toy(tmp_path))
    result = run(family, tmp_path, {**family.baseline_config, "EPOCHS": 0})
    assert result.status == "failed" and result.returncode == 1
    assert "exited with code 1" in result.reason and "EPOCHS must be positive" in result.reason
    assert read_jsonl(tmp_path / "c" / "runs.jsonl") == []


@pytest.mark.parametrize(
    ("body", "why"),
    [
        ("print('no metric here')\n", "no FINAL_METRIC line"),
        (GOOD + GOOD, "2 FINAL_METRIC lines"),
        ("print('FINAL_METRIC: {not json}')\n", "not valid JSON"),
        ("print('FINAL_METRIC: [1, 2]')\n", "not a JSON object"),
        (
            'print("FINAL_METRIC: " + json.dumps({"run_id": args.run_id, "other": 1}))\n',
            "no primary metric 'score'",
        ),
        ('print("FINAL_METRIC: " + json.dumps({"run_id": args.run_id, "score": "high"}))\n', "not a number"),
        ('print("FINAL_METRIC: " + json.dumps({"run_id": args.run_id, "score": True}))\n', "not a number"),
        (
            'print("FINAL_METRIC: " + json.dumps({"run_id": args.run_id, "score": float("nan")}))\n',
            "not finite",
        ),
        ('print("FINAL_METRIC: " + json.dumps({"run_id": args.run_id, "score": 1e999}))\n', "not finite"),
        ('print("FINAL_METRIC: " + json.dumps({"run_id": "other", "score": 1}))\n', "run_id is 'other'"),
        (GOOD + "sys.exit(3)\n", "exited with code 3"),
    ],
)
def test_metric_line_must_be_exactly_one_valid_record(tmp_path, body, why):
    result = run(mini_family(tmp_path / "fam", body), tmp_path)
    assert result.status == "failed" and result.final_metric is None and why in result.reason


def test_good_mini_run_and_its_environment(tmp_path):
    body = (
        'print("FINAL_METRIC: " + json.dumps({"run_id": args.run_id, "score": X * 1.5, '
        '"cwd": os.getcwd(), "family": os.environ["FAMILY_DIR"], "seed": args.seed}))\n'
    )
    family = mini_family(tmp_path / "fam", body)
    result = run(family, tmp_path, {"X": 4})
    assert result.status == "ok" and result.metric == 6.0
    assert result.final_metric["cwd"] == str((tmp_path / "c" / "runs" / "r1").resolve())
    assert result.final_metric["family"] == str(family.path) and result.final_metric["seed"] == "3"


def test_timeout_kills_the_whole_process_group(tmp_path):
    body = (
        "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(300)'])\n"
        "open('child.pid', 'w').write(str(child.pid))\n"
        "time.sleep(300)\n"
    )
    family = mini_family(tmp_path / "fam", body)
    started = time.monotonic()
    result = run(family, tmp_path, timeout=1.0)
    assert result.status == "timeout" and "1 s wall-clock limit" in result.reason
    assert time.monotonic() - started < 10
    child = int((tmp_path / "c" / "runs" / "r1" / "child.pid").read_text())
    deadline = time.monotonic() + 5
    while alive(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not alive(child)


def test_children_left_behind_after_exit_are_killed(tmp_path):
    body = (
        "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(300)'])\n"
        "open('child.pid', 'w').write(str(child.pid))\n" + GOOD
    )
    result = run(mini_family(tmp_path / "fam", body), tmp_path)
    assert result.status == "ok"
    child = int((tmp_path / "c" / "runs" / "r1" / "child.pid").read_text())
    deadline = time.monotonic() + 5
    while alive(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not alive(child)


def test_orphan_of_a_dead_loop_is_killed_only_if_it_is_ours(tmp_path):
    run_dir, other = tmp_path / "runs" / "it0003", tmp_path / "elsewhere"
    run_dir.mkdir(parents=True)
    other.mkdir()
    sleeper = [sys.executable, "-c", "import time; time.sleep(300)"]
    mine = subprocess.Popen(sleeper, cwd=run_dir, start_new_session=True)
    stranger = subprocess.Popen(sleeper, cwd=other, start_new_session=True)
    try:
        (run_dir / "process.json").write_text(json.dumps({"pid": stranger.pid}))
        assert not stop_orphaned_run(run_dir)  # not started in this run dir: left alone
        assert stranger.poll() is None
        (run_dir / "process.json").write_text(json.dumps({"pid": mine.pid}))
        assert stop_orphaned_run(run_dir)
        assert mine.wait(timeout=5) == -9
    finally:
        for proc in (mine, stranger):
            if proc.poll() is None:
                os.killpg(proc.pid, 9)
                proc.wait()


def test_prepare_check(tmp_path):
    assert run_prepare_check(copy_toy(tmp_path)) is None
    broken = mini_family(
        tmp_path / "fam", GOOD, prepare="import sys; sys.exit('dataset cache missing: run --warm-cache')\n"
    )
    message = run_prepare_check(broken.path)
    assert "exit 1" in message and "dataset cache missing" in message


def test_parse_final_metric_ignores_other_output():
    out = 'epoch 1\nloss 0.3\nFINAL_METRIC: {"run_id": "a", "m": 2}\ndone\n'
    record, value, reason = parse_final_metric(out, "m", "a")
    assert reason is None and value == 2.0 and record == {"run_id": "a", "m": 2}
    assert parse_final_metric("  FINAL_METRIC: {}", "m", "a")[2] == "no FINAL_METRIC line on stdout"


def test_a_run_dir_is_used_once(tmp_path):
    family = mini_family(tmp_path / "fam", GOOD)
    run(family, tmp_path)
    with pytest.raises(FileExistsError):
        run(family, tmp_path)
