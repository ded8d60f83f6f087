"""The campaign store owns the format: typed records of both schemas, every committed campaign loads
and checks, the write path computes verdicts and bests once, and a published campaign is valid."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from loop_helpers import TOY_OPTIMUM, ScriptedProposer, copy_toy, run_loop

from autoresearch.campaign import Campaign, CampaignError, CampaignMeta, Record, Status
from autoresearch.campaign.audit_log import read_audit, write_step
from autoresearch.campaign.check import PUBLISHED, check_campaign
from autoresearch.campaign.group import GROUP_FILE, GroupMeta, is_group, repeat_dirs
from autoresearch.family import Family

ROOT = Path(__file__).resolve().parents[1]
COMMITTED = sorted(
    p.parent for p in (ROOT / "results").rglob("campaign.json") if (p.parent / "proposals.jsonl").exists()
)


def test_a_schema_1_record_reads_into_the_same_record_type():
    legacy = {
        "iteration": 3,
        "status": "pruned",
        "record": {"run_id": "it0003", "loss": 1.0},
        "run_id": "it0003",
        "reason": "stopped early at step 2",
    }
    record = Record.from_json(legacy)
    assert record.status is Status.EARLY_STOPPED and record.schema == 1
    assert record.final_metric == {"run_id": "it0003", "loss": 1.0}
    written = record.to_json()
    assert written["status"] == "early_stopped" and written["schema"] == 2 and "record" not in written
    assert Record.from_json(written) == record.replace(schema=2)


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"status": "ran"}, "no iteration"),
        ({"iteration": 0, "status": "ran"}, "no iteration"),
        ({"iteration": 1, "status": "exploded"}, "unknown status 'exploded'"),
        ({"iteration": 1, "status": "ran", "colour": "red"}, r"unknown fields \['colour'\]"),
        ([1, 2], "not a JSON object"),
    ],
)
def test_a_bad_record_is_refused_naming_what_is_wrong(data, message):
    with pytest.raises(CampaignError, match=message):
        Record.from_json(data)


@pytest.mark.parametrize("root", COMMITTED, ids=[str(p.relative_to(ROOT)) for p in COMMITTED])
def test_every_committed_campaign_loads_and_checks_clean(root):
    records = Campaign(root).records()
    assert records and all(isinstance(r.status, Status) for r in records)
    result = check_campaign(root)
    assert result.problems == [] and PUBLISHED in result.notes  # committed without runs/


def test_the_write_path_computes_the_verdict_and_the_best_so_far_once(tmp_path):
    toy = copy_toy(tmp_path)
    run_loop(toy, ScriptedProposer([TOY_OPTIMUM]), tmp_path / "c", max_iters=3, stop_at_target=True)
    store = Campaign(tmp_path / "c")
    records = store.records()
    assert [r.status for r in records] == [Status.RAN, Status.RAN, Status.STOPPED]
    assert records[-1].trigger == "target_reached"
    assert records[0].verdict == "baseline" and records[1].best_so_far == records[1].metric
    assert all(r.schema == 2 for r in records)
    state = store.state(Family.load(toy))
    assert state.best == records[1] and store.running_best()["run_id"] == records[1].run_id
    raw = [json.loads(line) for line in (tmp_path / "c" / "proposals.jsonl").read_text().splitlines()]
    assert raw[1]["final_metric"]["run_id"] == "it0002" and "record" not in raw[1]


def test_a_published_campaign_still_shows_real_damage(tmp_path):
    toy = copy_toy(tmp_path)
    run_loop(toy, ScriptedProposer([TOY_OPTIMUM]), tmp_path / "c", max_iters=2)
    CampaignMeta.new(Family.load(toy), "scripted", {}).write(tmp_path / "c")  # as the CLI writes it
    for run_dir in sorted((tmp_path / "c" / "runs").iterdir()):
        for path in sorted(run_dir.rglob("*"), reverse=True):
            path.unlink() if path.is_file() else path.rmdir()
        run_dir.rmdir()
    (tmp_path / "c" / "runs").rmdir()
    result = check_campaign(tmp_path / "c")
    assert result.problems == [] and result.notes == [PUBLISHED]
    lines = (tmp_path / "c" / "proposals.jsonl").read_text().splitlines(keepends=True)
    (tmp_path / "c" / "proposals.jsonl").write_text("".join(lines[1:]))  # iteration 1 lost
    problems = check_campaign(tmp_path / "c").problems
    assert any("iteration 1 is missing" in p.what for p in problems)


@pytest.mark.parametrize("group", ["results/compare/dock-tpe", "results/compare-rendezvous/rdv-gp"])
def test_a_committed_group_reads_as_typed_and_writes_back_the_same_bytes(group, tmp_path):
    meta = GroupMeta.read(ROOT / group)
    assert is_group(ROOT / group) and meta.repeats == len(meta.seeds) == len(repeat_dirs(ROOT / group))
    meta.write(tmp_path)
    assert (tmp_path / GROUP_FILE).read_bytes() == (ROOT / group / GROUP_FILE).read_bytes()


def test_the_store_owns_audit_json_and_the_step_directories(tmp_path):
    paths = Campaign(tmp_path).paths
    assert read_audit(tmp_path) == {}
    write_step(tmp_path, "verify", {"status": "running"})
    write_step(tmp_path, "noise", {"status": "done"})
    write_step(tmp_path, "verify", {"status": "done"})
    assert json.loads(paths.audit_json.read_text()) == {
        "verify": {"status": "done"},
        "noise": {"status": "done"},
    }
    assert read_audit(tmp_path) == json.loads(paths.audit_json.read_text())
    assert paths.step_dir("prune") == tmp_path / "audit" / "prune"
