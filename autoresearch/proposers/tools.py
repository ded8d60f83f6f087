"""The two tools an LLM proposer must choose between, and the parsing of its call into a Proposal.

The schemas are built from the family registry, so the model sees the real parameter names, bounds
and axis taxonomy. They use only ``metric``, ``direction``, ``axes`` and ``search_space``: nothing
answer-bearing (target, baseline, best) can leak through them in blind mode.

Parsing checks the annotation's shape only. Override names and values are checked by the
orchestrator against the search space, which records its own reason for a refusal.
"""

from __future__ import annotations

import json
import math
from typing import Any

from autoresearch.proposers.base import Proposal

PROPOSE = "propose_experiment"
STOP = "stop_research"
STOP_STATUSES = ("target_met", "exhausted", "plateau", "other")
FAILURE_DIRECTIONS = ("above", "below")


def _parameter_schema(name: str, spec: dict[str, Any]) -> dict[str, Any]:
    kind = spec.get("type")
    axis = f"axis: {spec.get('axis')}"
    if kind == "bool":
        return {"type": "boolean", "description": axis}
    if kind == "categorical":
        return {"enum": list(spec["choices"]), "description": axis}
    if kind not in ("int", "real", "log-real"):
        raise ValueError(f"search_space[{name!r}]: unknown type {kind!r}")
    schema: dict[str, Any] = {"type": "integer" if kind == "int" else "number", "minimum": spec["low"]}
    schema["exclusiveMaximum" if spec.get("high_exclusive") else "maximum"] = spec["high"]
    scale = "; search it on a log scale" if kind == "log-real" else ""
    schema["description"] = f"{axis}{scale}"
    return schema


def _axes_schema(axes: list[str], min_items: int) -> dict[str, Any]:
    return {"type": "array", "items": {"enum": axes}, "minItems": min_items, "uniqueItems": True}


def tool_specs(registry: dict[str, Any]) -> list[dict[str, Any]]:
    """The two tools as provider-neutral {name, description, schema} dicts."""
    metric, direction, axes = registry["metric"], registry["direction"], list(registry["axes"])
    overrides = {
        "type": "object",
        "properties": {
            name: _parameter_schema(name, spec) for name, spec in registry["search_space"].items()
        },
        "additionalProperties": False,
        "minProperties": 1,
        "description": "New values for some editable parameters; the others keep their current values.",
    }
    failure_prediction = {
        "type": "object",
        "properties": {
            "metric": {"type": "number", "description": f"Kill threshold on {metric}."},
            "direction": {
                "enum": list(FAILURE_DIRECTIONS),
                "description": f"The hypothesis is refuted if {metric} lands on this side of the threshold.",
            },
            "description": {"type": "string", "description": "Optional: what else would refute it."},
        },
        "required": ["metric", "direction"],
        "additionalProperties": False,
    }
    propose = {
        "type": "object",
        "properties": {
            "hypothesis": {"type": "string", "description": "What you expect this change to do, and why."},
            "overrides": overrides,
            "axes": _axes_schema(axes, 1)
            | {"description": "Which axes of the search space this move touches."},
            "expected_mechanism": {"type": "string", "description": "The mechanism behind the effect."},
            "comparison_to_best": {
                "type": "string",
                "description": "How this configuration differs from the best so far, and the expected effect.",
            },
            "failure_prediction": failure_prediction,
        },
        "required": [
            "hypothesis",
            "overrides",
            "axes",
            "expected_mechanism",
            "comparison_to_best",
            "failure_prediction",
        ],
        "additionalProperties": False,
    }
    stop = {
        "type": "object",
        "properties": {
            "status": {"enum": list(STOP_STATUSES)},
            "conclusion": {"type": "string", "description": "What the campaign established, with evidence."},
            "axes_tested": _axes_schema(axes, 0) | {"description": "Every axis the campaign exercised."},
        },
        "required": ["status", "conclusion", "axes_tested"],
        "additionalProperties": False,
    }
    return [
        {
            "name": PROPOSE,
            "description": f"Run one experiment: a training run of the edited configuration, scored by "
            f"{metric} ({direction}). State a falsifiable hypothesis and a numerical kill criterion first.",
            "schema": propose,
        },
        {
            "name": STOP,
            "description": "End the research campaign. Accepted only when the target is met, or after enough "
            "experiments across several axes; a refused stop comes back as a warning.",
            "schema": stop,
        },
    ]


