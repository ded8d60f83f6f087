"""Issue 38, items 1, 9 and 10: what ``--ray-files ship`` sends, runs and brings back. The family a
task runs is its own private copy (nothing planted in a shared cache runs), the files shipped are
sized before they are read and links treated as a local run treats them, a run's outputs stream
back (a sparse file stays sparse, the driver holds one chunk at a time), and a runs.jsonl line
without its newline is handled as a local loop handles it."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from loop_helpers import ScriptedProposer, copy_toy, run_loop

from autoresearch.execution.executors import ExecutorError
from autoresearch.execution.ray_executor import MAX_SHIPPED_BYTES, _digest, family_files
from autoresearch.execution.spec import RunSpec
from autoresearch.family import Family
from autoresearch.journal import read_jsonl

FINAL_LINE = 'print(f"FINAL_METRIC: {line}", flush=True)'


def _edit(toy: Path, old: str, new: str) -> None:
    train = toy / "train.py"
    source = train.read_text()
    assert old in source
    train.write_text(source.replace(old, new, 1))


def _spec(family: Family, tmp_path: Path, run_id: str = "it0001") -> RunSpec:
    return RunSpec(
        family, family.baseline_config, run_id, 0, tmp_path / "runs" / run_id, tmp_path / "runs.jsonl", 60
    )


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


@pytest.mark.slow
@pytest.mark.needs("ray")
def test_a_planted_or_damaged_family_copy_is_never_run(ray_instance, tmp_path):
    from autoresearch.execution.ray_executor import RayExecutor

    toy = copy_toy(tmp_path)
    # The run says whether the family it ran from lies in a directory only this user can enter.
    private = (
        'record["private"] = any(os.stat(p).st_mode & 0o077 == 0 and os.stat(p).st_uid == os.getuid() '
        'for p in Path(os.environ["FAMILY_DIR"]).parents)\n    line = json.dumps(record)'
    )
    _edit(toy, "line = json.dumps(record)", private)
    family = Family.load(toy)
    # Where a worker used to keep its shared copy: a changed train.py and a missing file planted there.
    shared = Path(tempfile.gettempdir()) / "autoresearch-families" / _digest(family_files(family)) / "toy"
    shared.parent.mkdir(parents=True, exist_ok=True)
    try:
        copy_toy(shared.parent)
        _edit(shared, "        result = train(CONFIG, args.seed)", '        result = {"loss": 0.001}')
        (shared / "program.md").unlink()
        with RayExecutor(workers=1) as executor:
            result = executor.run(_spec(family, tmp_path))
    finally:
        subprocess.run(["rm", "-rf", str(shared.parent)], check=True)
    assert result.ok, result.reason
    assert result.metric != 0.001 and result.final_metric["private"] is True


def test_ship_follows_links_as_a_local_run_does(tmp_path):
    toy = copy_toy(tmp_path)
    data = tmp_path / "data"
    data.mkdir()
    (data / "table.csv").write_text("1,2\n")
    (toy / "data").symlink_to(data)  # a linked directory: a local run reads through it
    (toy / "weights.bin").symlink_to(data / "table.csv")  # a linked file
    (toy / "gone.txt").symlink_to(tmp_path / "nothing")  # dangling: absent for a local run too
    (data / "loop").symlink_to(data)  # a cycle is walked once
    files = family_files(Family.load(toy))
    assert files["data/table.csv"] == files["weights.bin"] == b"1,2\n"
    assert "gone.txt" not in files and not any(name.startswith("data/loop") for name in files)


def test_ship_refuses_a_special_file_in_one_line(tmp_path):
    toy = copy_toy(tmp_path)
    os.mkfifo(toy / "pipe")  # reading it would wait forever
    with pytest.raises(ExecutorError, match=r"pipe: not a regular file \(a FIFO\)") as err:
        family_files(Family.load(toy))
    assert "\n" not in str(err.value)


def test_ship_sizes_a_family_before_reading_it(tmp_path):
    toy = copy_toy(tmp_path)
    big = tmp_path / "big.bin"
    with open(big, "wb") as f:
        f.truncate(4 * MAX_SHIPPED_BYTES)  # sparse: nothing to write, 256 MB to read
    (toy / "big.bin").symlink_to(big)
    before = _peak_mb()
    with pytest.raises(ExecutorError, match="MB of files to send to every Ray worker") as err:
        family_files(Family.load(toy))
    assert "\n" not in str(err.value)
    assert _peak_mb() - before < 64  # refused from its size, never read


@pytest.mark.slow
@pytest.mark.needs("ray")
def test_a_shipped_runs_sparse_output_comes_back_sparse_a_chunk_at_a_time(ray_instance, tmp_path):
    from autoresearch.execution.ray_executor import RayExecutor

    toy = copy_toy(tmp_path)
    size = 300 * 2**20
    sparse = f'with open(out / "sparse.bin", "wb") as f:\n        f.truncate({size})\n    {FINAL_LINE}'
    _edit(toy, FINAL_LINE, sparse)
    family = Family.load(toy)
    before = _peak_mb()
    with RayExecutor(workers=1) as executor:
        result = executor.run(_spec(family, tmp_path))
    assert result.ok, result.reason
    back = tmp_path / "runs" / "it0001" / "out" / "sparse.bin"
    assert back.stat().st_size == size and back.stat().st_blocks * 512 < 2**20  # still a hole
    assert (back.parent / "policy.json").is_file()
    assert _peak_mb() - before < 100  # not the 300 MB held at once


@pytest.mark.slow
@pytest.mark.needs("ray")
def test_a_runs_log_line_without_its_newline_under_ray_as_locally(ray_instance, tmp_path):
    from autoresearch.execution.ray_executor import RayExecutor

    toy = copy_toy(tmp_path)
    _edit(toy, 'log.write(line + "\\n")', "log.write(line)")  # the family bug: no newline
    script = [{"EPOCHS": 20}, {"EPOCHS": 25}]
    _, local = run_loop(toy, ScriptedProposer(list(script)), tmp_path / "local", max_iters=3)
    with RayExecutor(workers=1) as executor:
        _, remote = run_loop(
            toy, ScriptedProposer(list(script)), tmp_path / "ray", max_iters=3, executor=executor
        )
    keys = ("status", "config", "metric")
    assert [[r.get(k) for k in keys] for r in remote] == [[r.get(k) for k in keys] for r in local]
    assert [r["status"] for r in remote] == ["ran", "ran", "ran", "stopped"]
    assert read_jsonl(tmp_path / "ray" / "runs.jsonl") == []  # no line was whole
    torn = (tmp_path / "ray" / "runs.jsonl.torn").read_text().splitlines()
    assert [line.split(",")[0] for line in torn] == [f'{{"run_id": "it000{i}"' for i in (1, 2, 3)]


@pytest.mark.slow
@pytest.mark.needs("ray")
def test_the_loop_refuses_a_family_with_a_fifo_under_ray_in_one_line(tmp_path):
    toy = copy_toy(tmp_path)
    os.mkfifo(toy / "pipe")
    cmd = [sys.executable, "-m", "autoresearch", "loop", "--family", str(toy), "--proposer", "random"]
    cmd += ["--max-iters", "2", "--campaign", str(tmp_path / "c"), "--plain", "--executor", "ray"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    assert done.returncode == 2, done.stderr[-2000:]
    assert "pipe: not a regular file (a FIFO)" in done.stderr and "Traceback" not in done.stderr
