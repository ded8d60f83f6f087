"""Resume after a crash at any moment: no record lost, none duplicated, the same state rebuilt."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from loop_helpers import ScriptedProposer, copy_toy, run_loop

from autoresearch.execution.executors import LocalExecutor
from autoresearch.execution.spec import NO_HOOKS
from autoresearch.journal import read_json, read_jsonl
from autoresearch.proposers.tpe import TPEProposer


class Crash(BaseException):
    """Stands in for kill -9: nothing after it runs."""


def processes_under(root: Path) -> list[int]:
    """Live processes whose working directory is inside ``root``."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if Path(os.readlink(entry / "cwd")).is_relative_to(root):
                    found.append(int(entry.name))
            except OSError:
                continue
    return found


def check_trail(campaign: Path, in_order: bool = True) -> list[dict]:
    """The invariants that must hold after any sequence of crashes and resumes (``in_order``
    False: runs were in flight side by side, records are in completion order)."""
    records = read_jsonl(campaign / "proposals.jsonl")
    iterations = [r["iteration"] for r in records]
    assert (iterations if in_order else sorted(iterations)) == list(range(1, len(records) + 1))
    run_ids = [r["run_id"] for r in records if r["run_id"]]
    assert len(run_ids) == len(set(run_ids))
    lost = [i for r in records for i in (r["interrupted_run_ids"] or [])]
    assert not set(lost) & set(run_ids)
    logged = [r["run_id"] for r in read_jsonl(campaign / "runs.jsonl")]
    assert len(logged) == len(set(logged))
    assert sorted(logged) == sorted(r["run_id"] for r in records if r["status"] == "ran")
    configs = [json.dumps(r["config"], sort_keys=True) for r in records if r["run_id"]]
    assert len(configs) == len(set(configs))
    for run_dir in (campaign / "runs").iterdir():
        assert run_dir.name in run_ids or (run_dir / "interrupted.json").exists()
    return records


