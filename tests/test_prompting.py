"""The user message: stable parts first, an append-only bounded history, the volatile tail last."""

from __future__ import annotations

import dataclasses
import json

from llm_support import BASELINE_METRIC, REGISTRY, TARGET, make_context

from autoresearch.proposers.prompting import (
    BEST,
    CHUNK,
    CURRENT,
    DETAIL_RUNS,
    HISTORY,
    MAX_PROGRESS_POINTS,
    PROGRAM,
    RANDOM_ARM,
    RUNNING,
    SYSTEM_PROMPT,
    WARNINGS,
    render_context,
    render_prompt,
)
from autoresearch.proposers.prompting import (
    REGISTRY as REGISTRY_HEADING,
)
from autoresearch.proposers.tools import PROPOSE, STOP

BASE = dict(REGISTRY["baseline"]["config"])


def _run(i: int, **extra) -> dict:
    config = BASE | {"EPOCHS": 10 + i}
    return {
        "iteration": i,
        "run_id": f"it{i:04d}",
        "status": "ok",
        "hypothesis": f"hypothesis {i}",
        "overrides": {"EPOCHS": 10 + i},
        "config": BASE if i == 1 else config,
        "score": 6.0 - 0.01 * i,
        "feasible": True,
        "verdict": "improved",
        "auxiliary": {"wall_seconds": 1.23456789},
        **extra,
    }


def _context(n: int, **changes):
    history = tuple(_run(i) for i in range(1, n + 1))
    return dataclasses.replace(make_context(), history=history, **changes)


def test_sections_come_stable_first_and_volatile_last():
    context = make_context(
        warnings=("Refused: N_DEMOS=100 is not one of the choices.", "Budget: iterations 3/50")
    )
    text = render_context(context)
    markers = [PROGRAM, REGISTRY_HEADING, RANDOM_ARM, HISTORY, RUNNING, WARNINGS, BEST, CURRENT]
    positions = [text.index(marker) for marker in markers]
    assert positions == sorted(positions)
    assert all(text.count(marker) == 1 for marker in markers)
    warnings_section = text[positions[5] : positions[6]]
    assert (
        "- Refused: N_DEMOS=100 is not one of the choices." in warnings_section
        and "Budget" in warnings_section
    )
    assert context.program in text[positions[0] : positions[1]] and "(program.md)" in text
    assert "random arm: 8 runs" in text[positions[2] : positions[3]]


def test_registry_and_current_values_are_json_and_the_moving_best_is_not_in_the_prefix():
    context = dataclasses.replace(
        make_context(), registry=REGISTRY | {"campaign_best": {"metric": 5.5, "run_id": "it0003"}}
    )
    prompt = render_prompt(context)
    block = prompt.stable.split(REGISTRY_HEADING)[1].split("```json\n")[1].split("\n```")[0]
    assert json.loads(block) == REGISTRY  # without the campaign's running best
    current = prompt.tail.split(CURRENT)[1].split("```json\n")[1].split("\n```")[0]
    assert json.loads(current) == context.current_values


def test_the_stable_part_does_not_change_from_turn_to_turn():
    first = render_prompt(_context(1, warnings=("Budget: iterations 1/50",)))
    later = render_prompt(_context(7, warnings=("Budget: iterations 7/50", "last proposal refused")))
    assert first.stable == later.stable


def test_history_lines_are_json_with_configs_as_deltas_from_the_first_run():
    prompt = render_prompt(_context(3))
    lines = [json.loads(line) for block in prompt.history for line in block.splitlines() if line]
    assert [line["iteration"] for line in lines] == [1, 2, 3]
    assert lines[0]["config"] == BASE
    assert (
        lines[2]["config_delta"] == {"EPOCHS": 13}
        and "config" not in lines[2]
        and "overrides" not in lines[2]
    )
    assert lines[2]["auxiliary"]["wall_seconds"] == 1.23457


