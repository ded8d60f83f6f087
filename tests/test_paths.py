"""Path mistakes: a family name that is not a plain name, campaigns inside the family directory,
a file or a missing directory where a directory is expected: each one line, nothing written."""

import json

import pytest
from loop_helpers import copy_toy, snapshot

from autoresearch.cli import main
from autoresearch.family import Family, FamilyError


@pytest.fixture
def toy(tmp_path):
    return copy_toy(tmp_path)


@pytest.mark.parametrize("name", ["../escape", "a/b", "..", ".hidden", "x..y", "/abs", "a b", "a" * 65, "é"])
def test_a_family_name_must_be_a_plain_name(toy, name):
    registry = json.loads((toy / "family.json").read_text())
    (toy / "family.json").write_text(json.dumps({**registry, "name": name}))
    with pytest.raises(FamilyError, match=r"'name' must be a plain name"):
        Family.load(toy)


def test_plain_names_still_load(toy):
    registry = json.loads((toy / "family.json").read_text())
    for name in ("docking", "audit-toy", "cwh_v2.1"):
        (toy / "family.json").write_text(json.dumps({**registry, "name": name}))
        assert Family.load(toy).name == name


def one_line_error(capsys, command: str) -> str:
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"autoresearch {command}: error: ")
    return err


@pytest.mark.parametrize("inside", ["runs", "sub/dir"])
def test_a_campaign_inside_the_family_directory_is_refused(toy, inside, capsys):
    before = snapshot(toy)
    campaign = toy / inside
    assert main(["loop", "--family", str(toy), "--proposer", "random", "--campaign", str(campaign)]) == 2
    assert "inside the family directory" in one_line_error(capsys, "loop")
    assert snapshot(toy) == before and not (toy / "runs").exists()
    assert main(["noise", "--family", str(toy), "--out", str(campaign)]) == 2
    assert "inside the family directory" in one_line_error(capsys, "noise")
    assert snapshot(toy) == before


def test_file_and_missing_paths_are_one_line_errors(toy, tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    cases = [
        ["loop", "--family", str(toy), "--proposer", "random", "--campaign", f"{afile}/sub"],
        ["loop", "--resume", "--campaign", str(afile)],
        ["loop", "--family", str(afile), "--proposer", "random"],
        ["noise", "--family", str(toy), "--out", str(afile)],
        ["noise", "--family", str(toy), "--campaign", str(tmp_path / "missing")],
        ["verify", "--campaign", str(afile)],
        ["prune", "--campaign", str(tmp_path / "missing")],
        ["audit", "--campaign", str(afile)],
        ["random", "--budget-from", str(afile)],
        ["report", "--campaign", str(afile)],
        ["report", "--campaign", str(tmp_path / "missing")],
        ["compare", str(afile)],
        ["check", "--campaign", str(afile)],
    ]
    for argv in cases:
        assert main(argv) == 2, argv
        one_line_error(capsys, argv[0])
    assert afile.read_text() == "x"


def test_output_paths_that_are_files_are_one_line_errors(tmp_path, capsys):
    toy, campaign, afile = copy_toy(tmp_path), tmp_path / "c", tmp_path / "afile"
    afile.write_text("x")
    loop = ["loop", "--family", str(toy), "--proposer", "random", "--max-iters", "2", "--plain"]
    assert main([*loop, "--campaign", str(campaign)]) == 0
    capsys.readouterr()
    for argv in (
        ["report", "--campaign", str(campaign), "--out", str(afile)],
        ["report", "--campaign", str(campaign), "--arm", str(afile)],
        ["compare", str(campaign), "--out", str(afile / "x")],
        ["random", "--budget-from", str(campaign), "--out", str(afile)],
    ):
        assert main(argv) == 2, argv
        one_line_error(capsys, argv[0])
    assert afile.read_text() == "x"


def test_constraints_field_is_checked_and_read_only_when_well_formed(toy):
    registry = json.loads((toy / "family.json").read_text())
    (toy / "family.json").write_text(
        json.dumps({**registry, "feasibility_field": None, "constraints_field": "c"})
    )
    with pytest.raises(FamilyError, match=r"'constraints_field' needs a feasibility_field"):
        Family.load(toy)
    (toy / "family.json").write_text(
        json.dumps({**registry, "feasibility_field": "ok", "constraints_field": 3})
    )
    with pytest.raises(FamilyError, match=r"'constraints_field' must be a field name or null"):
        Family.load(toy)
    (toy / "family.json").write_text(
        json.dumps({**registry, "feasibility_field": "ok", "constraints_field": "c"})
    )
    family = Family.load(toy)
    assert family.constraints({"c": {"gap": 0.25, "rate": 0}}) == {"gap": 0.25, "rate": 0.0}
    for record in ({}, {"c": {}}, {"c": [0.1]}, {"c": {"gap": "far"}}, {"c": {"gap": float("nan")}}, None):
        assert family.constraints(record) is None  # an older or malformed record: the 0/1 gate only
