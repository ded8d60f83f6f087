"""SIGTERM under Ray cancels the runs in flight instead of waiting for them (issue 29, item 6)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from loop_helpers import copy_toy, processes_naming
from test_ray_executor import processes_of, started_runs


@pytest.mark.slow
@pytest.mark.needs("ray")
@pytest.mark.parametrize("command", ["loop", "noise"])
def test_sigterm_under_ray_cancels_the_runs_in_flight(tmp_path, command):
    toy, out = copy_toy(tmp_path), tmp_path / "out"
    cmd = [sys.executable, "-m", "autoresearch", command, "--family", str(toy), "--executor", "ray"]
    cmd += ["--workers", "2"]
    if command == "loop":
        cmd += ["--proposer", "random", "--max-iters", "3", "--campaign", str(out), "--plain"]
        started = "runs/*/remote.json"
    else:
        cmd += ["--seeds", "2", "--out", str(out)]
        started = "*/remote.json"  # written by the driver once the task reports its run started
    proc = subprocess.Popen(
        cmd,
        env={**os.environ, "TOY_SLEEP_S": "300"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120
        while len(list(out.glob(started))) < 2:
            assert time.monotonic() < deadline and proc.poll() is None, "no two runs started"
            time.sleep(0.1)
        time.sleep(0.5)
        proc.send_signal(signal.SIGTERM)
        sent = time.monotonic()
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 130, err[-2000:]
        assert time.monotonic() - sent < 30  # not the 300 s the runs would take
        # both train.py (in scratch directories of the worker) and their watchdogs are gone
        assert processes_naming(str(out)) == [] and processes_of(started_runs(out, started).values()) == []
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        left = processes_naming(str(out)) + processes_of(started_runs(out, started).values())
        for pid, _ in left:  # what a failure left behind
            os.kill(pid, signal.SIGKILL)
