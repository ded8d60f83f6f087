"""Issue 38, item 2: a run cannot forge the runner's result. train.py runs in its run directory,
where the runner saves result.json; a result.json the run wrote there is read back (after its
supervisor died) as untrusted input, and one that is not the runner's own, valid for this run, is a
lost result: the run is re-run, never recorded from it, and neither the loop nor the audit crashes."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time

import pytest
from loop_helpers import copy_toy
from test_resume import check_trail, processes_under

from autoresearch.execution.runner import saved_run
from autoresearch.execution.spec import RunSpec
from autoresearch.family import Family
from autoresearch.journal import read_json, read_jsonl

# Written by the first attempt of the second run, which then hangs until its loop is killed.
FORGE = """    if os.environ.get("FORGE") and CONFIG["EPOCHS"] != 10:
        Path("result.json").write_text(os.environ["FORGE"])
        time.sleep(300)
"""


def _final_metric(run_id: str, loss: float) -> dict:
    return {"run_id": run_id, "loss": loss, "feasible": True, "seed": 0, "config": {}}


FORGED = {
    "a foreign shape": {"loss": 0.5},
    "NaN, skipping the checks": {
        "status": "ok",
        "run_id": "it0002",
        "final_metric": _final_metric("it0002", 0.001),
        "reason": None,
        "wall_seconds": 1.0,
        "returncode": 0,
        "metric": math.nan,
    },
}


@pytest.mark.parametrize("forged", FORGED, ids=list(FORGED))
def test_a_result_json_written_by_the_run_is_not_adopted(tmp_path, forged):
    toy, campaign = copy_toy(tmp_path), tmp_path / "c"
    train = toy / "train.py"
    source = train.read_text()
    anchor = "    try:\n        result = train(CONFIG, args.seed)"
    train.write_text(source.replace(anchor, FORGE + anchor, 1))
    base = [sys.executable, "-m", "autoresearch", "loop", "--campaign", str(campaign), "--plain"]
    start = [*base, "--family", str(toy), "--proposer", "random", "--max-iters", "3", "--seed", "1"]
    env = {**os.environ, "FORGE": json.dumps(FORGED[forged], allow_nan=True)}
    proc = subprocess.Popen(start, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    forged_at = campaign / "runs" / "it0002" / "result.json"
    deadline = time.monotonic() + 60
    while not forged_at.exists():
        assert time.monotonic() < deadline and proc.poll() is None, "the run never wrote its result.json"
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)  # the supervisor dies; the run's own result.json is all there is
    proc.wait()

    done = subprocess.run([*base, "--resume"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    records = check_trail(campaign)
    second = records[1]
    assert second["run_id"] == "it0002-r2" and second["interrupted_run_ids"] == ["it0002"]  # re-run
    assert second["status"] == "ran" and math.isfinite(second["metric"]) and second["metric"] != 0.001
    assert [r["status"] for r in records] == ["ran", "ran", "ran", "stopped"]
    assert processes_under(campaign) == []


def _spec(tmp_path, run_id: str = "it0001") -> RunSpec:
    family = Family.load(copy_toy(tmp_path))
    run_dir = tmp_path / "runs" / run_id
    run_dir.mkdir(parents=True)
    return RunSpec(family, family.baseline_config, run_id, 0, run_dir, tmp_path / "runs.jsonl", 60)


def test_only_the_runners_own_result_of_this_run_is_read_back(tmp_path):
    spec = _spec(tmp_path)
    good = {
        "status": "ok",
        "run_id": "it0001",
        "final_metric": _final_metric("it0001", 0.25),
        "reason": None,
        "wall_seconds": 1.5,
        "returncode": 0,
        "metric": 0.25,
        "progress": [{"step": 1, "value": 0.5}],
    }
    failed = {**good, "status": "failed", "final_metric": None, "metric": None, "reason": "exit 1"}
    path = spec.run_dir / "result.json"
    legacy = {**{k: v for k, v in good.items() if k != "final_metric"}, "record": good["final_metric"]}
    for data, expected in [(good, 0.25), (failed, None), (legacy, 0.25)]:
        path.write_text(json.dumps(data))
        found = saved_run(spec)
        assert found is not None and found.metric == expected
    forged = [
        [1, 2],
        {"loss": 0.5},
        {**good, "run_id": "it0009"},
        {**good, "status": "done"},
        {**good, "metric": 0.001},  # not the FINAL_METRIC's
        {**good, "metric": math.nan},
        {**good, "final_metric": {**good["final_metric"], "loss": math.inf}, "metric": math.inf},
        {**good, "final_metric": "ok"},
        {**good, "final_metric": {**good["final_metric"], "run_id": "it0009"}},
        {**good, "final_metric": {**good["final_metric"], "eval_split": "test"}},
        {**good, "progress": [{"step": "1", "value": 0.5}]},
        {**good, "wall_seconds": "long"},
        {**good, "returncode": True},
        {**failed, "metric": 0.25},
    ]
    for data in forged:
        path.write_text(json.dumps(data))
        assert saved_run(spec) is None, data
    path.write_bytes(b"\xff{")
    assert saved_run(spec) is None
    path.unlink()
    assert saved_run(spec) is None


def test_the_audit_reruns_a_trial_whose_result_json_the_run_forged(tmp_path):
    toy = copy_toy(tmp_path)
    out = tmp_path / "noise"
    cmd = [sys.executable, "-m", "autoresearch", "noise", "--family", str(toy), "--seeds", "2"]
    cmd += ["--out", str(out)]
    proc = subprocess.Popen(
        cmd, env={**os.environ, "TOY_SLEEP_S": "300"}, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    deadline = time.monotonic() + 30
    while not list(out.glob("*/process.json")):
        assert time.monotonic() < deadline and proc.poll() is None
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    (run_dir,) = [p.parent for p in out.glob("*/process.json")]
    (run_dir / "result.json").write_text(json.dumps({"loss": 0.5}))  # what the hung train.py left
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    rows = read_jsonl(out / "noise.jsonl")
    assert [row["status"] for row in rows] == ["ok", "ok"]
    assert read_json(run_dir / "result.json")["status"] == "ok"  # the runner's own, this time
