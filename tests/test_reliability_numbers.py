"""Untrusted numbers never crash: an integer too large for a float (10**400), or JSON nested too deep
to parse, is an invalid proposal, a failed run with its reason, or a one-line error (issue 29, item 1)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from llm_support import FakeServer, chat_reply, openai_client
from loop_helpers import TOY_FAMILY, ScriptedProposer, copy_toy, run_loop

from autoresearch.campaign import CampaignMeta
from autoresearch.campaign.check import check_campaign
from autoresearch.execution.protocol import check_final_metric, parse_progress
from autoresearch.execution.runner import run_locally
from autoresearch.execution.spec import RunSpec
from autoresearch.family import Family, FamilyError
from autoresearch.journal import read_jsonl
from autoresearch.loop.orchestrator import LoopSettings, Orchestrator
from autoresearch.loop.stopping import Budgets
from autoresearch.proposers.tools import PROPOSE
from autoresearch.space import SearchSpace, SpaceError, ValidationError

HUGE = 10**400  # an integer literal float() cannot hold: math.isfinite raises OverflowError on it
HUGE_TEXT = "1" + "0" * 400


def _loop_cli(*args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "autoresearch", "loop", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=60,
    )


def _call(overrides: dict) -> tuple[str, str]:
    return (
        PROPOSE,
        json.dumps(
            {
                "hypothesis": "A larger step.",
                "overrides": overrides,
                "axes": ["optimizer"],
                "expected_mechanism": "Faster descent.",
                "comparison_to_best": "Larger than the best run's.",
                "failure_prediction": {"metric": 1.0, "direction": "above"},
            }
        ),
    )


def _meta(toy, campaign, proposer: str) -> None:
    """campaign.json as ``autoresearch loop`` writes it, so ``check`` reads the campaign."""
    if not campaign.exists():
        campaign.mkdir()
        CampaignMeta.new(Family.load(toy), proposer, {"timeout_per_run": 60.0}).write(campaign)


def _openai_loop(toy, campaign, server: FakeServer, max_iters: int):
    family = Family.load(toy)
    _meta(toy, campaign, "openai")
    client = openai_client(server)  # the test skips here without the [llm] extra
    from autoresearch.proposers.openai_api import OpenAIProposer

    proposer = OpenAIProposer(family.registry, client=client, model="gpt-5.4")
    settings = LoopSettings("openai", Budgets(max_iters=max_iters), timeout_per_run=60.0)
    Orchestrator(family, proposer, campaign, settings).run()
    return read_jsonl(campaign / "proposals.jsonl")


def test_an_llm_proposal_of_a_huge_integer_is_invalid_and_the_campaign_resumes(tmp_path):
    toy, campaign = copy_toy(tmp_path), tmp_path / "c"
    server = FakeServer(
        chat_reply(tool_calls=[_call({"LEARNING_RATE": HUGE})]),
        chat_reply(tool_calls=[_call({"EPOCHS": HUGE})]),
    )
    assert HUGE_TEXT in server.replies[0].content.decode()  # the literal as a server would send it
    records = _openai_loop(toy, campaign, server, max_iters=3)
    assert [r["status"] for r in records] == ["ran", "invalid", "invalid", "stopped"]
    assert "LEARNING_RATE" in records[1]["reason"] and "outside" in records[1]["reason"]
    assert "EPOCHS" in records[2]["reason"] and "outside [0, 60]" in records[2]["reason"]
    resumed = _openai_loop(toy, campaign, FakeServer(chat_reply(tool_calls=[_call({"EPOCHS": 12})])), 4)
    assert [r["status"] for r in resumed] == ["ran", "invalid", "invalid", "stopped", "ran", "stopped"]
    assert check_campaign(campaign).problems == []


@pytest.mark.parametrize("value", [HUGE, -HUGE, float("inf")], ids=["huge", "minus-huge", "inf"])
def test_a_space_refuses_a_value_float_cannot_hold(value):
    registry = json.loads((TOY_FAMILY / "family.json").read_text())
    space = SearchSpace.from_json(registry["search_space"], tuple(registry["axes"]))
    for name in ("LEARNING_RATE", "MOMENTUM", "EPOCHS", "BATCH_SIZE"):
        with pytest.raises(ValidationError, match=name):
            space.validate({name: value})


@pytest.mark.parametrize("field", ["low", "high"])
def test_a_family_json_bound_too_large_for_a_float_is_a_family_error(tmp_path, field):
    toy = copy_toy(tmp_path)
    registry = json.loads((toy / "family.json").read_text())
    registry["search_space"]["EPOCHS"][field] = -HUGE if field == "low" else HUGE
    (toy / "family.json").write_text(json.dumps(registry))
    assert HUGE_TEXT in (toy / "family.json").read_text()
    with pytest.raises(FamilyError, match=r"search_space\['EPOCHS'\].*finite"):
        Family.load(toy)
    with pytest.raises(SpaceError):
        SearchSpace.from_json({"X": {"type": "categorical", "choices": [1, HUGE], "axis": "a"}}, ("a",))


@pytest.mark.parametrize("field", ["target", "seed_noise"])
def test_a_family_json_number_too_large_for_a_float_is_a_family_error(tmp_path, field):
    toy = copy_toy(tmp_path)
    registry = json.loads((toy / "family.json").read_text())
    registry[field] = HUGE if field == "target" else {"std": HUGE}
    (toy / "family.json").write_text(json.dumps(registry))
    with pytest.raises(FamilyError, match=field):
        Family.load(toy)
    proc = _loop_cli("--family", toy, "--proposer", "random", "--campaign", tmp_path / "c", "--max-iters", 1)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.count("\n") == 1 and field in proc.stderr


def test_an_enqueued_huge_literal_is_a_one_line_usage_error(tmp_path):
    toy = copy_toy(tmp_path)
    queue = tmp_path / "queue.json"
    queue.write_text('{"LEARNING_RATE": ' + HUGE_TEXT + "}")
    args = ("--family", toy, "--proposer", "tpe", "--campaign", tmp_path / "c", "--max-iters", 1)
    proc = _loop_cli(*args, "--enqueue", queue)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.count("\n") == 1 and "--enqueue entry 1: LEARNING_RATE" in proc.stderr
    assert not (tmp_path / "c").exists()


# train.py of the toy copy: EPOCHS 11 reports a loss float() cannot hold, EPOCHS 12 a FINAL_METRIC
# nested deeper than json can parse, EPOCHS 13 a huge (ignored) PROGRESS point, then a valid metric.
_HOSTILE_FINAL = """    line = json.dumps(record)
    if CONFIG["EPOCHS"] == 11:
        line = json.dumps({**record, "loss": 10**400})
    if CONFIG["EPOCHS"] == 12:
        line = "[" * 100000
    if CONFIG["EPOCHS"] == 13:
        print('PROGRESS: {"step": 1, "loss": ' + "1" + "0" * 400 + "}", flush=True)
        print('PROGRESS: {"step": 2, "loss": ' + "[" * 100000 + "}", flush=True)
        print('PROGRESS: {"step": 3, "loss": 0.5}', flush=True)
