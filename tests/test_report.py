"""`autoresearch audit` end to end through the CLI, and the report it leaves behind."""

from __future__ import annotations

import json
import shutil
import struct

import pytest
from audit_support import AUDIT_FAMILY, P1, P1W, ScriptedProposer, copy_family, run_campaign

from autoresearch.audit.noise import stale_noise
from autoresearch.campaign.audit_log import read_audit
from autoresearch.cli import main
from autoresearch.commands.random_arm import print_random
from autoresearch.family import Family
from autoresearch.proposers.tpe import TPEProposer


def png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    return struct.unpack(">II", data[16:24])


@pytest.fixture(scope="module")
def audited(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("report")
    family = copy_family(AUDIT_FAMILY, tmp / "family")
    root = run_campaign(family, tmp / "campaign", ScriptedProposer([P1, P1W]), iterations=3)
    tpe = run_campaign(family, tmp / "tpe", TPEProposer(family.registry, seed=0), iterations=4)
    argv = ["audit", "--campaign", str(root), "--noise-seeds", "4", "--seeds", "4", "--count", "5"]
    code = main([*argv, "--matched-range", "--arm", str(tpe), "--workers", "2"])
    return family, root, code, argv


def test_audit_command_runs_every_step(audited):
    family, root, code, _ = audited
    assert code == 0
    audit = read_audit(root)
    assert audit.pop("prune_decided_by") == {"key": "prune", "rule": "paper"}  # the default rule
    assert {k: audit[k]["status"] for k in audit} == dict.fromkeys(
        ("noise", "verify", "prune", "random", "random_matched"), "done"
    )
    assert Family.load(family.path).seed_noise["k"] == 4


def test_report_has_the_audit_table_in_the_papers_shape(audited):
    _, root, _, _ = audited
    text = (root / "report.md").read_text()
    for row in (
        "| Seed noise (n=4) | 1.8 ± 0.012 | 0 of 4 | reference |",
        "| Random search (best of 5 draws) |",
        "| Matched-range random (best of 5 draws) |",
        "| tpe (tpe) (best of ",
        "| Agent, single-seed best | 1.197 | yes | not gated |",
        "| Agent, reseeded (n=4) | **1.297 ± 0.012** | 4 of 4 | **43.6σ, PASS** |",
        "| Pruned recipe, reseeded (n=4) |",
    ):
        assert row in text
    assert "95% Welch CI [" in text and "It is not the single-seed best" in text
    assert "| DAGGER | optimizer | 0 → 1 | +2.87 | +2.00 | drop, flagged |" in text
    # The full recipe (1.297) missed the toy target (1.1), so the pruned one had none to lose.
    assert (
        "clears the gate and loses no target (the full recipe did not reach the family's target either)"
        in text
    )


def test_the_report_speaks_in_words(audited):
    """Issue 39, item 3: no field names, code words or paper equation labels a reader cannot look up."""
    _, root, _, _ = audited
    text = (root / "report.md").read_text()
    assert "a run counts as feasible only when its `feasible` is true" in text and "field `None`" not in text
    assert "target 1.1;" in text and "has no target to keep" not in text and "Eq. reseedgate" not in text
    assert 'The gate (docs/audit.md, "Reseeded verification"): a configuration passes when' in text
    assert "A pruned recipe is *published* when its own re-verification passes the same gate" in text


def test_the_headline_is_what_the_audit_promoted_and_the_export_its_policy(audited):
    """Issue 39, item 2: the pruned recipe (without HITCH and DAGGER, the edit that hurt) is more
    reproducible than the full one: the audit promotes it, the headline says so, the family best is
    it, and the exported policy is its own saved run."""
    family, root, _, _ = audited
    audit = read_audit(root)
    pruned = audit["prune"]["pruned"]
    assert audit["prune"]["promotes_pruned"] and audit["prune"]["family_best"]["updated"]
    assert "so it is promoted in place of the full configuration" in audit["prune"]["reason"]
    best = Family.load(family.path).best
    assert best == {"config": pruned["config"], "metric": pruned["mu_r"]}
    text = (root / "report.md").read_text()
    assert (
        f"**Headline**: the pruned recipe {pruned['config_id']} (EPOCHS=60, SAFE=True, BORDER=1.0, GAP=1.0) "
        f"reseeded on the search split {pruned['mu_r']:.4g} ± {pruned['sigma_r']:.2g} (n=4), "
        f"m = {pruned['margin']:.1f}σ: PASS, promoted." in text
    )
    assert "| Pruned recipe, reseeded (n=4) |" in text and "σ, published, promoted |" in text
    exported = json.loads((root / "policy.onnx").read_text())["exported"]
    assert exported == pruned["config"]  # the promoted policy's own saved run, not the full recipe's
    # Issue 59: one promoted recipe, named alike everywhere: verification's winner is "verified", and
    # the section says pruning promoted its pruned recipe in its place.
    verified = audit["verify"]["promoted"]
    assert f"| {verified} (verified) |" in text and f"{verified} (promoted)" not in text
    assert f"Verified: **{verified}**" in text and "Promoted: **" not in text
    assert f"Pruning then promoted its pruned recipe **{pruned['config_id']}** in its place" in text
    # Words, not marks or field names: no dagger, no "0 failed, 0 parity".
    assert "†" not in text and "parity" not in text and "| none |" in text


def test_report_figures_are_non_trivial_pngs(audited):
    _, root, _, _ = audited
    for name in ("search.png", "recipe.png", "trajectories.png"):  # trajectories: the family's hook
        width, height = png_size(root / name)
        assert width >= 300 and height >= 200 and (root / name).stat().st_size > 10_000
        assert f"({name})" in (root / "report.md").read_text()


def test_the_promoted_policy_is_exported_beside_the_report_by_the_familys_hook(audited):
    _, root, _, _ = audited
    assert "[policy.onnx](policy.onnx)" in (root / "report.md").read_text()


def test_a_clone_without_the_saved_policy_keeps_its_figure_or_says_why(audited, tmp_path):
    _, root, _, _ = audited
    clone = tmp_path / "clone"  # verification runs (and their weights) are not committed
    shutil.copytree(root, clone, ignore=shutil.ignore_patterns("out"))
    assert main(["report", "--campaign", str(clone)]) == 0
    assert "![trajectories](trajectories.png)" in (clone / "report.md").read_text()
    (clone / "trajectories.png").unlink()
    assert main(["report", "--campaign", str(clone)]) == 0
    text = (clone / "report.md").read_text()
    assert "No family figure: the promoted policy's saved run (" in text and "re-run prune to plot it" in text
    assert not (clone / "trajectories.png").exists()
    (clone / "policy.onnx").unlink()
    assert main(["report", "--campaign", str(clone)]) == 0
    assert "No exported policy: the promoted policy's saved run (" in (clone / "report.md").read_text()


def test_rerunning_the_audit_runs_nothing_again(audited):
    _, root, _, argv = audited
    logs = [*sorted(root.glob("audit/*/*.jsonl")), root.parent / "campaign-random" / "proposals.jsonl"]
    before = [p.read_bytes() for p in logs]
    assert main(argv) == 0
    assert [p.read_bytes() for p in logs] == before
    assert read_audit(root)["noise"]["source"] == "measured"  # the family's noise, measured by this audit


def test_report_of_an_unaudited_campaign_says_what_is_missing(tmp_path):
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2)
    assert main(["report", "--campaign", str(root)]) == 0
    text = (root / "report.md").read_text()
    assert "Not run (`autoresearch verify" in text and "No family figure: no promoted configuration" in text
    assert png_size(root / "search.png")[0] >= 300


