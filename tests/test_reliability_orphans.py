"""No orphan writes beside a re-run: a run is tracked by its run directory in its processes'
environment, whatever it does with its working directory or session, and its deadline holds without
a live loop (issue 29, item 4). The train.py here leaves its run directory and starts a grandchild
that calls setsid; the loop and the audit are killed with kill -9 while such runs are in flight."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from audit_support import ScriptedProposer, run_campaign
from loop_helpers import copy_toy, processes_naming

from autoresearch.execution import tracking
from autoresearch.execution.runner import run_locally
from autoresearch.execution.spec import RunSpec
from autoresearch.family import Family
from autoresearch.journal import read_json, read_jsonl

# Inserted at the top of the toy train.py's main(): with TOY_ESCAPE set, a grandchild leaves the
# session (os.setsid) and sleeps, and train.py itself moves to the TOY_ESCAPE directory.
_ESCAPE = """    if os.environ.get("TOY_ESCAPE"):
        import subprocess

        sleeper = "import os, time; os.setsid(); time.sleep(300)"
        subprocess.Popen([sys.executable, "-c", sleeper, "setsid-grandchild", os.environ["TOY_ESCAPE"]])
        os.chdir(os.environ["TOY_ESCAPE"])
"""


def _escaping_toy(tmp_path: Path) -> Path:
    toy = copy_toy(tmp_path)
    source = (toy / "train.py").read_text()
    anchor = "    args = parser.parse_args()\n"
    (toy / "train.py").write_text(source.replace(anchor, anchor + _ESCAPE, 1))
    (tmp_path / "elsewhere").mkdir()
    return toy


def _wait_until(condition, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


@pytest.fixture
def escape(tmp_path):
    """The environment of a run that escapes; afterwards, whatever a failing test left is killed."""
    yield {**os.environ, "TOY_ESCAPE": str(tmp_path / "elsewhere")}
    for pid, _ in processes_naming(str(tmp_path)):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def _grandchildren(tmp_path: Path) -> list:
    return [p for p in processes_naming(str(tmp_path)) if "setsid-grandchild" in p[1]]


def _leftovers(tmp_path: Path, settle_s: float = 10.0) -> list[tuple[int, str]]:
    """What is still running of ``tmp_path``'s runs once ``settle_s`` has passed without a change."""
    deadline = time.monotonic() + settle_s
    while processes_naming(str(tmp_path)) and time.monotonic() < deadline:
        time.sleep(0.05)
    return processes_naming(str(tmp_path))


def _loop(campaign: Path, *args: str) -> list[str]:
    return [sys.executable, "-m", "autoresearch", "loop", "--campaign", str(campaign), "--plain", *args]


def _in_flight(campaign: Path) -> list[str]:
    recorded = {r["run_id"] for r in read_jsonl(campaign / "proposals.jsonl")}
    runs = campaign / "runs"
    started = [d.name for d in runs.iterdir() if (d / "process.json").exists()] if runs.is_dir() else []
    return [run_id for run_id in started if run_id not in recorded]


def _kill_9(proc: subprocess.Popen) -> float:
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    return time.monotonic()


def test_a_setsid_grandchild_does_not_survive_its_run(tmp_path, escape, monkeypatch):
    toy = _escaping_toy(tmp_path)
    monkeypatch.setenv("TOY_ESCAPE", escape["TOY_ESCAPE"])
    family = Family.load(toy)
    run_dir = tmp_path / "runs" / "r1"
    result = run_locally(
        RunSpec(family, family.baseline_config, "r1", 0, run_dir, tmp_path / "runs.jsonl", 60)
    )
    assert result.ok, result.reason
    assert _leftovers(tmp_path, settle_s=5) == []  # the grandchild and the watchdog are gone too
    info = read_json(run_dir / "process.json")
    assert info["start_time"] > 0 and info["deadline"] > time.time() - 60 and info["timeout"] == 60