"""


def _hostile_toy(tmp_path):
    toy = copy_toy(tmp_path)
    source = (toy / "train.py").read_text()
    source = source.replace("    line = json.dumps(record)\n", _HOSTILE_FINAL, 1)
    assert "10**400" in source
    (toy / "train.py").write_text(source)
    return toy


def test_a_final_metric_float_cannot_hold_fails_the_run_and_resume_works(tmp_path):
    toy, campaign = _hostile_toy(tmp_path), tmp_path / "c"
    _meta(toy, campaign, "scripted")
    _, records = run_loop(toy, ScriptedProposer([{"EPOCHS": 11}, {"EPOCHS": 12}]), campaign, max_iters=3)
    assert [r["status"] for r in records] == ["ran", "failed", "failed", "stopped"]
    assert "'loss'" in records[1]["reason"] and "too large" in records[1]["reason"]
    assert "FINAL_METRIC is not valid JSON" in records[2]["reason"]
    _, records = run_loop(toy, ScriptedProposer([{"EPOCHS": 14}]), campaign, max_iters=4)
    assert [r["status"] for r in records][-2:] == ["ran", "stopped"]
    # the unparsable line train.py also appended to runs.jsonl is reported, not a crash of check
    (problem,) = check_campaign(campaign).problems
    assert problem.where == "runs.jsonl:3" and "not a JSON line" in problem.what


def test_the_adopted_runs_log_line_of_a_huge_metric_is_a_failed_run():
    value, reason = check_final_metric({"run_id": "a", "loss": HUGE}, "loss", "a")
    assert value is None and "too large" in reason
    value, reason = check_final_metric({"run_id": "a", "loss": 0.5, "aux": [{"x": HUGE}]}, "loss", "a")
    assert value is None and "too large" in reason and "aux" in reason


def test_a_huge_or_too_deep_progress_point_is_ignored(tmp_path):
    toy = _hostile_toy(tmp_path)
    family = Family.load(toy)
    run_dir = tmp_path / "run"
    config = {**family.baseline_config, "EPOCHS": 13}
    result = run_locally(RunSpec(family, config, "r", 0, run_dir, tmp_path / "runs.jsonl", 60))
    assert result.ok and result.progress == [{"step": 3, "value": 0.5}]
    assert parse_progress('PROGRESS: {"step": ' + HUGE_TEXT + ', "loss": 1}', "loss") is None
