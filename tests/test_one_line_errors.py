"""Issue 38, item 11: where the docs promise a one-line error (exit 2), or a problem of the family
in one line (check --family), there is one, never a traceback; and ``--plain`` passes nothing of a
run's output to the terminal that drives it (control characters are shown escaped)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from loop_helpers import copy_toy

from autoresearch.execution.protocol import check_final_metric
from autoresearch.family import Family, FamilyError
from autoresearch.journal import read_jsonl

CLI = [sys.executable, "-m", "autoresearch"]


def _cli(*args, env=None, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*CLI, *map(str, args)], capture_output=True, text=True, timeout=120, env=env, cwd=cwd
    )


def _loop(toy: Path, campaign: Path, *extra) -> subprocess.CompletedProcess:
    """A two-iteration random loop on ``toy``, one line per event."""
    random = ["--proposer", "random", "--max-iters", 2]
    return _cli("loop", "--family", toy, *random, "--campaign", campaign, "--plain", *extra)


def _one_line(done: subprocess.CompletedProcess, status: int = 2) -> str:
    assert done.returncode == status, done.stdout + done.stderr
    assert "Traceback" not in done.stderr
    (line,) = done.stderr.strip().splitlines()
    return line


def test_an_optuna_journal_that_is_no_journal_is_named_in_one_line(tmp_path):
    toy, campaign, journal = copy_toy(tmp_path), tmp_path / "c", tmp_path / "j.log"
    assert _loop(toy, campaign).returncode == 0
    journal.write_text("not a journal {\n")
    for args in (
        ["loop", "--resume", "--campaign", campaign, "--plain", "--optuna-journal", journal],
        ["export", "--campaign", campaign, "--optuna-journal", journal],
    ):
        line = _one_line(_cli(*args))
        assert f"{journal}: not an Optuna journal file" in line


@pytest.mark.parametrize(
    "damage, problem",
    [
        (
            lambda toy: (toy / "train.py").write_bytes((toy / "train.py").read_bytes() + b"\xff\xfe"),
            "train.py: not UTF-8 text",
        ),
        (lambda toy: (toy / "program.md").write_bytes(b"\xc3("), "program.md: not UTF-8 text"),
        (
            lambda toy: (toy / "family.json").write_text("[" * 100_000 + "]" * 100_000),
            "family.json: not valid JSON (nested too deeply)",
        ),
        (lambda toy: _bounds(toy, "MOMENTUM", -1e308, 1e308), "the width high - low must be a number"),
    ],
    ids=["train.py not UTF-8", "program.md not UTF-8", "family.json too deep", "real width overflows"],
)
def test_check_family_names_a_broken_file_in_one_line(tmp_path, damage, problem):
    toy = copy_toy(tmp_path)
    damage(toy)
    done = _cli("check", "--family", toy)
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
    assert done.stdout.splitlines()[0] == f"{toy}: 1 problem(s)" and problem in done.stdout
    with pytest.raises(FamilyError, match=r"not UTF-8|not valid JSON|width"):
        Family.load(toy)  # what loop and the audit load: the same problem, in one line


def _bounds(toy: Path, name: str, low: float, high: float) -> None:
    registry = json.loads((toy / "family.json").read_text())
    spec = registry["search_space"][name]
    spec.update(low=low, high=high, high_exclusive=False)
    spec.pop("random_range", None)
    (toy / "family.json").write_text(json.dumps(registry))


def test_init_into_a_link_to_an_empty_directory_writes_the_family_there(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "empty")
    done = _cli("init", tmp_path / "link")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "link").is_symlink() and Family.load(tmp_path / "link").name == "link"
    assert (tmp_path / "empty" / "train.py").is_file()


def _templates(tmp_path: Path) -> dict[str, str]:
    """An installed distribution offering broken templates: its module raises, its family.json is not
    JSON, or is JSON but no object."""
    site = tmp_path / "site"
    (site / "broken_templates-1.0.dist-info").mkdir(parents=True)
    (site / "broken_templates-1.0.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: broken-templates\nVersion: 1.0\n"
    )
    (site / "broken_templates-1.0.dist-info" / "entry_points.txt").write_text(
        "[autoresearch.templates]\nraises = broken_templates:raises\nbadjson = broken_templates:badjson\n"
        "notobject = broken_templates:notobject\n"
    )
    for name, text in (("badjson", "{"), ("notobject", "[1]")):
        (site / name).mkdir()
        (site / name / "family.json").write_text(text)
    (site / "broken_templates.py").write_text(
        "from pathlib import Path\nHERE = Path(__file__).parent\n"
        "def raises():\n    raise RuntimeError('no template here')\n"
        "def badjson():\n    return HERE / 'badjson'\n"
        "def notobject():\n    return HERE / 'notobject'\n"
    )
    return {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")])),
    }


@pytest.mark.parametrize(
    "template, said",
    [
        ("raises", "RuntimeError: no template here"),
        ("badjson", "JSONDecodeError"),
        ("notobject", "no JSON object"),
    ],
)
def test_a_broken_third_party_template_is_one_line(tmp_path, template, said):
    env = _templates(tmp_path)
    line = _one_line(_cli("init", tmp_path / "fam", "--template", template, env=env))
    assert line.startswith(f"autoresearch init: error: template {template!r}") and said in line
    assert not (tmp_path / "fam").exists()


def test_a_final_metric_of_true_is_called_true():
    assert check_final_metric({"run_id": "r", "loss": True}, "loss", "r") == (
        None,
        "FINAL_METRIC 'loss' is not a number: true",
    )


def test_plain_output_escapes_a_runs_terminal_control_sequences(tmp_path):
    toy, enqueued = copy_toy(tmp_path), tmp_path / "enqueued.json"
    enqueued.write_text(json.dumps({"EPOCHS": 0}))
    train = toy / "train.py"
    hostile = "\\x1b]0;pwned\\x07\\x1b[2J\\x9b1m"  # retitle the terminal, clear it, a C1 CSI
    train.write_text(
        train.read_text().replace(
            '        print(f"training failed: {err}", file=sys.stderr)',
            f'        print("{hostile}" + f"training failed: {{err}}", file=sys.stderr)',
            1,
        )
    )
    done = _loop(toy, tmp_path / "c", "--enqueue", enqueued)
    assert done.returncode == 0, done.stderr
    assert not any(c in done.stdout for c in "\x1b\x07\x9b")
    assert "\\x1b]0;pwned\\x07\\x1b[2J\\x9b1mtraining failed" in done.stdout
    failed = [r for r in read_jsonl(tmp_path / "c" / "proposals.jsonl") if r["status"] == "failed"]
    assert "\x1b]0;pwned" in failed[0]["reason"]  # the record keeps what the run said