def anthropic_tools(registry: dict[str, Any]) -> list[dict[str, Any]]:
    """The tools in the Messages API form."""
    return [
        {"name": t["name"], "description": t["description"], "input_schema": t["schema"]}
        for t in tool_specs(registry)
    ]


def openai_tools(registry: dict[str, Any]) -> list[dict[str, Any]]:
    """The tools in the Chat Completions function form."""
    return [
        {
            "type": "function",
            "function": {"name": t["name"], "description": t["description"], "parameters": t["schema"]},
        }
        for t in tool_specs(registry)
    ]


class _Malformed(ValueError):
    pass


def _text(data: dict[str, Any], key: str) -> str:
    value = data.get(key)
    if not isinstance(value, str) or not value.strip():
        raise _Malformed(f"{key!r} must be a non-empty string, got {value!r}")
    return value


def _axes(data: dict[str, Any], key: str, taxonomy: list[str], *, allow_empty: bool) -> list[str]:
    value = data.get(key)
    if not isinstance(value, list) or not all(isinstance(a, str) for a in value):
        raise _Malformed(f"{key!r} must be a list of axis names, got {value!r}")
    if not value and not allow_empty:
        raise _Malformed(f"{key!r} must name at least one axis")
    unknown = [a for a in value if a not in taxonomy]
    if unknown:
        raise _Malformed(f"{key!r} has axes outside the taxonomy {taxonomy}: {unknown}")
    return list(dict.fromkeys(value))


def _failure_prediction(data: dict[str, Any]) -> dict[str, Any]:
    value = data.get("failure_prediction")
    if not isinstance(value, dict):
        raise _Malformed(f"'failure_prediction' must be an object, got {value!r}")
    threshold = value.get("metric")
    # bool is an int subclass; a kill criterion of `true` is not a number.
    if isinstance(threshold, bool) or not isinstance(threshold, (int, float)) or not math.isfinite(threshold):
        raise _Malformed(f"'failure_prediction.metric' must be a finite number, got {threshold!r}")
    if value.get("direction") not in FAILURE_DIRECTIONS:
        raise _Malformed(
            f"'failure_prediction.direction' must be one of {list(FAILURE_DIRECTIONS)}, "
            f"got {value.get('direction')!r}"
        )
    description = value.get("description")
    if description is not None and not isinstance(description, str):
        raise _Malformed(f"'failure_prediction.description' must be a string, got {description!r}")
    return dict(value)


def _parse(name: str, data: Any, taxonomy: list[str]) -> Proposal:
    if isinstance(data, str):  # Chat Completions sends the arguments as JSON text
        try:
            data = json.loads(data)
        except json.JSONDecodeError as err:
            raise _Malformed(f"arguments are not valid JSON ({err})") from None
    if not isinstance(data, dict):
        raise _Malformed(f"arguments must be an object, got {type(data).__name__}")
    if name == PROPOSE:
        overrides = data.get("overrides")
        if not isinstance(overrides, dict) or not overrides:
            raise _Malformed(f"'overrides' must be a non-empty object, got {overrides!r}")
        annotation = {
            "hypothesis": _text(data, "hypothesis"),
            "axes": _axes(data, "axes", taxonomy, allow_empty=False),
            "expected_mechanism": _text(data, "expected_mechanism"),
            "comparison_to_best": _text(data, "comparison_to_best"),
            "failure_prediction": _failure_prediction(data),
        }
        return Proposal(kind="propose", overrides=dict(overrides), annotation=annotation)
    if name == STOP:
        status = data.get("status")
        if status not in STOP_STATUSES:
            raise _Malformed(f"'status' must be one of {list(STOP_STATUSES)}, got {status!r}")
        annotation = {
            "status": status,
            "conclusion": _text(data, "conclusion"),
            "axes_tested": _axes(data, "axes_tested", taxonomy, allow_empty=True),
        }
        return Proposal(kind="stop", annotation=annotation)
    raise _Malformed(f"unknown tool {name!r}; expected {PROPOSE!r} or {STOP!r}")


def parse_tool_call(name: str, arguments: Any, registry: dict[str, Any]) -> Proposal:
    """One tool call (input dict, or JSON text) -> Proposal; malformed input -> kind "invalid"."""
    try:
        return _parse(name, arguments, list(registry["axes"]))
    except _Malformed as err:
        return Proposal(kind="invalid", error=f"malformed {name} call: {err}")
