"""What the README tells a newcomer holds (issue 39): the quickstart prints what the README says it
prints and says why the expert ends off the docking point (item 16); the install from a checkout
it gives while the package is unpublished installs (item 11); and a missing extra ends as it says,
for autoresearch's own extras and for a family's (item 10)."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from loop_helpers import copy_toy

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
INSTALL = (ROOT / "docs" / "install.md").read_text(encoding="utf-8")  # the README links it


def _section(title: str) -> str:
    return README.split(f"## {title}\n", 1)[1].split("\n## ", 1)[0]


def test_the_quickstart_prints_what_the_readme_says_and_why():
    quickstart = _section("Quickstart")
    code = re.search(r"```python\n(.*?)```", quickstart, re.S).group(1)
    said = re.search(r"It prints `([^`]+)`", quickstart).group(1)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == said
    assert "edits one of the 240 steps" in quickstart and "open-loop" in quickstart


def test_the_install_from_a_checkout_the_readme_gives_installs(tmp_path):
    install = _section("Install")
    assert "Until cwh-autoresearch is published on PyPI" in install
    checkout = re.search(r'^pip install "\.\[all\]"', install, re.M).group(0)
    # What that line asks of pip, resolved without touching the network or this environment.
    args = [*shlex.split(checkout)[1:], "--dry-run", "--no-deps", "--no-index", "--no-build-isolation", "-q"]
    args += ["--report", str(tmp_path / "report.json")]
    done = subprocess.run(
        [sys.executable, "-m", "pip", *args], capture_output=True, text=True, cwd=ROOT, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert '"name": "cwh-autoresearch"' in (tmp_path / "report.json").read_text()
    assert "pip wheel --no-deps -w dist ." in install and "dist/cwh_autoresearch-*.whl)[all]" in install


@pytest.fixture
def without_torch(tmp_path) -> dict[str, str]:
    """An environment whose `import torch` fails as it does where the [families] extra is missing."""
    shadow = tmp_path / "shadow" / "torch"
    shadow.mkdir(parents=True)
    (shadow / "__init__.py").write_text(
        "raise ModuleNotFoundError(\"No module named 'torch'\", name='torch')\n"
    )
    return {**os.environ, "PYTHONPATH": str(shadow.parent)}


def test_a_familys_missing_extra_ends_check_and_loop_as_the_readme_says(tmp_path, without_torch):
    assert "`autoresearch check --family` lists it as the family's problem" in INSTALL
    extra = "this family trains with torch, which is not installed: pip install 'cwh-autoresearch[families]'"
    family = ROOT / "families" / "rendezvous"
    cli = [sys.executable, "-m", "autoresearch"]
    check = subprocess.run(  # --campaigns: none of the committed campaigns (their splits are listed too)
        [*cli, "check", "--family", family, "--campaigns", tmp_path],
        capture_output=True,
        text=True,
        env=without_torch,
    )
    assert check.returncode == 1 and "Traceback" not in check.stderr
    assert check.stdout.splitlines() == [
        f"{family}: 1 problem(s)",
        f"  prepare.py --check failed (exit 1): {extra}",
    ]
    loop = [*cli, "loop", "--family", family, "--proposer", "random", "--campaign", tmp_path / "c", "--plain"]
    done = subprocess.run(loop, capture_output=True, text=True, env=without_torch, timeout=120)
    assert done.returncode == 1 and "Traceback" not in done.stderr
    assert (
        f"ended: prepare_failed (prepare_check): prepare.py --check failed (exit 1): {extra}" in done.stdout
    )


def test_autoresearchs_own_missing_extra_is_one_line_and_exit_2(tmp_path, without_torch):
    assert "is one line naming it, before\nanything runs (`autoresearch` exits 2)" in INSTALL
    toy = copy_toy(tmp_path)
    loop = [sys.executable, "-m", "autoresearch", "loop", "--family", toy, "--proposer", "gp"]
    done = subprocess.run(
        [*loop, "--campaign", tmp_path / "c"], capture_output=True, text=True, env=without_torch
    )
    assert done.returncode == 2
    (line,) = done.stderr.strip().splitlines()
    assert "pip install 'cwh-autoresearch[gp]'" in line and not (tmp_path / "c" / "proposals.jsonl").exists()


def test_the_readme_is_a_front_page():
    """Issue 59: 415 lines opening on a research log. At most about 150 lines now: what it is, the two
    commands, the quickstarts, the leaderboard, links; the research log is docs/findings.md."""
    assert len(README.splitlines()) <= 155
    titles = re.findall(r"^## (.+)$", README, re.M)
    assert titles[:4] == ["Two commands", "Quickstart", "Leaderboard", "Install"], titles
    assert "bash scripts/main.sh" in _section("Two commands") and "bash scripts/test.sh" in _section(
        "Two commands"
    )
    assert "(docs/findings.md)" in README and (ROOT / "docs" / "findings.md").is_file()


@pytest.mark.needs("families")  # the leaderboard script imports the families' extras
def test_the_readmes_leaderboard_is_the_committed_one():
    """The README's tables are written from results/leaderboard.json (benchmarks/leaderboard.py's
    summary), never typed: the numbers a newcomer reads are the ones measured."""
    import importlib.util
    import json

    spec = importlib.util.spec_from_file_location("leaderboard", ROOT / "benchmarks" / "leaderboard.py")
    board = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = board
    spec.loader.exec_module(board)
    rows = json.loads((ROOT / "results" / "leaderboard.json").read_text(encoding="utf-8"))
    block = README.split(board.SUMMARY_START + "\n", 1)[1].split(board.SUMMARY_END, 1)[0]
    assert block == board.summary(rows)
    assert (ROOT / "results" / "leaderboard-summary.md").read_text(encoding="utf-8") == block
    for task in ("rendezvous", "docking", "docking-constrained"):
        assert f"**{task}**" in block
    assert "family best (BC)" in block and "MPC" in block and "robust CBF" in block
    assert "(long run)" in block  # the best long RL row of a task that has one (issue 60)