def test_cli_errors_are_one_line_with_exit_code_2(tmp_path, capsys):
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    assert main(["noise", "--family", str(family.path), "--seeds", "1", "--out", str(tmp_path / "n")]) == 2
    assert "K >= 2" in capsys.readouterr().err
    assert main(["verify", "--campaign", str(tmp_path)]) == 2
    assert "not a campaign directory" in capsys.readouterr().err


def test_an_audit_of_a_changed_family_measures_the_noise_again(audited, tmp_path, capsys):
    """The seed noise pins what it was measured on; an audit after train.py changed does not gate on
    the old numbers (issue 28's family grew its data under an unchanged family.json noise)."""
    family, _, _, _ = audited
    copy = copy_family(family.path, tmp_path / "family")
    old = copy.seed_noise
    assert stale_noise(copy) == [] and old["pinned"]["files"]["train.py"]
    train = copy.path / "train.py"
    # Prose is not code: a comment or a corrected docstring leaves the noise standing (issue 59) ...
    source = train.read_text()
    train.write_text(source.replace('"""', '"""Reworded. ', 1) + "\n# a comment\n")
    assert stale_noise(Family.load(copy.path)) == [], source[:80]
    # ... and a change to what runs stales it.
    train.write_text(source + "\nCHANGED = 1\n")
    copy = Family.load(copy.path)
    assert [line.split(":")[0] for line in stale_noise(copy)] == ["train.py"]
    root = run_campaign(copy, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2)
    assert main(["verify", "--campaign", str(root), "--top", "1", "--seeds", "2"]) == 2  # no gate on it
    refused = capsys.readouterr().err
    assert "measured on another version of it (train.py: sha256" in refused
    assert "`autoresearch noise --family" in refused
    assert main(["audit", "--campaign", str(root), "--noise-seeds", "2", "--seeds", "2", "--count", "2"]) == 0
    out = capsys.readouterr().out
    assert "measuring again" in out
    # The gate in words where the audit first names it (issue 59: "runaway gate" went unexplained).
    assert (
        "split: a candidate passes when its reseeded mean beats the baseline's by 2 seed-noise units" in out
    )
    noise = Family.load(copy.path).seed_noise
    assert noise["k"] == 2 and noise["measured_at"] >= old["measured_at"]
    assert stale_noise(Family.load(copy.path)) == []
    # A noise measured before pinning has nothing to compare: it is kept, as before.
    ledger = json.loads((copy.path / "ledger.json").read_text())
    del ledger["seed_noise"]["pinned"]
    (copy.path / "ledger.json").write_text(json.dumps(ledger))
    assert stale_noise(Family.load(copy.path)) == []


def test_a_random_arm_counts_the_draws_that_did_not_finish(capsys):
    """Issue 59: 'best of 4 ... feasible 3 of 3' hid a draw that timed out."""
    part = {"dir": "arm", "count": 4, "n_ran": 3, "n_feasible": 3, "units": None, "verdict": "tie"}
    part["best"] = {"metric": 0.59, "run_id": "it0002"}
    print_random(part)
    line = capsys.readouterr().out.splitlines()[0]
    assert "4 draws, 1 did not finish: best 0.59 (it0002); feasible 3 of the 3 that finished" in line
