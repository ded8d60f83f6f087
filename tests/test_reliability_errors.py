"""A full disk and corrupt files end in one line on stderr with a documented exit status, never a
traceback; ``check`` validates audit.json and finds a ran run without its runs.jsonl line
(issue 29, item 5)."""

from __future__ import annotations

import errno
import json
import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from loop_helpers import copy_toy

from autoresearch.campaign.check import check_campaign
from autoresearch.exits import EXIT_ERROR, EXIT_NO_SPACE, error_exit
from autoresearch.journal import read_jsonl

LIMIT = 6000  # bytes: the largest file a process under this limit may write


def _limited() -> None:
    """In the child: files stop growing at LIMIT bytes (EFBIG, as a full disk gives ENOSPC)."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT, LIMIT))


def _cli(*args, limited: bool = False) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "autoresearch", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=_limited if limited else None,
    )


def _one_line_error(proc: subprocess.CompletedProcess, status: int, command: str) -> str:
    assert proc.returncode == status, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if not line.startswith("[")]  # not progress
    assert len(lines) == 1 and lines[0].startswith(f"autoresearch {command}: error: "), proc.stderr
    return lines[0]


@pytest.fixture
def campaign(tmp_path) -> Path:
    toy, root = copy_toy(tmp_path), tmp_path / "c"
    proc = _cli(
        "loop", "--family", toy, "--proposer", "random", "--max-iters", 2, "--campaign", root, "--plain"
    )
    assert proc.returncode == 0, proc.stderr
    return root


def test_a_full_disk_stops_the_loop_with_one_line_and_its_status_then_resume_works(tmp_path):
    toy, root = copy_toy(tmp_path), tmp_path / "c"
    start = (
        "loop",
        "--family",
        toy,
        "--proposer",
        "random",
        "--max-iters",
        12,
        "--campaign",
        root,
        "--plain",
    )
    line = _one_line_error(_cli(*start, limited=True), EXIT_NO_SPACE, "loop")
    assert "out of disk space" in line and f"autoresearch loop --resume --campaign {root}" in line
    assert str(root) in line.split("; free")[0]  # the file it could not write
    done = _cli("loop", "--resume", "--campaign", root, "--plain")
    assert done.returncode == 0, done.stderr
    records = read_jsonl(root / "proposals.jsonl")
    assert [r["iteration"] for r in records] == list(range(1, 14)) and records[-1]["trigger"] == "max_iters"
    assert [p for p in check_campaign(root).problems if "torn" not in p.what] == []


def test_a_full_disk_stops_an_audit_step_with_one_line_and_its_status(tmp_path):
    toy = copy_toy(tmp_path)
    line = _one_line_error(
        _cli("noise", "--family", toy, "--seeds", 12, "--out", tmp_path / "noise", limited=True), 3, "noise"
    )
    assert "out of disk space" in line and "run the same command again" in line
    assert str(tmp_path / "noise") in line  # the file it could not write


def test_the_exit_status_of_each_kind_of_error():
    assert error_exit("x", OSError(errno.ENOSPC, "No space left on device")) == EXIT_NO_SPACE == 3
    assert error_exit("x", OSError(errno.EDQUOT, "Disk quota exceeded")) == EXIT_NO_SPACE
    assert error_exit("x", OSError(errno.EACCES, "Permission denied")) == EXIT_ERROR == 2
    assert error_exit("x", ValueError("two\nlines")) == EXIT_ERROR


@pytest.mark.parametrize("command", ["audit", "verify", "report"])
def test_an_audit_json_that_is_no_object_is_a_one_line_error(campaign, command):
    (campaign / "audit.json").write_text("[]")
    line = _one_line_error(_cli(command, "--campaign", campaign), 2, command)
    assert "audit.json: does not hold a JSON object" in line and "autoresearch check" in line
    (campaign / "audit.json").write_text(json.dumps({"verify": [], "noise": {"status": "done"}}))
    line = _one_line_error(_cli(command, "--campaign", campaign), 2, command)
    assert "step 'verify' does not hold a JSON object" in line


def test_a_campaign_family_json_of_another_family_is_a_one_line_error_on_resume(campaign):
    registry = json.loads((campaign / "family.json").read_text())
    (campaign / "family.json").write_text(json.dumps({**registry, "name": "other"}))
    line = _one_line_error(_cli("loop", "--resume", "--campaign", campaign, "--max-iters", 3), 2, "loop")
    assert "belongs to family 'other', not 'toy'; delete it" in line
    (campaign / "family.json").write_text("[]")
    line = _one_line_error(_cli("loop", "--resume", "--campaign", campaign, "--max-iters", 3), 2, "loop")
    assert "is no family.json; delete it" in line
    (campaign / "family.json").unlink()  # the repair it names
    assert _cli("loop", "--resume", "--campaign", campaign, "--max-iters", 3, "--plain").returncode == 0


def test_check_validates_audit_json(campaign):
    (campaign / "audit.json").write_text("[]")
    (problem,) = check_campaign(campaign).problems
    assert (problem.where, problem.what) == ("audit.json", "does not hold a JSON object")
    audit = {
        "noise": {"status": "done"},
        "verify": {"status": "finished"},
        "prune": [],
        "prune_decided_by": {"key": "prune"},
        "a_future_step": 1,  # parts of steps unknown here are left alone
    }
    (campaign / "audit.json").write_text(json.dumps(audit))
    problems = sorted(p.what for p in check_campaign(campaign).problems)
    assert problems == [
        "step 'prune' does not hold a JSON object",
        "step 'verify' has status 'finished', not one of running, done, skipped",
    ]
    (campaign / "audit.json").write_text(json.dumps({"noise": {"status": "done"}}))
    assert check_campaign(campaign).problems == []


def test_check_finds_a_ran_run_without_its_runs_log_line(campaign):
    runs_log = campaign / "runs.jsonl"
    lines = runs_log.read_text().splitlines(keepends=True)
    runs_log.write_text(lines[0])
    (problem,) = check_campaign(campaign).problems
    assert (
        problem.where == "runs.jsonl"
        and "run 'it0002' of iteration 2 ran, but has no readable line" in problem.what
    )
    proc = _cli("check", "--campaign", campaign)
    assert proc.returncode == 1 and "it0002" in proc.stdout
    os.remove(runs_log)
    assert len(check_campaign(campaign).problems) == 2