def test_kill_9_of_a_running_loop_then_resume(tmp_path):
    toy, campaign = copy_toy(tmp_path), tmp_path / "c"
    base = [sys.executable, "-m", "autoresearch", "loop", "--campaign", str(campaign)]
    start = [
        *base,
        "--family",
        str(toy),
        "--proposer",
        "random",
        "--max-iters",
        "10",
        "--seed",
        "1",
        "--plain",
    ]
    resume = [*base, "--resume", "--plain"]
    slow = {**os.environ, "TOY_SLEEP_S": "0.3"}

    # Session 1: killed while a run is in flight (its train.py survives as an orphan).
    proc = subprocess.Popen(start, env=slow, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        done = len(read_jsonl(campaign / "proposals.jsonl"))
        if done >= 3 and (campaign / "runs" / f"it{done + 1:04d}" / "process.json").exists():
            break
        time.sleep(0.01)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert len(read_jsonl(campaign / "proposals.jsonl")) >= 3

    # Session 2: resumed, then killed again at an arbitrary moment once it is under way.
    proc = subprocess.Popen(resume, env=slow, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 30
    while len(read_json(campaign / "campaign.json")["sessions"]) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.5)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()

    # Session 3: resumed to the end.
    done = subprocess.run(resume, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    records = check_trail(campaign)
    assert len(records) == 11 and records[-1]["trigger"] == "max_iters"
    assert records[0]["proposer"] == "baseline"
    assert len(read_json(campaign / "campaign.json")["sessions"]) == 3
    assert processes_under(campaign) == []  # no orphaned training process left behind


def test_kill_9_with_several_runs_in_flight_then_resume(tmp_path):
    toy, campaign = copy_toy(tmp_path), tmp_path / "c"
    base = [sys.executable, "-m", "autoresearch", "loop", "--campaign", str(campaign), "--plain"]
    start = [*base, "--family", str(toy), "--proposer", "random", "--max-iters", "10", "--workers", "2"]
    proc = subprocess.Popen(
        start, env={**os.environ, "TOY_SLEEP_S": "1.0"}, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )

    def in_flight() -> list[str]:
        recorded = {r["run_id"] for r in read_jsonl(campaign / "proposals.jsonl")}
        runs = campaign / "runs"
        started = [d.name for d in runs.iterdir() if (d / "process.json").exists()] if runs.is_dir() else []
        return [run_id for run_id in started if run_id not in recorded]

    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if (campaign / "proposals.jsonl").exists() and len(read_jsonl(campaign / "proposals.jsonl")) >= 2:
            if len(in_flight()) == 2:
                break
        time.sleep(0.01)
    interrupted = in_flight()
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert len(interrupted) == 2

    done = subprocess.run([*base, "--resume"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert read_json(campaign / "campaign.json")["settings"]["workers"] == 2  # honoured on --resume
    records = check_trail(campaign, in_order=False)
    assert len(records) == 11 and records[-1]["trigger"] == "max_iters"
    recorded = [r["run_id"] for r in records if r["run_id"] is not None]  # stop records name no run
    lost = [i for r in records for i in (r["interrupted_run_ids"] or [])]
    for run_id in interrupted:  # adopted (it finished) or re-run exactly once under a new run id
        assert (run_id in recorded) != (run_id in lost)
        if run_id in lost:
            assert sum(r.startswith(run_id + "-r") for r in recorded) == 1
    assert processes_under(campaign) == []


def test_a_runs_log_line_is_adopted_only_with_the_intents_config_and_seed(tmp_path):
    toy, campaign = copy_toy(tmp_path), tmp_path / "c"
    crash_at_it0003(toy, campaign, "before", max_iters=4)
    intent = read_json(campaign / "runs" / "it0003" / "intent.json")
    forged = [
        {
            "run_id": "it0003",
            "loss": 0.0,
            "feasible": True,
            "seed": 0,
            "config": {**intent["config"], "EPOCHS": 13},
        },
        {"run_id": "it0003", "loss": 0.0, "feasible": True, "seed": 7, "config": intent["config"]},
    ]
    with open(campaign / "runs.jsonl", "a") as log:
        log.writelines(json.dumps(line) + "\n" for line in forged)
    _, records = run_loop(toy, ScriptedProposer([]), campaign, max_iters=3)
    third = records[2]
    assert third["run_id"] == "it0003-r2" and third["interrupted_run_ids"] == ["it0003"]
    assert third["status"] == "ran" and third["metric"] != 0.0


def test_a_campaign_resumed_with_a_larger_cap_runs_up_to_it(tmp_path):
    toy, campaign = copy_toy(tmp_path), tmp_path / "c"
    run_loop(toy, ScriptedProposer([{"EPOCHS": 11}, {"EPOCHS": 12}]), campaign, max_iters=3)
    outcome, records = run_loop(
        toy, ScriptedProposer([{"EPOCHS": 13}, {"EPOCHS": 14}]), campaign, max_iters=5
    )
    # the first session's stop record keeps its number but is not one of the five iterations
    assert [r["status"] for r in records] == ["ran"] * 3 + ["stopped"] + ["ran"] * 2 + ["stopped"]
    assert [r["iteration"] for r in records] == list(range(1, 8))
    assert [r["config"]["EPOCHS"] for r in records if r["status"] == "ran"][1:] == [11, 12, 13, 14]
    assert outcome.iterations == 5 and records[-1]["reason"] == "5 iterations reached the cap of 5"


def crash_at_it0003(toy: Path, campaign: Path, when: str, max_iters: int) -> None:
    """A scripted campaign whose loop dies around its third run (CrashingExecutor)."""
    with pytest.raises(Crash):
        proposer = ScriptedProposer([{"EPOCHS": 11}, {"EPOCHS": 12}])
        run_loop(toy, proposer, campaign, max_iters=max_iters, executor=CrashingExecutor("it0003", when))


class CrashingExecutor(LocalExecutor):
    """Makes the loop die around the run ``run_id``: before it starts, or after it finished."""

    def __init__(self, run_id: str, when: str):
        super().__init__()
        self.run_id, self.when = run_id, when

    def run(self, spec, hooks=NO_HOOKS):
        if spec.run_id != self.run_id:
            return super().run(spec, hooks)
        if self.when == "before, orphan alive":
            # A train.py that outlived its supervisor, still running in the run dir.
            sleeper = subprocess.Popen(
                [sys.executable, "-c", "import time; time.sleep(300)"],
                cwd=spec.run_dir,
                start_new_session=True,
            )
            (spec.run_dir / "process.json").write_text(json.dumps({"pid": sleeper.pid}))
        if self.when.startswith("after"):
            super().run(spec, hooks)
            if self.when == "after, before result.json":
                (spec.run_dir / "result.json").unlink()
        raise Crash


@pytest.mark.parametrize("when", ["after", "after, before result.json", "before", "before, orphan alive"])
def test_an_iteration_in_flight_is_adopted_or_rerun(tmp_path, when):
    toy, campaign = copy_toy(tmp_path), tmp_path / "c"
    crash_at_it0003(toy, campaign, when, max_iters=5)
    with open(campaign / "proposals.jsonl", "ab") as f:
        f.write(b'{"iteration": 3, "status": "ra')  # and a torn line from a crash mid-append
    resumed = ScriptedProposer([{"EPOCHS": 11}, {"EPOCHS": 13}])
    _, records = run_loop(toy, resumed, campaign, max_iters=5)
    check_trail(campaign)
    assert [r["status"] for r in records] == ["ran", "ran", "ran", "invalid", "ran", "stopped"]
    third = records[2]
    if when.startswith("after"):
        assert third["run_id"] == "it0003" and third["interrupted_run_ids"] == []  # adopted
    else:
        assert third["run_id"] == "it0003-r2" and third["interrupted_run_ids"] == ["it0003"]  # re-run
        assert (campaign / "runs" / "it0003" / "interrupted.json").exists()
    assert third["config"]["EPOCHS"] == 12
    # The rebuilt state remembers what ran before the crash.
    assert records[3]["reason"] == "this override map was already run at iteration 2"
    assert [t[0]["EPOCHS"] for t in resumed.tells] == [10, 11, 12, 13]
    assert (campaign / "proposals.jsonl.torn").read_bytes() == b'{"iteration": 3, "status": "ra\n'
    assert processes_under(campaign) == []


def test_tpe_resumed_after_a_crash_asks_what_it_would_have(tmp_path):
    toy = copy_toy(tmp_path)
    registry = json.loads((toy / "family.json").read_text())
    _, straight = run_loop(
        toy, TPEProposer(registry, seed=2), tmp_path / "straight", max_iters=12, plateau_window=50
    )
    with pytest.raises(Crash):
        run_loop(
            toy,
            TPEProposer(registry, seed=2),
            tmp_path / "crashed",
            max_iters=12,
            plateau_window=50,
            executor=CrashingExecutor("it0012", "before"),
        )
    _, resumed = run_loop(
        toy, TPEProposer(registry, seed=2), tmp_path / "crashed", max_iters=12, plateau_window=50
    )
    assert [r["config"] for r in resumed] == [r["config"] for r in straight]
    assert [r["metric"] for r in resumed] == [r["metric"] for r in straight]


def test_crash_windows_around_a_retry_and_before_an_intent(tmp_path):
    toy, campaign = copy_toy(tmp_path), tmp_path / "c"
    crash_at_it0003(toy, campaign, "before", max_iters=5)
    # The loop died again right after writing the retry's intent, before marking it0003 interrupted.
    intent = read_json(campaign / "runs" / "it0003" / "intent.json")
    (campaign / "runs" / "it0003-r2").mkdir()
    retry = {**intent, "run_id": "it0003-r2", "interrupted_run_ids": ["it0003"]}
    (campaign / "runs" / "it0003-r2" / "intent.json").write_text(json.dumps(retry))
    # ... and a crash between creating a run dir and writing its intent left it empty.
    (campaign / "runs" / "it0004").mkdir()
    _, records = run_loop(toy, ScriptedProposer([{"EPOCHS": 13}]), campaign, max_iters=5)
    check_trail(campaign)
    assert [r["run_id"] for r in records] == ["it0001", "it0002", "it0003-r3", "it0004", None, None]
    assert records[2]["interrupted_run_ids"] == ["it0003", "it0003-r2"]
    assert "superseded" in read_json(campaign / "runs" / "it0003" / "interrupted.json")["reason"]
    assert "re-run as it0003-r3" in read_json(campaign / "runs" / "it0003-r2" / "interrupted.json")["reason"]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_an_audit_command_stopped_by_a_signal_leaves_no_run_behind(tmp_path, sig):
    toy = copy_toy(tmp_path)
    out = tmp_path / "noise"
    cmd = [sys.executable, "-m", "autoresearch", "noise", "--family", str(toy), "--seeds", "4"]
    slow = {**os.environ, "TOY_SLEEP_S": "60"}
    proc = subprocess.Popen(
        [*cmd, "--workers", "2", "--out", str(out)],
        env=slow,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    deadline = time.monotonic() + 30
    while len(list(out.glob("*/process.json"))) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert len(list(out.glob("*/process.json"))) == 2  # two runs in flight, each in its own session
    time.sleep(0.5)
    proc.send_signal(sig)
    _, stderr = proc.communicate(timeout=20)
    assert proc.returncode == 130 and b"run the same command again to resume" in stderr
    assert processes_under(out) == []  # both training processes were killed with the command
