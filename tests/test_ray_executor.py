"""Issue 27: Ray at full parity. Runs stream their PROGRESS to the driver's early-stop pruner, the
family travels to the workers and the runs' files come back (no shared filesystem), no train.py
outlives its task, and kill -9 of the driver then --resume loses and duplicates nothing, on a
two-node cluster whose worker node cannot see the campaign's or the family's directory."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from loop_helpers import ScriptedProposer, copy_toy, processes_naming, run_loop
from test_early_stop import SCRIPT, progress_family
from test_resume import check_trail

from autoresearch.journal import read_json, read_jsonl

pytestmark = [pytest.mark.slow, pytest.mark.needs("ray")]
SCRATCH = "autoresearch-it0"  # the prefix of a shipped run's scratch directory on its worker
RAY = str(Path(sys.executable).with_name("ray"))


@pytest.mark.parametrize("files", ["ship", "shared"])
def test_early_stop_under_ray_decides_as_a_local_loop_does(ray_instance, tmp_path, files):
    from autoresearch.execution.ray_executor import RayExecutor

    toy = progress_family(tmp_path)
    _, local = run_loop(
        toy, ScriptedProposer(list(SCRIPT)), tmp_path / "local", max_iters=6, early_stop="median"
    )
    with RayExecutor(workers=1, files=files) as executor:
        _, remote = run_loop(
            toy,
            ScriptedProposer(list(SCRIPT)),
            tmp_path / "ray",
            max_iters=6,
            early_stop="median",
            executor=executor,
        )
    assert processes_of(started_runs(tmp_path / "ray").values()) == []  # the pruned run's train.py too
    keys = ("status", "config", "metric", "verdict", "best_so_far")
    assert [[r[k] for k in keys] for r in remote] == [[r[k] for k in keys] for r in local]
    assert remote[5]["status"] == "early_stopped" and 1 <= len(remote[5]["progress"]) < 4
    assert [len(r["progress"]) for r in remote[:5]] == [4] * 5  # the curves came back whole
    for record in remote[:6]:
        run = tmp_path / "ray" / "runs" / record["run_id"]
        where = read_json(run / "remote.json")
        assert where["files"] == files and where["worker_pid"] != os.getpid()
        assert where["run_dir"] == str(run.resolve()) if files == "shared" else SCRATCH in where["run_dir"]
        assert {"train.py", "stdout.txt", "stderr.txt", "result.json"} <= {p.name for p in run.iterdir()}
        assert "PROGRESS:" in (run / "stdout.txt").read_text()
        if record["status"] == "ran":
            assert (run / "out" / "policy.json").is_file()  # the trained "policy" came back
    logged = [line["run_id"] for line in read_jsonl(tmp_path / "ray" / "runs.jsonl")]
    assert logged == [r["run_id"] for r in remote[:6] if r["status"] == "ran"]


def started_runs(root: Path, pattern: str = "runs/*/remote.json") -> dict[str, str]:
    """Run id -> the directory on its worker, of each run under ``root`` that started (remote.json)."""
    return {where.parent.name: read_json(where)["run_dir"] for where in root.glob(pattern)}


def processes_of(run_dirs) -> list[tuple[int, str]]:
    """The live processes of these runs: each train.py and its watchdog name the run's directory. Only
    these: the suite runs on both cores, and another test's runs may be ending beside this one's."""
    return [found for run_dir in run_dirs for found in processes_naming(run_dir)]


def trainers(run_dirs) -> list[tuple[int, str]]:
    return [(pid, cmd) for pid, cmd in processes_of(run_dirs) if " train.py " in cmd]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _node(args: list[str], env: dict[str, str], hide: Path | None = None) -> subprocess.Popen:
    """A Ray node in the foreground (``ray start --block``), in a session of its own. With ``hide``,
    in a mount namespace of its own where an empty tmpfs covers that directory: its tasks cannot see
    the campaign or the family (no shared filesystem)."""
    cmd = [RAY, "start", *args, "--disable-usage-stats", "--block"]
    if hide is not None:
        script = 'mount -t tmpfs tmpfs "$0" && exec "$@"'
        cmd = ["unshare", "--mount", "--propagation", "private", "sh", "-c", script, str(hide), *cmd]
    return subprocess.Popen(
        cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )


def _stop(node: subprocess.Popen) -> None:
    """What ``ray stop`` does to one node: every process it started goes."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(node.pid, sig)
        except ProcessLookupError:
            return
        try:
            node.wait(timeout=15)
            time.sleep(1)  # its raylet's children leave with it
        except subprocess.TimeoutExpired:
            continue


def _wait(predicate, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.1)


def _namespaces_work(tmp_path: Path) -> bool:
    probe = tmp_path / "probe"
    probe.mkdir()
    done = subprocess.run(
        ["unshare", "--mount", "--propagation", "private", "sh", "-c", f'mount -t tmpfs tmpfs "{probe}"'],
        capture_output=True,
    )
    return done.returncode == 0


