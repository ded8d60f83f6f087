"""The two tool schemas come from the registry; malformed calls become invalid proposals."""

from __future__ import annotations

import copy
import json

import pytest
from llm_support import PROPOSAL_INPUT, REGISTRY, STOP_INPUT

from autoresearch.proposers.tools import (
    PROPOSE,
    STOP,
    STOP_STATUSES,
    anthropic_tools,
    openai_tools,
    parse_tool_call,
    tool_specs,
)


def test_schemas_follow_the_registry():
    propose, stop = tool_specs(REGISTRY)
    assert (propose["name"], stop["name"]) == (PROPOSE, STOP)

    schema = propose["schema"]
    assert set(schema["required"]) == {
        "hypothesis",
        "overrides",
        "axes",
        "expected_mechanism",
        "comparison_to_best",
        "failure_prediction",
    }
    overrides = schema["properties"]["overrides"]
    assert overrides["type"] == "object" and overrides["additionalProperties"] is False
    props = overrides["properties"]
    assert list(props) == list(REGISTRY["search_space"])
    assert props["N_DEMOS"]["enum"] == [32, 64, 128, 256]
    assert props["ACTIVATION"]["enum"] == ["tanh", "relu", "gelu"]
    epochs = props["EPOCHS"]
    assert (epochs["type"], epochs["minimum"], epochs["maximum"]) == ("integer", 10, 120)
    assert props["LEARNING_RATE"]["type"] == "number" and "log scale" in props["LEARNING_RATE"]["description"]
    assert props["DROPOUT"]["exclusiveMaximum"] == 0.5 and "maximum" not in props["DROPOUT"]
    assert props["RUNTIME_CBF_FILTER"]["type"] == "boolean"

    axes = schema["properties"]["axes"]
    assert axes["items"]["enum"] == REGISTRY["axes"] and axes["minItems"] == 1
    kill = schema["properties"]["failure_prediction"]
    assert kill["properties"]["metric"]["type"] == "number"
    assert kill["required"] == ["metric", "direction"]

    stop_schema = stop["schema"]
    assert stop_schema["properties"]["status"]["enum"] == list(STOP_STATUSES)
    assert stop_schema["properties"]["axes_tested"]["items"]["enum"] == REGISTRY["axes"]
    assert set(stop_schema["required"]) == {"status", "conclusion", "axes_tested"}


def test_schemas_carry_no_answer_bearing_field():
    text = json.dumps(tool_specs(REGISTRY))
    for value in (REGISTRY["target"], REGISTRY["baseline"]["metric"], REGISTRY["seed_noise"]["mean"]):
        assert str(value) not in text


def test_provider_forms_wrap_the_same_schemas():
    specs = tool_specs(REGISTRY)
    assert [t["input_schema"] for t in anthropic_tools(REGISTRY)] == [s["schema"] for s in specs]
    functions = openai_tools(REGISTRY)
    assert [f["type"] for f in functions] == ["function", "function"]
    assert [f["function"]["parameters"] for f in functions] == [s["schema"] for s in specs]


def test_unknown_parameter_type_is_a_registry_error():
    registry = copy.deepcopy(REGISTRY)
    registry["search_space"]["EPOCHS"]["type"] = "integer"
    with pytest.raises(ValueError, match=r"EPOCHS.*unknown type 'integer'"):
        tool_specs(registry)


def test_propose_call_becomes_a_proposal():
    proposal = parse_tool_call(PROPOSE, PROPOSAL_INPUT, REGISTRY)
    assert proposal.kind == "propose" and proposal.error is None
    assert proposal.overrides == {"N_DEMOS": 128}
    assert proposal.annotation["axes"] == ["data"]
    assert proposal.annotation["failure_prediction"] == {"metric": 6.0, "direction": "above"}
    assert proposal.annotation["hypothesis"] == PROPOSAL_INPUT["hypothesis"]


def test_json_text_arguments_are_decoded():
    assert parse_tool_call(PROPOSE, json.dumps(PROPOSAL_INPUT), REGISTRY).kind == "propose"
    bad = parse_tool_call(PROPOSE, '{"hypothesis": ', REGISTRY)
    assert bad.kind == "invalid" and "not valid JSON" in bad.error


def test_stop_call_becomes_a_stop():
    proposal = parse_tool_call(STOP, STOP_INPUT, REGISTRY)
    assert proposal.kind == "stop" and proposal.overrides == {}
    assert proposal.annotation == STOP_INPUT


def _without(key):
    return {k: v for k, v in PROPOSAL_INPUT.items() if k != key}


@pytest.mark.parametrize(
    ("arguments", "reason"),
    [
        (_without("hypothesis"), "'hypothesis' must be a non-empty string"),
        (_without("overrides"), "'overrides' must be a non-empty object"),
        (_without("failure_prediction"), "'failure_prediction' must be an object"),
        (PROPOSAL_INPUT | {"overrides": "N_DEMOS=128"}, "'overrides' must be a non-empty object"),
        (PROPOSAL_INPUT | {"overrides": {}}, "'overrides' must be a non-empty object"),
        (PROPOSAL_INPUT | {"axes": []}, "'axes' must name at least one axis"),
        (PROPOSAL_INPUT | {"axes": "data"}, "'axes' must be a list"),
        (PROPOSAL_INPUT | {"axes": ["data", "vibes"]}, "outside the taxonomy"),
        (PROPOSAL_INPUT | {"failure_prediction": {"metric": "6.0", "direction": "above"}}, "finite number"),
        (PROPOSAL_INPUT | {"failure_prediction": {"metric": True, "direction": "above"}}, "finite number"),
        (PROPOSAL_INPUT | {"failure_prediction": {"metric": 6.0, "direction": "worse"}}, "direction"),
        (PROPOSAL_INPUT | {"comparison_to_best": "  "}, "'comparison_to_best' must be a non-empty string"),
        ([PROPOSAL_INPUT], "arguments must be an object"),
    ],
)
def test_malformed_propose_is_invalid_with_a_reason(arguments, reason):
    proposal = parse_tool_call(PROPOSE, arguments, REGISTRY)
    assert proposal.kind == "invalid"
    assert proposal.error.startswith(f"malformed {PROPOSE} call: ")
    assert reason in proposal.error


@pytest.mark.parametrize(
    ("arguments", "reason"),
    [
        (STOP_INPUT | {"status": "done"}, "'status' must be one of"),
        (STOP_INPUT | {"conclusion": None}, "'conclusion' must be a non-empty string"),
        (STOP_INPUT | {"axes_tested": ["everything"]}, "outside the taxonomy"),
    ],
)
def test_malformed_stop_is_invalid_with_a_reason(arguments, reason):
    proposal = parse_tool_call(STOP, arguments, REGISTRY)
    assert proposal.kind == "invalid" and reason in proposal.error


def test_unknown_tool_is_invalid():
    proposal = parse_tool_call("run_shell", {"cmd": "ls"}, REGISTRY)
    assert proposal.kind == "invalid" and "unknown tool 'run_shell'" in proposal.error
