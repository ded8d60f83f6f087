"""Issue 29, items 2 and 3: two audits of one family keep the better best, and a campaign always
finds the family it ran (or refuses with one line naming what it expected)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from audit_support import AUDIT_FAMILY, P1, P1W, ScriptedProposer, copy_family, family_best, run_campaign
from loop_helpers import copy_toy

from autoresearch.audit.inputs import open_campaign
from autoresearch.audit.noise import measure_noise
from autoresearch.campaign import CampaignError, CampaignMeta
from autoresearch.campaign.audit_log import read_audit
from autoresearch.execution.executors import LocalExecutor
from autoresearch.journal import read_json, write_json_atomic

ROOT = Path(__file__).resolve().parents[1]


def cli(*args: str, cwd: Path | None = None, env: dict | None = None, **popen) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "autoresearch", *args],
        cwd=cwd,
        env=env or dict(os.environ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **popen,
    )


def finish(proc: subprocess.Popen) -> tuple[int, str, str]:
    out, err = proc.communicate(timeout=300)
    return proc.returncode, out, err


def test_two_audits_at_once_end_with_the_better_best(tmp_path):
    """X (P1W: erratic, the worse bound) is slow; Y (P1: tight) finishes first. X decides against the
    best Y wrote meanwhile, not against the family.json it read when its step began."""
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    worse = run_campaign(family, tmp_path / "x", ScriptedProposer([P1W]), iterations=2)
    better = run_campaign(family, tmp_path / "y", ScriptedProposer([P1]), iterations=2)
    measure_noise(family, LocalExecutor(1), k=4, campaign=open_campaign(worse))
    verify = ["verify", "--top", "1", "--seeds", "4"]
    slow = cli(*verify, "--campaign", str(worse), env={**os.environ, "AUDIT_SLEEP_S": "1.5"})
    time.sleep(1.0)  # X has read family.json (no best yet) and is training
    fast = cli(*verify, "--campaign", str(better))
    assert finish(fast)[0] == 0
    assert family_best(family.path)["source"]["campaign"].endswith("y")
    code, _, err = finish(slow)
    assert code == 0, err
    best = family_best(family.path)
    assert best["source"]["campaign"].endswith("y")  # the better best stands
    decided = read_audit(worse)["verify"]["family_best"]
    assert decided["updated"] is False and "better bound" in decided["why"]


def test_a_campaign_finds_its_family_from_any_working_directory(tmp_path):
    """The loop started in one directory, the audit from another that holds an impostor of the same
    relative name (other bounds): the audit runs the campaign's own family and writes only into it."""
    start, elsewhere = tmp_path / "start", tmp_path / "elsewhere"
    for where in (start, elsewhere):
        (where / "families").mkdir(parents=True)
    family = copy_family(AUDIT_FAMILY, start / "families" / "audit-toy")
    impostor = copy_family(AUDIT_FAMILY, elsewhere / "families" / "audit-toy")
    registry = read_json(impostor.path / "family.json")
    registry["search_space"]["EPOCHS"]["high"] = 60
    write_json_atomic(impostor.path / "family.json", registry)
    before = (impostor.path / "family.json").read_bytes()

    loop = ["loop", "--family", "families/audit-toy", "--proposer", "random", "--max-iters", "2", "--plain"]
    code, _, err = finish(cli(*loop, "--campaign", "c", cwd=start))
    assert code == 0, err
    assert read_json(start / "c" / "campaign.json")["family_dir"] == "../families/audit-toy"
    code, _out, err = finish(
        cli(
            "noise",
            "--family",
            str(family.path),
            "--seeds",
            "2",
            "--campaign",
            str(start / "c"),
            cwd=elsewhere,
        )
    )
    assert code == 0, err
    assert read_json(family.path / "ledger.json")["seed_noise"]["k"] == 2
    assert (impostor.path / "family.json").read_bytes() == before  # never touched
    assert not (impostor.path / "ledger.json").exists()

    # Resuming against a family of the same name whose problem differs is refused, in one line.
    resume = ["loop", "--resume", "--campaign", str(start / "c"), "--max-iters", "3", "--plain"]
    code, _, err = finish(cli(*resume, "--family", str(impostor.path)))
    assert (
        code == 2 and "is not the family.json this campaign ran" in err and len(err.strip().splitlines()) == 1
    )
    assert len(read_json(start / "c" / "campaign.json")["sessions"]) == 1

    # A family moved away: the campaign says where it looked and what it expected.
    shutil.move(family.path, tmp_path / "moved")
    code, _, err = finish(cli("verify", "--campaign", str(start / "c"), "--top", "1", "--seeds", "2"))
    assert code == 2 and "its family directory does not exist" in err and "'audit-toy' family" in err
    # ... and --resume --family at its new place continues it, recording where it now is.
    code, _, err = finish(cli(*resume, "--family", str(tmp_path / "moved")))
    assert code == 0, err
    assert read_json(start / "c" / "campaign.json")["family_dir"] == "../../moved"