def test_two_nodes_without_a_shared_filesystem_kill_9_and_resume(tmp_path):
    toy = copy_toy(tmp_path)
    # The baseline trains at once; every other configuration sleeps 300 s, unless its node says fast.
    train = toy / "train.py"
    baseline = '(config["EPOCHS"], config["LEARNING_RATE"]) == (10, 0.01)'
    slow = f'time.sleep(0.0 if os.environ.get("TOY_FAST") or {baseline} else 300.0)'
    train.write_text(
        train.read_text().replace('time.sleep(float(os.environ.get("TOY_SLEEP_S", "0")))', slow, 1)
    )
    campaign = tmp_path / "c"
    hide = tmp_path if _namespaces_work(tmp_path) else None  # else: the same checks, on one filesystem
    port = _free_port()
    address = f"127.0.0.1:{port}"
    # Loopback only: Ray's token authentication (on by default for `ray start --head`) is turned off.
    env = {**{k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}, "RAY_AUTH_MODE": "disabled"}
    nodes = [_node(["--head", f"--port={port}", "--num-cpus=0", "--include-dashboard=false"], env)]
    loop = [sys.executable, "-m", "autoresearch", "loop", "--campaign", str(campaign), "--plain"]
    ray_flags = ["--executor", "ray", "--ray-address", address, "--workers", "2"]
    try:
        nodes.append(_node([f"--address={address}", "--num-cpus=2"], env, hide))
        first = [*loop, "--family", str(toy), "--proposer", "random", "--max-iters", "4", *ray_flags]
        driver = subprocess.Popen(
            first, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
        )

        def started(n: int) -> bool:
            assert driver.poll() is None, f"the loop ended before {n} runs started"
            return len(list(campaign.glob("runs/*/remote.json"))) >= n

        def unfinished() -> list[str]:  # started on the worker, nothing back yet
            runs = started_runs(campaign)
            return [
                d for run_id, d in runs.items() if not (campaign / "runs" / run_id / "result.json").exists()
            ]

        def training(n: int) -> bool:  # n runs in flight, each with its train.py in a worker scratch dir
            dirs = unfinished()
            return len(dirs) == n and all(SCRATCH in d for d in dirs) and len(trainers(dirs)) == n

        _wait(lambda: started(3), 180, "two runs in flight on the worker node")  # the baseline, 2 slow ones
        _wait(lambda: training(2), 60, "the two slow runs' train.py (the baseline's ended)")
        # SIGKILL of a run's Ray worker: the run dies with it (its watchdog), and is recorded as failed.
        killed = read_json(campaign / "runs" / "it0002" / "remote.json")
        os.kill(killed["worker_pid"], signal.SIGKILL)
        _wait(lambda: not processes_naming(killed["run_dir"]), 30, "the run of the killed worker to stop")
        _wait(lambda: started(4), 60, "the loop to go on with iteration 4")
        (failed,) = [r for r in read_jsonl(campaign / "proposals.jsonl") if r["run_id"] == "it0002"]
        assert failed["status"] == "failed" and "Ray worker died" in failed["reason"]
        _wait(lambda: training(2), 60, "the train.py of it0003 and it0004")
        os.killpg(driver.pid, signal.SIGKILL)
        driver.wait()
        # No train.py outlives its task: the job's workers die with the driver, their runs with them.
        _wait(
            lambda: not processes_of(started_runs(campaign).values()),
            60,
            "the runs of the dead driver to stop",
        )
        in_flight = sorted(campaign.glob("runs/it000[34]/remote.json"))
        assert len(in_flight) == 2
        for where in in_flight:
            assert SCRATCH in read_json(where)["run_dir"]  # it trained in a scratch directory of the worker
            assert not (where.parent / "result.json").exists()  # and nothing came back from the killed task
        _stop(nodes.pop())  # "ray stop" of the worker node
        assert processes_of(started_runs(campaign).values()) == []

        nodes.append(_node([f"--address={address}", "--num-cpus=2"], {**env, "TOY_FAST": "1"}, hide))
        resumed = subprocess.run(
            [*loop, "--resume", *ray_flags], env=env, capture_output=True, text=True, timeout=300
        )
        assert resumed.returncode == 0, resumed.stderr[-3000:]
    finally:
        for node in reversed(nodes):
            _stop(node)
        current = Path(tempfile.gettempdir(), "ray", "ray_current_cluster")  # as `ray stop` leaves it
        if current.is_file() and current.read_text().strip().endswith(f":{port}"):
            current.unlink()
    records = check_trail(campaign, in_order=False)  # each iteration and run id once, runs.jsonl agrees
    assert sorted(r["iteration"] for r in records if r["status"] != "stopped") == [1, 2, 3, 4]
    rerun = [r for r in records if r.get("interrupted_run_ids")]
    assert len(rerun) == 2 and all(r["run_id"].endswith("-r2") for r in rerun)
    for record in records:
        if record["status"] == "ran":
            run = campaign / "runs" / record["run_id"]
            assert SCRATCH in read_json(run / "remote.json")["run_dir"]  # trained on the worker
            assert json.loads((run / "result.json").read_text())["status"] == "ok"
    assert processes_of(started_runs(campaign).values()) == [] and processes_naming(str(campaign)) == []