def test_without_a_loop_a_finished_run_takes_its_setsid_grandchild_along(tmp_path, escape):
    toy, campaign = _escaping_toy(tmp_path), tmp_path / "c"
    start = _loop(campaign, "--family", str(toy), "--proposer", "random", "--max-iters", "3")
    proc = subprocess.Popen(
        start, env={**escape, "TOY_SLEEP_S": "2"}, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    _wait_until(lambda: _in_flight(campaign) == ["it0001"] and _grandchildren(tmp_path), 60, "the run")
    _kill_9(proc)
    # train.py ends on its own 2 s later; its watchdog then kills the grandchild, and exits
    assert _leftovers(tmp_path, settle_s=20) == []
    assert [line["run_id"] for line in read_jsonl(campaign / "runs.jsonl")] == ["it0001"]
    assert not (campaign / "runs" / "it0001" / tracking.WATCHDOG_FILE).exists()  # no timeout


def test_kill_9_of_the_loop_with_escaping_runs_in_flight_then_resume(tmp_path, escape):
    toy, campaign = _escaping_toy(tmp_path), tmp_path / "c"
    start = _loop(
        campaign, "--family", str(toy), "--proposer", "random", "--max-iters", "4", "--workers", "2"
    )
    proc = subprocess.Popen(
        start, env={**escape, "TOY_SLEEP_S": "4"}, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    _wait_until(
        lambda: len(_in_flight(campaign)) == 2 and len(_grandchildren(tmp_path)) == 2,
        60,
        "two runs in flight",
    )
    interrupted = _in_flight(campaign)
    killed_at = _kill_9(proc)

    done = subprocess.run(
        _loop(campaign, "--resume"), env=escape, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    time.sleep(max(0.0, killed_at + 6 - time.monotonic()))  # an orphan left alive would have logged by now
    records = read_jsonl(campaign / "proposals.jsonl")
    ran = sorted(r["run_id"] for r in records if r["status"] == "ran")
    logged = sorted(line["run_id"] for line in read_jsonl(campaign / "runs.jsonl"))
    assert logged == ran  # exactly one line per run, none from an orphan
    lost = [i for r in records for i in r["interrupted_run_ids"] or []]
    assert sorted(lost) == sorted(interrupted) and sorted(r for r in ran if "-r" in r) == [
        f"{i}-r2" for i in sorted(interrupted)
    ]
    assert _leftovers(tmp_path) == []


def _start_a_hung_run(tmp_path: Path, escape: dict) -> tuple[Path, subprocess.Popen]:
    """A loop of one run that sleeps 300 s (with a setsid grandchild) under --timeout-per-run 3."""
    toy, campaign = _escaping_toy(tmp_path), tmp_path / "c"
    start = _loop(campaign, "--family", str(toy), "--proposer", "random", "--max-iters", "1")
    proc = subprocess.Popen(
        [*start, "--timeout-per-run", "3"],
        env={**escape, "TOY_SLEEP_S": "300"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    return campaign, proc


def test_a_hung_run_does_not_outlive_its_timeout_without_a_loop(tmp_path, escape):
    campaign, proc = _start_a_hung_run(tmp_path, escape)
    _wait_until(lambda: _in_flight(campaign) == ["it0001"] and _grandchildren(tmp_path), 60, "the run")
    killed_at = _kill_9(proc)
    # No loop: the run's watchdog kills it, grandchild included, 3 s + its grace after it started.
    assert _leftovers(tmp_path, settle_s=30) == []
    assert time.monotonic() - killed_at > 3
    assert (campaign / "runs" / "it0001" / tracking.WATCHDOG_FILE).exists()

    done = subprocess.run(
        _loop(campaign, "--resume"), env=escape, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    first = read_jsonl(campaign / "proposals.jsonl")[0]
    assert first["run_id"] == "it0001" and first["interrupted_run_ids"] == []  # recorded, not re-run
    assert first["status"] == "failed" and first["run_status"] == "timeout"
    assert "3 s wall-clock limit" in first["reason"] and "watchdog" in first["reason"]


def test_a_run_past_its_deadline_at_resume_is_killed_and_timed_out(tmp_path, escape):
    campaign, proc = _start_a_hung_run(tmp_path, escape)
    run_dir = (campaign / "runs" / "it0001").resolve()
    _wait_until(
        lambda: tracking.processes(run_dir, tracking.WATCHDOG_ENV) and _grandchildren(tmp_path), 60, "run"
    )
    _kill_9(proc)
    (watchdog,) = tracking.processes(run_dir, tracking.WATCHDOG_ENV)
    os.kill(watchdog, signal.SIGKILL)  # as if it had died too: only the resume can stop the run now
    deadline = read_json(run_dir / "process.json")["deadline"]
    time.sleep(max(0.0, deadline + 0.5 - time.time()))
    assert len(tracking.processes(run_dir)) == 2  # train.py and its grandchild, both past the deadline

    done = subprocess.run(
        _loop(campaign, "--resume"), env=escape, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    first = read_jsonl(campaign / "proposals.jsonl")[0]
    assert first["run_id"] == "it0001" and first["status"] == "failed" and first["run_status"] == "timeout"
    assert "still running past its 3 s wall-clock limit at resume" in first["reason"]
    assert _leftovers(tmp_path) == []


def test_kill_9_of_the_audit_with_escaping_runs_in_flight_then_rerun(tmp_path, escape):
    toy = _escaping_toy(tmp_path)
    family = Family.load(toy)
    campaign = run_campaign(family, tmp_path / "c", ScriptedProposer([{"EPOCHS": 30}]), iterations=2)
    registry = json.loads((toy / "family.json").read_text())
    registry["seed_noise"] = {"mean": 0.86, "std": 0.01, "k": 4, "seeds": [1, 2, 3, 4]}
    (toy / "family.json").write_text(json.dumps(registry))
    verify = [sys.executable, "-m", "autoresearch", "verify", "--campaign", str(campaign), "--top", "1"]
    verify += ["--seeds", "4", "--workers", "2"]
    root = campaign / "audit" / "verify"

    def in_flight() -> list[str]:
        done = {row["key"] for row in read_jsonl(root / "verify.jsonl")} if root.is_dir() else set()
        started = [d.name for d in root.iterdir() if (d / "process.json").exists()] if root.is_dir() else []
        return [key for key in started if key not in done]

    proc = subprocess.Popen(
        verify, env={**escape, "TOY_SLEEP_S": "4"}, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    _wait_until(lambda: len(in_flight()) == 2 and len(_grandchildren(tmp_path)) == 2, 60, "two trials")
    killed_at = _kill_9(proc)

    done = subprocess.run(verify, env=escape, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    time.sleep(max(0.0, killed_at + 6 - time.monotonic()))  # an orphan left alive would have logged by now
    logged = [line["run_id"] for line in read_jsonl(root / "runs.jsonl")]
    rows = [row for row in read_jsonl(root / "verify.jsonl") if row["status"] == "ok"]
    assert len(logged) == len(set(logged)) and sorted(logged) == sorted(row["run_id"] for row in rows)
    assert _leftovers(tmp_path) == []