def _legacy_campaign(toy: Path, campaign: Path, relative_to: Path) -> dict:
    """A one-run campaign of ``toy`` as written before family_dir: ``family`` relative to
    ``relative_to`` (where its loop started). Returns its campaign.json."""
    loop = ["loop", "--family", str(toy), "--proposer", "random", "--max-iters", "1", "--plain"]
    assert finish(cli(*loop, "--campaign", str(campaign)))[0] == 0
    legacy = read_json(campaign / "campaign.json")
    legacy.pop("family_dir")
    legacy["family"] = os.path.relpath(toy, relative_to)
    (campaign / "campaign.json").write_text(json.dumps(legacy))
    return legacy


def test_a_campaign_written_before_family_dir_still_resumes_from_its_directory(tmp_path):
    toy, campaign = copy_toy(tmp_path), tmp_path / "c"
    _legacy_campaign(toy, campaign, relative_to=tmp_path)
    resume = ["loop", "--resume", "--campaign", "c", "--max-iters", "2", "--plain"]
    code, _, err = finish(cli(*resume, cwd=tmp_path))
    assert code == 0, err
    assert read_json(campaign / "campaign.json")["family_dir"] == "../toy"


def test_a_legacy_campaign_finds_its_relative_family_above_it(tmp_path):
    """Written before family_dir, with ``family`` relative to where its loop started (the repository
    root): read from anywhere, the family is found under a directory above the campaign."""
    toy = copy_toy(tmp_path)
    campaign = tmp_path / "results" / "evidence" / "c"
    legacy = _legacy_campaign(toy, campaign, relative_to=tmp_path)
    assert CampaignMeta.read(campaign).open_family(campaign).path.resolve() == toy.resolve()
    legacy["family"] = "nowhere/toy"
    (campaign / "campaign.json").write_text(json.dumps(legacy))
    with pytest.raises(CampaignError, match="nowhere/toy under each directory above the campaign"):
        CampaignMeta.read(campaign).open_family(campaign)


def test_numbers_the_audit_and_the_prompts_read_from_family_json_are_checked(tmp_path):
    from autoresearch.family import Family, FamilyError

    toy = copy_toy(tmp_path)
    registry = read_json(toy / "family.json")
    cases = {
        "baseline.metric": {**registry, "baseline": {**registry["baseline"], "metric": 10**400}},
        "seed_noise.mean": {**registry, "seed_noise": {"mean": 10**400, "std": 0.1, "k": 2}},
        "seed_noise.test.std": {
            **registry,
            "seed_noise": {"mean": 1.0, "std": 0.1, "k": 2, "test": {"mean": 1.0, "std": float("nan")}},
        },
        "best.metric": {**registry, "best": {"config": registry["baseline"]["config"], "metric": 10**400}},
    }
    for field, bad in cases.items():
        (toy / "family.json").write_text(json.dumps(bad))
        with pytest.raises(FamilyError, match=field.replace(".", r"\.")):
            Family.load(toy)