def test_history_is_append_only_between_compactions():
    for n in range(1, 60):
        before, after = render_prompt(_context(n)), render_prompt(_context(n + 1))
        if len(after.history) > len(before.history):  # one run appended: every earlier block kept
            assert after.history[: len(before.history)] == before.history
        else:  # a chunk of CHUNK runs was folded into a compact block
            assert n + 1 - DETAIL_RUNS > 0 and (n + 1 - DETAIL_RUNS) % CHUNK == 0


def test_history_stays_bounded_on_a_long_campaign():
    sizes = {n: len("".join(render_prompt(_context(n)).history)) for n in (50, 100, 200)}
    per_old_run = (sizes[200] - sizes[100]) / 100
    assert per_old_run < 200  # compact rows only
    long_hypothesis = dataclasses.replace(
        make_context(), history=(_run(1), _run(2, hypothesis="x" * 1_000_000, reason="y" * 50_000))
    )
    # the run shows twice (history, best run), each of its two strings cut to 300 characters
    assert len(render_context(long_hypothesis)) < len(render_context(_context(2))) + 4 * 300 + 100


def test_compact_rows_keep_the_metric_and_the_configuration():
    prompt = render_prompt(_context(45))
    compact = [json.loads(line) for line in prompt.history[0].splitlines()]
    assert len(compact) == CHUNK and compact[0]["config"] == BASE
    assert compact[3] == {
        "iteration": 4,
        "status": "ok",
        "feasible": True,
        "verdict": "improved",
        "score": 5.96,
        "config_delta": {"EPOCHS": 14},
    }


def test_running_experiments_best_run_and_learning_curves_are_in_the_tail():
    running = (
        {
            "iteration": 9,
            "run_id": "it0009",
            "overrides": {"EPOCHS": 99},
            "config": BASE | {"EPOCHS": 99},
            "hypothesis": "longer",
        },
    )
    curve = [{"step": s, "score": 7.0 - s / 100} for s in range(100)]
    history = (*(_run(i) for i in range(1, 40)), _run(40, status="pruned", progress=curve))
    prompt = render_prompt(dataclasses.replace(make_context(), history=history, running=running))
    assert f"{RUNNING} (1)" in prompt.tail and '"config_delta":{"EPOCHS":99}' in prompt.tail
    last = json.loads(prompt.history[-1])
    assert len(last["progress"]) == MAX_PROGRESS_POINTS and last["progress"][0] == curve[0]
    assert last["progress"][-1] == {"step": 99, "score": 6.01}
    best = json.loads(prompt.tail.split(BEST)[1].splitlines()[1])
    assert best["iteration"] == 39  # the lowest feasible score (minimize), shown whole though compacted


def test_model_text_in_the_history_is_escaped():
    hostile = _run(2, hypothesis="fine\x1b]0;title\x07")
    text = render_context(
        dataclasses.replace(make_context(), history=(_run(1), hostile), warnings=("bad\x1b[2J",))
    )
    assert "\x1b" not in text and "\x07" not in text
    assert "fine\\u001b]0;title\\u0007" in text and "- bad\\x1b[2J" in text


def test_empty_parts_are_stated_or_left_out():
    context = dataclasses.replace(make_context(), history=(), random_arm_summary=None)
    text = render_context(context)
    assert f"{WARNINGS}\n(none)" in text and f"{RUNNING} (0)\n(none)" in text
    assert RANDOM_ARM not in text
    assert "No runs yet." in text


def test_blind_context_shows_the_blind_program_and_no_answer():
    context = make_context(blind=True)
    text = render_context(context) + SYSTEM_PROMPT
    assert "(program_blind.md)" in text and "(program.md)" not in text
    assert str(TARGET) not in text and str(BASELINE_METRIC) not in text
    assert '"target"' not in text and '"baseline"' not in text


def test_system_prompt_demands_exactly_one_tool():
    assert "exactly one tool" in SYSTEM_PROMPT
    assert PROPOSE in SYSTEM_PROMPT and STOP in SYSTEM_PROMPT
