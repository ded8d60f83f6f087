"""The user message shows the evidence in the paper's fixed order, and nothing the context lacks."""

from __future__ import annotations

import dataclasses
import json

from llm_support import BASELINE_METRIC, TARGET, make_context

from autoresearch.prompting import (
    CURRENT,
    HISTORY,
    PROGRAM,
    RANDOM_ARM,
    REGISTRY,
    SYSTEM_PROMPT,
    WARNINGS,
    render_context,
)
from autoresearch.proposers.tools import PROPOSE, STOP


def test_sections_come_in_the_paper_order():
    context = make_context(warnings=("Refused: N_DEMOS=100 is not one of the choices.",))
    text = render_context(context)
    markers = [WARNINGS, PROGRAM, REGISTRY, RANDOM_ARM, HISTORY, CURRENT]
    positions = [text.index(marker) for marker in markers]
    assert positions == sorted(positions)
    assert all(text.count(marker) == 1 for marker in markers)

    warnings_section = text[positions[0] : positions[1]]
    assert "- Refused: N_DEMOS=100 is not one of the choices." in warnings_section
    assert context.program in text[positions[1] : positions[2]]
    assert "(program.md)" in text[positions[1] : positions[2]]
    assert "random arm: 8 runs" in text[positions[3] : positions[4]]


def test_registry_history_and_current_values_are_json():
    context = make_context()
    text = render_context(context)
    registry_block = text.split(REGISTRY)[1].split("```json\n")[1].split("\n```")[0]
    assert json.loads(registry_block) == context.registry

    history_block = text.split(HISTORY)[1].split("```jsonl\n")[1].split("\n```")[0]
    assert [json.loads(line) for line in history_block.splitlines()] == list(context.history)

    current_block = text.split(CURRENT)[1].split("```json\n")[1].split("\n```")[0]
    assert json.loads(current_block) == context.current_values


def test_empty_parts_are_stated_or_left_out():
    context = dataclasses.replace(make_context(), history=(), random_arm_summary=None)
    text = render_context(context)
    assert f"{WARNINGS}\n(none)" in text
    assert RANDOM_ARM not in text
    assert f"{HISTORY} (0)\nNo runs yet." in text


def test_blind_context_shows_the_blind_program_and_no_answer():
    context = make_context(blind=True)
    text = render_context(context) + SYSTEM_PROMPT
    assert "(program_blind.md)" in text and "(program.md)" not in text
    assert str(TARGET) not in text and str(BASELINE_METRIC) not in text
    assert '"target"' not in text and '"baseline"' not in text


def test_system_prompt_demands_exactly_one_tool():
    assert "exactly one tool" in SYSTEM_PROMPT
    assert PROPOSE in SYSTEM_PROMPT and STOP in SYSTEM_PROMPT
