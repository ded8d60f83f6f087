"""One result shape: the Split enum and ScoredRun read every FINAL_METRIC shape a family prints or
printed, the protocol checks what a run scored on a split must hold, and an audit step's rows read
the same whether written now or before the shape existed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from autoresearch.audit.progress import _outcome
from autoresearch.campaign.audit_log import StepLog, TrialRow
from autoresearch.execution.protocol import check_split
from autoresearch.splits import Score, ScoredRun, Split, split_parts

ROOT = Path(__file__).resolve().parents[1]


def feasible(metrics: dict) -> bool:
    return metrics.get("ok") is True


def read(final_metric: dict) -> ScoredRun:
    return ScoredRun.read(final_metric, "loss", feasible)


SEARCH = {"loss": 1.0, "ok": True}
TEST = {"loss": 2.0, "ok": False}
NOW_SEARCH = {"run_id": "r", **SEARCH, "splits": {"search": SEARCH}, "eval_split": "search", "seed": 0}
NOW_TEST = {
    "run_id": "r",
    **TEST,
    "splits": {"search": SEARCH, "test": TEST},
    "eval_split": "test",
    "seed": 0,
}
BEFORE_TEST = {"run_id": "r", **TEST, "search_split": SEARCH, "eval_split": "test", "seed": 0}  # until 0.x
PLAIN = {"run_id": "r", **SEARCH, "seed": 0}  # a family that prints no splits (the minimal template)


def test_a_split_is_its_value_in_json_text_and_choices():
    assert Split("test") is Split.TEST and Split.SEARCH == "search"
    assert f"{Split.TEST} split" == "test split" and str(Split.SEARCH) == "search"
    assert json.dumps({"split": Split.TEST}) == '{"split": "test"}'
    assert [s.value for s in Split] == ["search", "test"]


@pytest.mark.parametrize("final_metric", [NOW_SEARCH, PLAIN])
def test_a_search_run_scores_on_the_search_split_only(final_metric):
    assert read(final_metric) == ScoredRun(Score(1.0, True))
    assert read(final_metric).on(Split.TEST) is None


@pytest.mark.parametrize("final_metric", [NOW_TEST, BEFORE_TEST])
def test_a_test_run_reads_the_same_in_either_shape(final_metric):
    scored = read(final_metric)
    assert scored.on(Split.SEARCH) == Score(1.0, True) and scored.on(Split.TEST) == Score(2.0, False)
    assert ScoredRun.from_json(json.loads(json.dumps(scored.to_json()))) == scored
    assert set(split_parts(final_metric)) == {Split.SEARCH, Split.TEST}


@pytest.mark.parametrize(
    ("final_metric", "split", "why"),
    [
        (NOW_SEARCH, Split.SEARCH, None),
        (PLAIN, Split.SEARCH, None),
        (NOW_TEST, Split.TEST, None),
        (BEFORE_TEST, Split.TEST, None),
        (NOW_SEARCH, Split.TEST, "scored on the 'search' split, but the run asked for 'test'"),
        (
            {**NOW_SEARCH, "splits": {"search": SEARCH, "test": TEST}},
            Split.SEARCH,
            "holds test-split metrics",
        ),
        ({**NOW_TEST, "splits": {"test": TEST}}, Split.TEST, "has no splits.search object"),
        ({**NOW_TEST, "splits": {"search": SEARCH}}, Split.TEST, "has no splits.test object"),
        (
            {**NOW_TEST, "splits": {"search": {"ok": True}, "test": TEST}},
            Split.TEST,
            "splits.search has no finite",
        ),
        ({**NOW_TEST, "loss": 3.0}, Split.TEST, "splits.test.loss differs from the 'loss' on top"),
        ({k: v for k, v in BEFORE_TEST.items() if k != "search_split"}, Split.TEST, "no splits.search"),
    ],
)
def test_the_protocol_checks_what_a_run_scored_on_a_split_holds(final_metric, split, why):
    reason = check_split(final_metric, "loss", split)
    assert reason is None if why is None else why in reason


def test_a_trial_row_written_now_reads_back_as_written():
    row = TrialRow("k", "k", 3, "ok", Split.TEST, read(NOW_TEST), 0.5, None, 1.0, 0, {"X": 1}, NOW_TEST)
    data = json.loads(json.dumps(row.to_json()))
    assert data["split"] == "test" and data["scores"]["test"] == {"metric": 2.0, "feasible": False}
    assert TrialRow.from_json(data) == row
    failed = TrialRow("f", "f", 3, "failed", Split.SEARCH, None, None, "boom", 1.0, 1, {"X": 1}, None)
    assert TrialRow.from_json(json.loads(json.dumps(failed.to_json()))) == failed


def test_an_audit_step_shows_each_run_on_the_split_its_gate_judges():
    # NOW_TEST is feasible on the search split and infeasible on the sealed one: a verify line that
    # showed the search split's verdict contradicted the gate's summary below it.
    verify = TrialRow("v-s11", "v-s11", 11, "ok", Split.TEST, read(NOW_TEST), 0.5, None, 9.0, 0, {}, NOW_TEST)
    assert _outcome(verify) == "v-s11 2 on test infeasible (9s)"
    noise = TrialRow(
        "n-s1", "n-s1", 1, "ok", Split.SEARCH, read(NOW_SEARCH), 0.5, None, None, 0, {}, NOW_SEARCH
    )
    assert _outcome(noise) == "n-s1 1"
    failed = TrialRow("f", "f", 3, "failed", Split.TEST, None, None, "boom", 1.0, 1, {}, None)
    assert _outcome(failed) == "f failed"


def test_committed_rows_from_before_the_shape_still_read():
    sealed = StepLog(ROOT / "results" / "sealed" / "rendezvous" / "377583d0" / "trials.jsonl").read()
    first = json.loads(
        (ROOT / "results" / "sealed" / "rendezvous" / "377583d0" / "trials.jsonl").open().readline()
    )
    assert sealed[0].split is Split.TEST and sealed[0].final_metric == first["record"]
    assert sealed[0].on(Split.SEARCH).metric == first["metric"]
    assert sealed[0].on(Split.TEST).metric == first["test"]["metric"]
    searched = StepLog(ROOT / "results" / "rendezvous" / "hand" / "audit" / "verify" / "verify.jsonl").read()
    assert all(r.split is Split.SEARCH and r.on(Split.TEST) is None for r in searched)
    assert [r.on(Split.SEARCH).metric for r in searched if r.ok] == [
        r["metric"]
        for r in map(json.loads, open(ROOT / "results/rendezvous/hand/audit/verify/verify.jsonl"))
        if r["status"] == "ok"
    ]
