"""Runs, seed noise and random arms scored on data other than the family pins (family.json's
split_ids) are refused, re-run or named, never compared with the family's numbers."""

from __future__ import annotations

import json

import pytest
from audit_support import AUDIT_FAMILY, P1, ScriptedProposer, copy_family, run_campaign

from autoresearch.audit.noise import stale_noise
from autoresearch.cli import main
from autoresearch.family import Family, FamilyError
from autoresearch.splits import split_mismatches

PINNED = {"search": "starts-a"}


def pinned_family(tmp_path, ids=PINNED) -> Family:
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    registry = json.loads((family.path / "family.json").read_text())
    registry["split_ids"] = ids
    (family.path / "family.json").write_text(json.dumps(registry, indent=2))
    return Family.load(family.path)


def test_split_mismatches_name_each_split_and_legacy_records():
    assert split_mismatches({"search": "a"}, {"search": "a"}) == []
    assert split_mismatches({}, {}) == []  # a family that pins nothing compares nothing
    assert split_mismatches({"search": "b"}, {"search": "a"}) == [
        "search split: was scored on b; the family pins a"
    ]
    assert split_mismatches({}, {"search": "a", "test": "t"}) == [
        "search split: records no split identity (scored before splits were pinned); the family pins a",
        "test split: records no split identity (scored before splits were pinned); the family pins t",
    ]


@pytest.mark.parametrize(
    "ids, why",
    [
        ({"search": ""}, "split_ids"),
        ({"train": "x"}, "split_ids"),
        (["x"], "split_ids"),
        ({"test": "x"}, "pins a test split, but the family declares no test_split"),
    ],
)
def test_family_json_split_ids_are_validated(tmp_path, ids, why):
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    registry = json.loads((family.path / "family.json").read_text())
    registry["split_ids"] = ids
    (family.path / "family.json").write_text(json.dumps(registry))
    with pytest.raises(FamilyError, match=why):
        Family.load(family.path)


def test_noise_scored_on_another_split_is_stale_and_verify_refuses_it(tmp_path, monkeypatch, capsys):
    family = pinned_family(tmp_path)
    monkeypatch.setenv("AUDIT_SPLIT_IDS", json.dumps(PINNED))
    assert main(["noise", "--family", str(family.path), "--seeds", "2", "--out", str(tmp_path / "n")]) == 0
    family = Family.load(family.path)
    assert family.seed_noise["split_ids"] == PINNED and stale_noise(family) == []
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2)
    # The family moves to another build of its search split: the noise no longer gates anything.
    registry = json.loads((family.path / "family.json").read_text())
    registry["split_ids"] = {"search": "starts-b"}
    (family.path / "family.json").write_text(json.dumps(registry))
    moved = Family.load(family.path)
    assert stale_noise(moved) == [
        "seed noise on the search split: was scored on starts-a; the family pins starts-b"
    ]
    capsys.readouterr()
    assert main(["verify", "--campaign", str(root), "--top", "1", "--seeds", "2"]) == 2
    refused = capsys.readouterr().err
    assert "was scored on starts-a; the family pins starts-b" in refused
    assert f"`autoresearch noise --family {moved.path}`" in refused


def test_noise_measured_before_splits_were_pinned_is_stale(tmp_path, monkeypatch):
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    assert main(["noise", "--family", str(family.path), "--seeds", "2", "--out", str(tmp_path / "n")]) == 0
    assert stale_noise(Family.load(family.path)) == []  # nothing pinned, nothing to compare
    registry = json.loads((family.path / "family.json").read_text())
    registry["split_ids"] = PINNED
    (family.path / "family.json").write_text(json.dumps(registry))
    assert stale_noise(Family.load(family.path)) == [
        "seed noise on the search split: records no split identity (scored before splits were pinned); "
        "the family pins starts-a"
    ]
    # Measured again on the pinned split, its earlier rows (which record none) run again.
    monkeypatch.setenv("AUDIT_SPLIT_IDS", json.dumps(PINNED))
    assert main(["noise", "--family", str(family.path), "--seeds", "2", "--out", str(tmp_path / "n")]) == 0
    rows = [json.loads(line) for line in (tmp_path / "n" / "noise.jsonl").read_text().splitlines()]
    assert len(rows) == 4 and stale_noise(Family.load(family.path)) == []


def test_runs_scored_off_the_pinned_split_are_refused_with_exit_2(tmp_path, monkeypatch, capsys):
    family = pinned_family(tmp_path)
    monkeypatch.setenv("AUDIT_SPLIT_IDS", json.dumps({"search": "starts-elsewhere"}))
    assert main(["noise", "--family", str(family.path), "--seeds", "2", "--out", str(tmp_path / "n")]) == 2
    err = capsys.readouterr().err
    assert "2 run(s) were scored on data other than family" in err
    assert "was scored on starts-elsewhere; the family pins starts-a" in err and "prepare.py --check" in err
    assert Family.load(family.path).seed_noise is None  # nothing was written from them


def test_the_loop_says_when_a_run_was_scored_off_the_pinned_split(tmp_path, monkeypatch, capsys):
    family = pinned_family(tmp_path)
    monkeypatch.setenv("AUDIT_SPLIT_IDS", json.dumps({"search": "starts-elsewhere"}))
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2)
    err = capsys.readouterr().err
    assert err.count("was scored on data other than family") == 2
    records = [json.loads(line) for line in (root / "proposals.jsonl").read_text().splitlines()]
    ran = [r for r in records if r["status"] == "ran"]
    assert ran and all(r["final_metric"]["split_ids"] == {"search": "starts-elsewhere"} for r in ran)


def test_check_family_lists_the_campaigns_scored_on_other_data(tmp_path, monkeypatch, capsys):
    family = pinned_family(tmp_path)
    results = tmp_path / "results"
    monkeypatch.setenv("AUDIT_SPLIT_IDS", json.dumps(PINNED))
    run_campaign(family, results / "same", ScriptedProposer([P1]), iterations=2)
    monkeypatch.setenv("AUDIT_SPLIT_IDS", json.dumps({"search": "starts-elsewhere"}))
    run_campaign(family, results / "elsewhere", ScriptedProposer([P1]), iterations=2)
    monkeypatch.delenv("AUDIT_SPLIT_IDS")
    run_campaign(family, results / "older", ScriptedProposer([P1]), iterations=1)
    capsys.readouterr()
    main(["check", "--family", str(family.path), "--campaigns", str(results)])
    out = capsys.readouterr().out
    assert f"2 of 3 campaign(s) under {results} hold runs scored on data other than" in out
    assert f"  {results / 'elsewhere'}: 2 run(s): search split: was scored on starts-elsewhere" in out
    assert f"  {results / 'older'}: 1 run(s): search split: records no split identity" in out
    assert f"{results / 'same'}:" not in out


def test_a_random_arm_scored_off_the_pinned_split_is_refused(tmp_path, monkeypatch, capsys):
    family = pinned_family(tmp_path)
    monkeypatch.setenv("AUDIT_SPLIT_IDS", json.dumps(PINNED))
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2)
    monkeypatch.setenv("AUDIT_SPLIT_IDS", json.dumps({"search": "starts-elsewhere"}))
    capsys.readouterr()
    assert main(["random", "--budget-from", str(root), "--count", "2"]) == 2
    err = capsys.readouterr().err
    assert "holds 2 draw(s) scored on data other than family" in err
    assert "was scored on starts-elsewhere; the family pins starts-a" in err
    assert f"`autoresearch random --budget-from {root}` again" in err
