"""A run's stdout is read in bounded memory: the loop keeps the protocol lines (FINAL_METRIC, PROGRESS)
and never re-reads ``\\r`` progress, whatever a train.py prints (issue 29, item 6)."""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
import textwrap

import pytest
from loop_helpers import copy_toy

from autoresearch.execution.protocol import MAX_LINE, MAX_POINTS, StdoutReader, read_final_metric

# train.py of the toy copy: TOY_SPAM=lines:N prints N MB of short lines, cr:N prints N MB of
# carriage-return progress without a newline, err:N prints N MB to stderr and fails; a PROGRESS point
# sits in the middle of the spam, the FINAL_METRIC line comes last. points:N prints N PROGRESS points.
_SPAM = """    spam = os.environ.get("TOY_SPAM")
    if spam and spam.startswith("points:"):
        for i in range(int(spam.split(":")[1])):
            sys.stdout.write(f'PROGRESS: {{"step": {i}, "loss": {1 / (1 + i)}}}\\n')
        sys.stdout.flush()
    elif spam:
        kind, mb = spam.split(":")
        if kind == "lines":
            chunk = ("x" * 63 + "\\n") * 16384
        else:
            chunk = "".join(f"\\rstep {i:09d} of the epoch, loss 0.1234567" for i in range(20000))
        stream = sys.stderr if kind == "err" else sys.stdout
        n = int(mb) * 2**20 // len(chunk)
        for i in range(n):
            stream.write(chunk)
            if i == n // 2:
                stream.write('\\nPROGRESS: {"step": 7, "loss": 0.25}\\n')
        stream.flush()
        if kind == "err":
            return 3
        print(flush=True)
    line = json.dumps(record)
"""

_DRIVER = textwrap.dedent(
    """
    import json, os, sys
    from pathlib import Path
    from autoresearch.family import Family
    from autoresearch.execution.runner import run_locally
    from autoresearch.execution.spec import RunSpec

    def peak_kb():
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])

    family = Family.load(sys.argv[1])
    tmp = Path(sys.argv[2])
    warm = run_locally(RunSpec(family, family.baseline_config, "warm", 0, tmp / "warm", tmp / "runs.jsonl", 120))
    assert warm.ok, warm
    os.environ["TOY_SPAM"] = sys.argv[3]  # the warm-up run printed nothing
    before = peak_kb()
    result = run_locally(RunSpec(family, family.baseline_config, "r", 0, tmp / "r", tmp / "runs.jsonl", 120))
    print(json.dumps({"growth_mb": (peak_kb() - before) / 1024, "status": result.status,
                      "progress": result.progress, "metric": result.metric, "reason": result.reason}))
    for name in ("stdout.txt", "stderr.txt"):  # tens of MB each
        (tmp / "r" / name).unlink()
    """
)


def _spam_toy(tmp_path):
    toy = copy_toy(tmp_path)
    source = (toy / "train.py").read_text()
    (toy / "train.py").write_text(source.replace("    line = json.dumps(record)\n", _SPAM, 1))
    return toy


def _drive(tmp_path, spam: str) -> dict:
    toy = _spam_toy(tmp_path)
    proc = subprocess.run(
        [sys.executable, "-c", _DRIVER, str(toy), str(tmp_path), spam],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("spam", ["lines:64", "cr:32"])
def test_a_run_printing_a_lot_does_not_grow_the_loops_memory(tmp_path, spam):
    out = _drive(tmp_path, spam)
    assert out["status"] == "ok", out["reason"]
    assert out["progress"] == [{"step": 7, "value": 0.25}] and out["metric"] is not None
    assert out["growth_mb"] < 16, out  # 32-64 MB of output grew it by over 160 MB when read whole


def test_a_huge_stderr_is_read_only_for_its_tail(tmp_path):
    out = _drive(tmp_path, "err:64")
    assert out["status"] == "failed" and out["reason"].startswith("train.py exited with code 3: ...")
    assert len(out["reason"]) < 1000
    assert out["growth_mb"] < 16, out


def test_the_reader_keeps_protocol_lines_across_blocks_and_line_ends(tmp_path):
    path = tmp_path / "stdout.txt"
    heard = []
    reader = StdoutReader(path, "loss", lambda step, value: heard.append(step) or False)
    with open(path, "wb") as out:
        out.write(b'epoch 1 0%\repoch 1 50%\rPROGRESS: {"step": 1, "lo')
        out.flush()
        reader.poll()
        assert reader.points == [] and len(reader.partial) < 64  # read once, the \r lines dropped
        out.write(b'ss": 0.5}\r\nnoise ' + b"y" * (2 * MAX_LINE) + b'\nPROGRESS: {"step": 2, "loss": 0.4}\n')
        out.write(b"FINAL_METRIC: " + b"z" * (2 * MAX_LINE) + b"\r")  # too long: counted, not kept
        out.flush()
        reader.poll(budget=10**9)
        assert heard == [1, 2] and reader.n_finals == 1 and reader.finals == []
        out.write(b'\rFINAL_METRIC: {"run_id": "r", "loss": 0.3}')  # the last line, without its end
    reader.finish()
    assert reader.n_finals == 2 and reader.finals == []  # only the first is kept, and it was too long
    assert read_final_metric(reader.finals, reader.n_finals, "loss", "r")[2] == (
        "2 FINAL_METRIC lines on stdout; exactly one is required"
    )
    assert (
        read_final_metric([], 1, "loss", "r")[2] == f"the FINAL_METRIC line is longer than {MAX_LINE} bytes"
    )
    path.write_bytes(b'99%\rFINAL_METRIC: {"run_id": "r", "loss": 0.3}')  # the last line needs no end
    reader = StdoutReader(path, "loss", None)
    reader.finish()
    assert read_final_metric(reader.finals, reader.n_finals, "loss", "r")[1:] == (0.3, None)


def test_a_run_reporting_without_end_keeps_a_bounded_curve(tmp_path):
    out = _drive(tmp_path, "points:300000")
    assert out["status"] == "ok", out["reason"]
    curve = out["progress"]
    assert len(curve) <= MAX_POINTS + 1 and curve[-1] == {"step": 299999, "value": 1 / 300000}
    gaps = {b["step"] - a["step"] for a, b in itertools.pairwise(curve[:-1])}
    assert curve[0]["step"] == 0 and len(gaps) == 1  # evenly thinned, from the first point on
    assert out["growth_mb"] < 16, out  # 300k points grew it by about 100 MB when all were kept


def test_the_thinned_curve_hears_every_point_and_keeps_the_last(tmp_path):
    path = tmp_path / "stdout.txt"
    heard = []
    reader = StdoutReader(path, "loss", lambda step, value: heard.append(step) or False)
    path.write_text("".join(f'PROGRESS: {{"step": {i}, "loss": 1.0}}\n' for i in range(5 * MAX_POINTS + 3)))
    reader.finish()
    assert heard == []  # finish() judges nothing
    reader = StdoutReader(path, "loss", lambda step, value: heard.append(step) or False)
    reader.poll(budget=10**9)
    assert heard == list(range(5 * MAX_POINTS + 3))  # every point is heard (an early-stop pruner)
    steps = [point["step"] for point in reader.curve]
    assert steps[:3] == [0, 8, 16] and steps[-2:] == [5000, 5002] and len(steps) == 627
