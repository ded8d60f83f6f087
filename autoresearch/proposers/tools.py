"""The two tools an LLM proposer must choose between, and the parsing of its call into a Proposal.

The schemas are built from the family registry, so the model sees the real parameter names, bounds
and axis taxonomy. They use only ``metric``, ``direction``, ``axes`` and ``search_space``: nothing
answer-bearing (target, baseline, best) can leak through them in blind mode.

Parsing checks the annotation's shape and size (:data:`FIELD_LIMITS`: a too-long field makes the
call invalid, so no reply can bloat every later prompt) and escapes control characters in every
string the model wrote (:func:`safe_text`), so what is printed from a proposal can never drive the
terminal. Override names and values are checked by the orchestrator against the search space, which
records its own reason for a refusal.
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

from autoresearch.proposers.base import Proposal

PROPOSE = "propose_experiment"
STOP = "stop_research"
STOP_STATUSES = ("target_met", "exhausted", "plateau", "other")
FAILURE_DIRECTIONS = ("above", "below")
# Characters per free-text field, and entries per map or list: generous for a reasoned proposal,
# small enough that a runaway reply cannot fill the context of later prompts.
FIELD_LIMITS = {
    "hypothesis": 2000,
    "expected_mechanism": 2000,
    "comparison_to_best": 2000,
    "conclusion": 4000,
    "description": 1000,
}
MAX_VALUE_CHARS = 200  # one override value (a categorical choice) or name
MAX_ENTRIES = 64  # overrides, axes
# Schema keywords some local guided-decoding back-ends reject (vLLM's, Ollama's).
LOCAL_UNSUPPORTED = ("uniqueItems", "minProperties", "maxLength")

# C0 controls but tab and newline, DEL, C1 controls, and the invisible bidi/format characters that
# can reorder what a terminal shows.
_CONTROL = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u200b-\u200f\u202a-\u202e\u2066-\u2069]")


def safe_text(text: str) -> str:
    """``text`` with control characters written as visible escapes (ESC -> ``\\x1b``)."""
    return _CONTROL.sub(lambda m: m.group().encode("unicode_escape").decode("ascii"), text)


def safe_value(value: Any) -> Any:
    """``value`` with :func:`safe_text` applied to every string in it, keys included."""
    if isinstance(value, str):
        return safe_text(value)
    if isinstance(value, dict):
        return {safe_value(k): safe_value(v) for k, v in value.items()}
    if isinstance(value, list):
        return [safe_value(v) for v in value]
    return value


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


def _text_schema(description: str, field: str) -> dict[str, Any]:
    return {"type": "string", "description": description, "maxLength": FIELD_LIMITS[field]}


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
            "description": _text_schema("Optional: what else would refute it.", "description"),
        },
        "required": ["metric", "direction"],
        "additionalProperties": False,
    }
    propose = {
        "type": "object",
        "properties": {
            "hypothesis": _text_schema("What you expect this change to do, and why.", "hypothesis"),
            "overrides": overrides,
            "axes": _axes_schema(axes, 1)
            | {"description": "Which axes of the search space this move touches."},
            "expected_mechanism": _text_schema("The mechanism behind the effect.", "expected_mechanism"),
            "comparison_to_best": _text_schema(
                "How this configuration differs from the best so far, and the expected effect.",
                "comparison_to_best",
            ),
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
            "conclusion": _text_schema("What the campaign established, with evidence.", "conclusion"),
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


def strip_keywords(schema: Any, keywords: tuple[str, ...] = LOCAL_UNSUPPORTED) -> Any:
    """``schema`` without ``keywords`` at any depth (a property *named* like one is kept)."""
    if isinstance(schema, list):
        return [strip_keywords(s, keywords) for s in schema]
    if not isinstance(schema, dict):
        return schema
    return {
        k: (
            {n: strip_keywords(v, keywords) for n, v in s.items()}
            if k == "properties"
            else strip_keywords(s, keywords)
        )
        for k, s in schema.items()
        if k not in keywords
    }


def anthropic_tools(registry: dict[str, Any]) -> list[dict[str, Any]]:
    """The tools in the Messages API form."""
    return [
        {"name": t["name"], "description": t["description"], "input_schema": t["schema"]}
        for t in tool_specs(registry)
    ]


def openai_tools(registry: dict[str, Any], *, local: bool = False) -> list[dict[str, Any]]:
    """The tools in the Chat Completions function form; ``local`` leaves out the schema keywords
    local guided-decoding back-ends reject (:data:`LOCAL_UNSUPPORTED`)."""
    return [
        {
            "type": "function",
            "function": {
                "name": t["name"],
                "description": t["description"],
                "parameters": strip_keywords(t["schema"]) if local else t["schema"],
            },
        }
        for t in tool_specs(registry)
    ]


class _Malformed(ValueError):
    pass


def _short_repr(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 120 else f"{text[:100]}... ({len(text)} chars)"


def _text(data: dict[str, Any], key: str, *, where: str = "") -> str:
    value = data.get(key)
    if not isinstance(value, str) or not value.strip():
        raise _Malformed(f"{where}{key!r} must be a non-empty string, got {_short_repr(value)}")
    if len(value) > FIELD_LIMITS[key]:
        raise _Malformed(f"{where}{key!r} is {len(value)} characters long; the limit is {FIELD_LIMITS[key]}")
    return safe_text(value)


def _overrides(data: dict[str, Any]) -> dict[str, Any]:
    overrides = data.get("overrides")
    if not isinstance(overrides, dict) or not overrides:
        raise _Malformed(f"'overrides' must be a non-empty object, got {_short_repr(overrides)}")
    if len(overrides) > MAX_ENTRIES:
        raise _Malformed(f"'overrides' has {len(overrides)} entries; the limit is {MAX_ENTRIES}")
    for name, value in overrides.items():
        for text in (name, value):
            if isinstance(text, str) and len(text) > MAX_VALUE_CHARS:
                raise _Malformed(
                    f"'overrides' holds a string of {len(text)} characters; the limit is {MAX_VALUE_CHARS}"
                )
    return safe_value(dict(overrides))


def _axes(data: dict[str, Any], key: str, taxonomy: list[str], *, allow_empty: bool) -> list[str]:
    value = data.get(key)
    if not isinstance(value, list) or not all(isinstance(a, str) for a in value):
        raise _Malformed(f"{key!r} must be a list of axis names, got {_short_repr(value)}")
    if len(value) > MAX_ENTRIES:
        raise _Malformed(f"{key!r} has {len(value)} entries; the limit is {MAX_ENTRIES}")
    if not value and not allow_empty:
        raise _Malformed(f"{key!r} must name at least one axis")
    unknown = [a for a in value if a not in taxonomy]
    if unknown:
        raise _Malformed(f"{key!r} has axes outside the taxonomy {taxonomy}: {_short_repr(unknown)}")
    return list(dict.fromkeys(value))


def _failure_prediction(data: dict[str, Any]) -> dict[str, Any]:
    value = data.get("failure_prediction")
    if not isinstance(value, dict):
        raise _Malformed(f"'failure_prediction' must be an object, got {_short_repr(value)}")
    threshold = value.get("metric")
    # bool is an int subclass; a kill criterion of `true` is not a number.
    if isinstance(threshold, bool) or not isinstance(threshold, (int, float)) or not math.isfinite(threshold):
        raise _Malformed(f"'failure_prediction.metric' must be a finite number, got {_short_repr(threshold)}")
    if value.get("direction") not in FAILURE_DIRECTIONS:
        raise _Malformed(
            f"'failure_prediction.direction' must be one of {list(FAILURE_DIRECTIONS)}, "
            f"got {_short_repr(value.get('direction'))}"
        )
    extra = set(value) - {"metric", "direction", "description"}
    if extra:
        raise _Malformed(f"'failure_prediction' has unknown keys {_short_repr(sorted(map(str, extra)))}")
    if value.get("description") is not None:
        _text(value, "description", where="failure_prediction.")
    return safe_value(dict(value))


def _parse(name: str, data: Any, taxonomy: list[str]) -> Proposal:
    if isinstance(data, str):  # Chat Completions sends the arguments as JSON text
        try:
            data = json.loads(data)
        except json.JSONDecodeError as err:
            raise _Malformed(f"arguments are not valid JSON ({err})") from None
    if not isinstance(data, dict):
        raise _Malformed(f"arguments must be an object, got {type(data).__name__}")
    if name == PROPOSE:
        overrides = _overrides(data)
        annotation = {
            "hypothesis": _text(data, "hypothesis"),
            "axes": _axes(data, "axes", taxonomy, allow_empty=False),
            "expected_mechanism": _text(data, "expected_mechanism"),
            "comparison_to_best": _text(data, "comparison_to_best"),
            "failure_prediction": _failure_prediction(data),
        }
        return Proposal(kind="propose", overrides=overrides, annotation=annotation)
    if name == STOP:
        status = data.get("status")
        if status not in STOP_STATUSES:
            raise _Malformed(f"'status' must be one of {list(STOP_STATUSES)}, got {_short_repr(status)}")
        annotation = {
            "status": status,
            "conclusion": _text(data, "conclusion"),
            "axes_tested": _axes(data, "axes_tested", taxonomy, allow_empty=True),
        }
        return Proposal(kind="stop", annotation=annotation)
    raise _Malformed(f"unknown tool {_short_repr(name)}; expected {PROPOSE!r} or {STOP!r}")


def parse_tool_call(name: str, arguments: Any, registry: dict[str, Any]) -> Proposal:
    """One tool call (input dict, or JSON text) -> Proposal; malformed input -> kind "invalid"."""
    try:
        return _parse(name, arguments, list(registry["axes"]))
    except _Malformed as err:
        return Proposal(kind="invalid", error=safe_text(f"malformed {_short_repr(name)[1:-1]} call: {err}"))
