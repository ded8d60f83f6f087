"""The two tool schemas come from the registry; malformed calls become invalid proposals."""

from __future__ import annotations

import copy
import json

import pytest
from llm_support import PROPOSAL_INPUT, REGISTRY, STOP_INPUT

from autoresearch.proposers.tools import (
    FIELD_LIMITS,
    LOCAL_UNSUPPORTED,
    PROPOSE,
    STOP,
    STOP_STATUSES,
    anthropic_tools,
    openai_tools,
    parse_tool_call,
    safe_text,
    strip_keywords,
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


@pytest.mark.parametrize(
    ("arguments", "reason"),
    [
        (
            PROPOSAL_INPUT | {"hypothesis": "h" * 2001},
            "'hypothesis' is 2001 characters long; the limit is 2000",
        ),
        (PROPOSAL_INPUT | {"expected_mechanism": "m" * 5000}, "'expected_mechanism' is 5000 characters"),
        (PROPOSAL_INPUT | {"comparison_to_best": "c" * 2001}, "'comparison_to_best' is 2001"),
        (
            PROPOSAL_INPUT
            | {"failure_prediction": {"metric": 6.0, "direction": "above", "description": "d" * 1001}},
            "failure_prediction.'description' is 1001",
        ),
        (
            PROPOSAL_INPUT | {"failure_prediction": {"metric": 6.0, "direction": "above", "x": 1}},
            "unknown keys",
        ),
        (PROPOSAL_INPUT | {"overrides": {"ACTIVATION": "r" * 201}}, "a string of 201 characters"),
        (PROPOSAL_INPUT | {"overrides": {f"P{i}": 1 for i in range(65)}}, "'overrides' has 65 entries"),
        (PROPOSAL_INPUT | {"axes": ["data"] * 65}, "'axes' has 65 entries"),
    ],
)
def test_a_too_long_field_is_an_invalid_proposal_with_that_reason(arguments, reason):
    proposal = parse_tool_call(PROPOSE, arguments, REGISTRY)
    assert proposal.kind == "invalid" and reason in proposal.error
    assert len(proposal.error) < 400  # the reason quotes no runaway value


def test_the_schemas_state_the_limits():
    schema = tool_specs(REGISTRY)[0]["schema"]["properties"]
    assert schema["hypothesis"]["maxLength"] == FIELD_LIMITS["hypothesis"]
    assert (
        tool_specs(REGISTRY)[1]["schema"]["properties"]["conclusion"]["maxLength"]
        == FIELD_LIMITS["conclusion"]
    )


def test_control_characters_are_escaped_in_every_string_of_a_proposal():
    hostile = PROPOSAL_INPUT | {
        "hypothesis": "a\x1b]0;pwn\x07b",
        "expected_mechanism": "c\u202ed\x9be",
        "overrides": {"ACTIVATION": "tanh\x1b[2J"},
        "failure_prediction": {"metric": 6.0, "direction": "above", "description": "\x00x"},
    }
    proposal = parse_tool_call(PROPOSE, hostile, REGISTRY)
    assert proposal.annotation["hypothesis"] == "a\\x1b]0;pwn\\x07b"
    assert proposal.annotation["expected_mechanism"] == "c\\u202ed\\x9be"
    assert proposal.overrides == {"ACTIVATION": "tanh\\x1b[2J"}
    assert proposal.annotation["failure_prediction"]["description"] == "\\x00x"
    assert safe_text("line one\n\tline two") == "line one\n\tline two"
    bad = parse_tool_call("\x1b[31mrun", {}, REGISTRY)
    assert "\x1b" not in bad.error


def test_local_form_drops_the_keywords_local_backends_reject():
    local = json.dumps(openai_tools(REGISTRY, local=True))
    assert all(f'"{k}"' not in local for k in LOCAL_UNSUPPORTED)
    assert '"uniqueItems"' in json.dumps(openai_tools(REGISTRY))
    registry = copy.deepcopy(REGISTRY)
    registry["search_space"]["maxLength"] = {"type": "int", "low": 1, "high": 9, "axis": "data"}
    overrides = strip_keywords(tool_specs(registry)[0]["schema"])["properties"]["overrides"]["properties"]
    assert "maxLength" in overrides  # a parameter named like a keyword stays
