"""``autoresearch check``: each kind of damage is found, with its repair; ``report`` notices too."""

import json
import shutil
from pathlib import Path

import pytest
from loop_helpers import copy_toy

from autoresearch.campaign.lock import CampaignLock
from autoresearch.cli import main


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("check")
    toy, root = copy_toy(tmp), tmp / "c"
    args = ["--family", str(toy), "--proposer", "random", "--max-iters", "4", "--seed", "2", "--plain"]
    assert main(["loop", "--campaign", str(root), *args]) == 0
    return root


@pytest.fixture
def campaign(pristine, tmp_path) -> Path:
    return Path(shutil.copytree(pristine, tmp_path / "c"))


def lines(path: Path) -> list[str]:
    return path.read_text().splitlines(keepends=True)


def check(campaign: Path, capsys) -> tuple[int, str]:
    code = main(["check", "--campaign", str(campaign)])
    return code, capsys.readouterr().out


def test_a_clean_campaign_passes(campaign, capsys):
    code, out = check(campaign, capsys)
    assert code == 0 and out == f"{campaign}: clean (4 iterations)\n"  # the loop's stop record is none


def test_an_exact_duplicate_line_is_found(campaign, capsys):
    proposals = campaign / "proposals.jsonl"
    text = lines(proposals)
    proposals.write_text("".join([*text[:3], text[1], *text[3:]]))
    code, out = check(campaign, capsys)
    assert code == 1
    assert "proposals.jsonl:4: iteration 2 again (first at line 2)\n    repair: delete line 4" in out


def test_two_writers_interleaved_are_found(campaign, capsys):
    """What two concurrent resumes left before the lock: the same iterations recorded twice."""
    proposals = campaign / "proposals.jsonl"
    text = lines(proposals)
    other = json.loads(text[2])
    other["config"] = {**other["config"], "EPOCHS": 99}
    proposals.write_text("".join([*text, json.dumps(other) + "\n"]))
    code, out = check(campaign, capsys)
    assert code == 1
    assert "proposals.jsonl:6: iteration 3 again (first at line 3), with a different record" in out
    assert "keep the lines before 6" in out
    assert main(["report", "--campaign", str(campaign)]) == 2  # report does not trust such a trail
    err = capsys.readouterr().err
    assert "proposals.jsonl:6: iteration 3 again" in err and "autoresearch check --campaign" in err
    assert not (campaign / "report.md").exists()


def test_a_gap_a_torn_line_and_a_bad_line_are_found(campaign, capsys):
    proposals = campaign / "proposals.jsonl"
    text = lines(proposals)
    proposals.write_text("".join([text[0], "{not json\n", *text[2:], '{"iteration": 6, "sta']))
    code, out = check(campaign, capsys)
    assert code == 1
    assert "proposals.jsonl:2: not a JSON line" in out
    assert "proposals.jsonl:3: iteration 3 follows 1: iteration 2 is missing" in out
    assert "proposals.jsonl:6: torn last line" in out


def test_a_missing_run_dir_and_stray_or_repeated_runs_log_lines_are_found(campaign, capsys):
    shutil.rmtree(campaign / "runs" / "it0002")
    runs_log = campaign / "runs.jsonl"
    text = lines(runs_log)
    forged = json.loads(text[0]) | {"run_id": "it0042"}
    runs_log.write_text("".join([*text, text[0], json.dumps(forged) + "\n"]))
    code, out = check(campaign, capsys)
    assert code == 1
    assert "iteration 2 records run 'it0002', but runs/it0002 is missing" in out
    assert f"runs.jsonl:{len(text) + 1}: run it0001 logged again (first at line 1)" in out
    assert f"runs.jsonl:{len(text) + 2}: run it0042 was started by no proposal or intent" in out


def test_unreadable_meta_files_are_found(campaign, capsys):
    (campaign / "campaign.json").write_text("{")
    (campaign / "family.json").write_text("[]")
    code, out = check(campaign, capsys)
    assert code == 1
    assert "campaign.json: unreadable" in out and "family.json: does not hold a JSON object" in out


def test_path_mistakes_are_one_line_errors(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    for path, what in ((tmp_path / "file", "is not a directory"), (tmp_path / "no", "does not exist")):
        assert main(["check", "--campaign", str(path)]) == 2
        assert (
            capsys.readouterr().err
            == f"autoresearch check: error: {path} {what}; expected a campaign directory\n"
        )
    assert main(["check", "--campaign", str(tmp_path)]) == 1  # a directory that is no campaign
    assert "campaign.json: missing" in capsys.readouterr().out


def test_report_reads_past_a_torn_last_line(campaign, capsys):
    """A torn tail is what a crash (or a loop still writing) leaves; readers skip it, so report may."""
    with open(campaign / "proposals.jsonl", "a") as f:
        f.write('{"iteration": 6, "sta')
    assert main(["report", "--campaign", str(campaign)]) == 0
    assert (campaign / "report.md").exists()


def test_a_group_is_checked_repeat_by_repeat(tmp_path, capsys):
    toy, group = copy_toy(tmp_path), tmp_path / "g"
    args = ["--family", str(toy), "--proposer", "random", "--repeats", "2", "--max-iters", "2", "--plain"]
    assert main(["loop", "--campaign", str(group), *args]) == 0
    with CampaignLock(group, "loop"):  # a group is locked as a whole, besides each repeat
        assert main(["loop", "--campaign", str(group), *args]) == 2
    assert "is in use by pid" in capsys.readouterr().err
    proposals = group / "repeat-01" / "proposals.jsonl"
    proposals.write_text("".join(lines(proposals)[1:]))  # iteration 1 lost
    code, out = check(group, capsys)
    assert code == 1
    assert f"{group / 'repeat-00'}: clean (2 iterations)" in out
    assert "proposals.jsonl:1: iteration 2 comes first: iteration 1 is missing" in out
