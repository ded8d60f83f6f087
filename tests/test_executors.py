"""Executors: serial, local pool and Ray give the same results; logs never interleave."""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
import time

import pytest
from audit_support import TOY_FAMILY, copy_family

from autoresearch.audit.trials import Trial, run_trials
from autoresearch.commands.common import add_executor_arguments, make_executor
from autoresearch.execution.executors import LocalExecutor
from autoresearch.journal import read_jsonl


def _square(x: int) -> int:
    time.sleep(0.01 * (5 - x))  # later tasks finish first
    return x * x


def test_local_pool_returns_results_in_task_order_and_reports_each_once():
    seen: list[tuple[int, int]] = []
    results = LocalExecutor(3).map(_square, [1, 2, 3, 4], on_result=lambda i, r: seen.append((i, r)))
    assert results == [1, 4, 9, 16]
    assert sorted(seen) == [(0, 1), (1, 4), (2, 9), (3, 16)]


def test_local_pool_runs_tasks_concurrently():
    active, peak, lock = [0], [0], threading.Lock()

    def task(_):
        with lock:
            active[0] += 1
            peak[0] = max(peak[0], active[0])
        time.sleep(0.05)
        with lock:
            active[0] -= 1

    LocalExecutor(2).map(task, range(4))
    assert peak[0] == 2


def test_workers_must_be_positive():
    with pytest.raises(ValueError, match="--workers must be >= 1"):
        LocalExecutor(0)


def test_flags_build_the_local_executor_by_default():
    parser = argparse.ArgumentParser()
    add_executor_arguments(parser)
    with make_executor(parser.parse_args(["--workers", "2"])) as executor:
        assert executor.name == "local" and executor.workers == 2


def _trials(config: dict) -> list[Trial]:
    return [Trial(f"t-s{seed}", config, seed) for seed in range(1, 7)]


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    return copy_family(TOY_FAMILY, tmp_path_factory.mktemp("toy") / "family")


@pytest.fixture(scope="module")
def serial_rows(toy, tmp_path_factory):
    root = tmp_path_factory.mktemp("serial")
    return run_trials(toy, _trials(toy.baseline_config), LocalExecutor(1), root / "log.jsonl", root, 60)


def _metrics(rows):
    return [(r.key, r.seed, r.scores.search) for r in rows]


def test_pool_results_are_identical_to_serial(toy, serial_rows, tmp_path):
    rows = run_trials(
        toy, _trials(toy.baseline_config), LocalExecutor(2), tmp_path / "log.jsonl", tmp_path, 60
    )
    assert _metrics(rows) == _metrics(serial_rows)
    assert all(r.ok for r in rows)
    # Six concurrent appenders: every line whole, one per run (train.py's own log too).
    assert sorted(r["key"] for r in read_jsonl(tmp_path / "log.jsonl")) == sorted(t.key for t in _trials({}))
    assert len(read_jsonl(tmp_path / "runs.jsonl")) == 6


def test_run_trials_skips_logged_runs_and_retries_failures(toy, tmp_path, capsys):
    bad = {**toy.baseline_config, "EPOCHS": 0}  # the toy family's failure mode
    trials = [Trial("good", toy.baseline_config, 1), Trial("bad", bad, 1)]
    rows = run_trials(toy, trials, LocalExecutor(2), tmp_path / "log.jsonl", tmp_path, 60)
    assert [r.status for r in rows] == ["ok", "failed"] and "EPOCHS" in rows[1].reason
    progress = capsys.readouterr().err.splitlines()
    assert progress[0] == "[log] 2 of 2 runs to do"
    assert [line.split()[1] for line in progress[1:]] == ["1/2", "2/2"]  # one line per run, as it ends
    assert sorted(line.split()[2] for line in progress[1:]) == ["bad", "good"]
    rows = run_trials(toy, trials, LocalExecutor(2), tmp_path / "log.jsonl", tmp_path, 60)
    logged = sorted(r["key"] for r in read_jsonl(tmp_path / "log.jsonl"))
    assert logged == ["bad", "bad", "good"]  # only the failure ran again
    progress = capsys.readouterr().err.splitlines()
    assert progress[0] == "[log] 1 of 2 runs to do"
    assert progress[1].startswith("[log] 2/2 bad failed")


def test_a_logged_key_counts_only_for_the_configuration_it_ran(toy, tmp_path):
    log = tmp_path / "log.jsonl"
    (first,) = run_trials(toy, [Trial("k", toy.baseline_config, 1)], LocalExecutor(1), log, tmp_path, 60)
    other = {**toy.baseline_config, "EPOCHS": 20}
    (second,) = run_trials(toy, [Trial("k", other, 1)], LocalExecutor(1), log, tmp_path, 60)
    assert second.config == other and second.scores.search != first.scores.search
    assert len(read_jsonl(log)) == 2


@pytest.mark.slow
def test_ray_results_are_identical_to_serial(ray_instance, toy, serial_rows, tmp_path):
    from autoresearch.execution.ray_executor import RayExecutor

    with RayExecutor(workers=2) as executor:
        assert executor.options == {"num_cpus": 1, "num_gpus": 0}  # no GPU on a CPU-only instance
        rows = run_trials(toy, _trials(toy.baseline_config), executor, tmp_path / "log.jsonl", tmp_path, 60)
    assert _metrics(rows) == _metrics(serial_rows)
    assert len(read_jsonl(tmp_path / "log.jsonl")) == 6


@pytest.mark.slow
@pytest.mark.needs("ray")
def test_sigterm_under_ray_exits_130_as_documented(toy, tmp_path):
    """ray.init installs a SIGTERM handler that exits 15; the executor puts ours back. A process of
    its own: the executor must start Ray itself for the test to mean anything."""
    out = tmp_path / "noise"
    cmd = [sys.executable, "-m", "autoresearch", "noise", "--family", str(toy.path), "--seeds", "2"]
    proc = subprocess.Popen(
        [*cmd, "--out", str(out), "--executor", "ray", "--workers", "1"],
        env={**os.environ, "TOY_SLEEP_S": "120"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    while not list(out.glob("*/remote.json")):
        assert time.monotonic() < deadline and proc.poll() is None, "no run started"
        time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err[-2000:]
    assert "interrupted; run the same command again to resume" in err
