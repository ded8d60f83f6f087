"""--space for every key-free arm: the loop keeps it in campaign.json and on resume, the audit's random
arm follows the campaign's space (real subprocess runs of the toy and audit families)."""

from __future__ import annotations

import json

import pytest
from audit_support import AUDIT_FAMILY, P1, ScriptedProposer, copy_family, run_campaign
from loop_helpers import copy_toy

from autoresearch.audit.inputs import AuditError, open_campaign
from autoresearch.audit.random_arm import run_random_arm
from autoresearch.campaign import BASELINE_PROPOSER
from autoresearch.cli import main
from autoresearch.execution.executors import LocalExecutor
from autoresearch.journal import read_json, read_jsonl, write_json_atomic

SERIAL = LocalExecutor(1)


def epochs_drawn(campaign):
    # By proposer, not by position: with two workers the baseline may be recorded after a draw.
    records = read_jsonl(campaign / "proposals.jsonl")
    return [r["config"]["EPOCHS"] for r in records if r.get("config") and r["proposer"] != BASELINE_PROPOSER]


@pytest.mark.needs("gp")
def test_loop_keeps_the_space_and_resume_honours_it(tmp_path, capsys):
    toy = copy_toy(tmp_path)  # EPOCHS: bounds [0, 60], random_range [5, 50]
    campaign = tmp_path / "c"
    args = ("--family", toy, "--proposer", "gp", "--space", "random-range", "--plateau-window", 50)
    assert main(["loop", *map(str, args), "--max-iters", "4", "--campaign", str(campaign)]) == 0
    assert read_json(campaign / "campaign.json")["settings"]["space"] == "random-range"
    assert main(["loop", "--resume", "--campaign", str(campaign), "--max-iters", "7"]) == 0
    drawn = epochs_drawn(campaign)
    assert len(drawn) == 6 and all(5 <= e <= 50 for e in drawn)  # 3 + 3 GP draws: 7 iterations in all
    assert read_json(campaign / "campaign.json")["settings"]["space"] == "random-range"
    with pytest.raises(SystemExit):
        main(["loop", "--family", str(toy), "--proposer", "random", "--space", "all"])
    assert "invalid choice: 'all'" in capsys.readouterr().err


def test_random_arm_searches_the_campaign_space_unless_told(tmp_path):
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    registry = read_json(family.path / "family.json")
    registry["search_space"]["EPOCHS"]["random_range"] = {"low": 1, "high": 3}
    write_json_atomic(family.path / "family.json", registry)
    family = type(family).load(family.path)
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2)
    meta = read_json(root / "campaign.json")
    write_json_atomic(root / "campaign.json", {**meta, "settings": {**meta["settings"], "space": "bounds"}})
    bounds = run_random_arm(open_campaign(root), LocalExecutor(2), count=6)
    assert (
        bounds["space"] == "bounds"
        and read_json(tmp_path / "campaign-random" / "campaign.json")["settings"]["space"] == "bounds"
    )
    assert max(epochs_drawn(tmp_path / "campaign-random")) > 3
    narrow = run_random_arm(
        open_campaign(root), LocalExecutor(2), count=6, space="random-range", out=tmp_path / "rr"
    )
    assert narrow["space"] == "random-range" and all(1 <= e <= 3 for e in epochs_drawn(tmp_path / "rr"))
    with pytest.raises(AuditError, match="other settings"):  # the same directory, another space
        run_random_arm(open_campaign(root), SERIAL, count=6, space="bounds", out=tmp_path / "rr")
    # An arm written before --space existed (no "space" in its campaign.json) resumes as random-range.
    arm_meta = read_json(tmp_path / "rr" / "campaign.json")
    del arm_meta["settings"]["space"]
    (tmp_path / "rr" / "campaign.json").write_text(json.dumps(arm_meta))
    again = run_random_arm(open_campaign(root), SERIAL, count=6, space="random-range", out=tmp_path / "rr")
    assert again["best_any"] == narrow["best_any"]
