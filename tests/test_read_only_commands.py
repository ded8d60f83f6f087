"""Issue 38, items 3 and 7: the read-only commands. ``check --campaign`` and ``report`` run nothing
the family's git repository names (``git status`` runs its core.fsmonitor and clean filters), and
``check``, ``report --out elsewhere`` and ``export`` change nothing in the campaign directory: a torn
last line is read past, not moved, and no lock file is made, so they work on a read-only copy."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from audit_support import ScriptedProposer, copy_family, run_campaign
from loop_helpers import TOY_FAMILY, snapshot

CLI = [sys.executable, "-m", "autoresearch"]


def _git(repo: Path, *args: str) -> None:
    subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True)


def _hostile_repository(tmp_path: Path) -> tuple[Path, Path]:
    """A family in a git repository whose config runs a program on ``git status``; the marker file it
    appends to."""
    repo, marker = tmp_path / "repo", tmp_path / "ran.txt"
    family = copy_family(TOY_FAMILY, repo / "toy")
    _git(repo, "init", "-q")
    _git(repo, "add", ".")
    _git(repo, "-c", "user.email=a@b", "-c", "user.name=a", "commit", "-qm", "family")
    hook = tmp_path / "hook.sh"
    hook.write_text(f"#!/bin/sh\necho ran >> {marker}\ncat\n")
    hook.chmod(0o755)
    _git(repo, "config", "core.fsmonitor", str(hook))
    _git(repo, "config", "filter.x.clean", str(hook))
    (repo / ".gitattributes").write_text("* filter=x\n")
    campaign = run_campaign(family, tmp_path / "c", ScriptedProposer([{"EPOCHS": 20}]), 2)
    (repo / "toy" / "train.py").touch()  # a stat change: git status would run the clean filter
    marker.unlink(missing_ok=True)  # the loop ran the family's code, and git status with it
    return campaign, marker


def test_check_and_report_run_nothing_the_familys_repository_names(tmp_path):
    campaign, marker = _hostile_repository(tmp_path)
    check = subprocess.run([*CLI, "check", "--campaign", str(campaign)], capture_output=True, text=True)
    assert check.returncode == 0, check.stdout + check.stderr
    report = subprocess.run([*CLI, "report", "--campaign", str(campaign)], capture_output=True, text=True)
    assert report.returncode == 0, report.stderr
    assert not marker.exists()


def test_read_only_commands_change_nothing_in_the_campaign(tmp_path):
    family = copy_family(TOY_FAMILY, tmp_path / "toy")
    campaign = run_campaign(family, tmp_path / "c", ScriptedProposer([{"EPOCHS": 20}]), 3)
    for log in ("proposals.jsonl", "runs.jsonl"):
        with open(campaign / log, "ab") as f:
            f.write(b'{"iteration": 9, "status": "ra')  # a torn last line, as a crash leaves it
    for lock in campaign.glob("*.lock"):
        lock.unlink()  # a read-only copy holds no lock files: nothing may need to make one
    before = snapshot(campaign)
    commands = [
        ["check", "--campaign", str(campaign)],
        ["report", "--campaign", str(campaign), "--out", str(tmp_path / "report")],
        ["export", "--campaign", str(campaign), "--optuna-journal", str(tmp_path / "study.log")],
    ]
    for command in commands:
        done = subprocess.run([*CLI, *command], capture_output=True, text=True)
        assert done.returncode == (1 if command[0] == "check" else 0), done.stdout + done.stderr
        assert snapshot(campaign) == before, command[0]
    assert "torn last line" in subprocess.run([*CLI, *commands[0]], capture_output=True, text=True).stdout
    assert (tmp_path / "report" / "report.md").is_file()
