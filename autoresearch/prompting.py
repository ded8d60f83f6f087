"""What an LLM proposer is shown each turn (paper Sec. 3.3).

The user message holds the same evidence a human researcher would have, in a fixed order:
orchestrator warnings, the program (program.md, or program_blind.md in blind mode), the family.json
registry, a summary of the random-search arm when there is one, the run history, and the current
editable values. Everything comes from the ProposerContext as given: redaction for blind mode is the
context builder's job, and this module adds no fact of its own (the system prompt names no family,
target or baseline).
"""

from __future__ import annotations

import json
from typing import Any

from autoresearch.proposers.base import ProposerContext
from autoresearch.proposers.tools import PROPOSE, STOP

WARNINGS = "## Orchestrator warnings"
PROGRAM = "## Program"
REGISTRY = "## Registry (family.json)"
RANDOM_ARM = "## Random-search arm"
HISTORY = "## Runs so far"
CURRENT = "## Current editable values"

SYSTEM_PROMPT = f"""\
You are a research agent tuning the hyperparameters of a training script, one experiment at a time.
Each turn you see, in order: warnings from the orchestrator about your previous turn, the research
program, the family registry (metric, direction, axes and search space), a summary of a random-search
baseline when one exists, every run so far, and the current values of the editable parameters.

Every turn you must call exactly one tool, and write nothing else:
- {PROPOSE}: change one or more parameters of the current configuration. Use only names from the
  search space, stay within their bounds, and never repeat a configuration already run. State a
  falsifiable hypothesis, the axes the move touches, the mechanism, how it compares to the best run so
  far, and a numerical kill criterion on the metric, fixed before the run.
- {STOP}: end the campaign, when the target is met or the search is exhausted. A stop is accepted
  only with the target met, or after enough experiments across several axes; a refused stop comes
  back as a warning.

Proposals that break these rules are refused and count against the campaign's budget of failures."""


def _json(value: Any, indent: int | None = None) -> str:
    # default=str: a path or date in a run record must not crash the turn.
    separators = None if indent else (",", ":")
    return json.dumps(value, indent=indent, separators=separators, default=str)


def render_context(context: ProposerContext) -> str:
    """The user message for one turn, sections in the paper's order."""
    warnings = "\n".join(f"- {w}" for w in context.warnings) or "(none)"
    program_file = "program_blind.md" if context.blind else "program.md"
    sections = [
        f"{WARNINGS}\n{warnings}",
        f"{PROGRAM} ({program_file})\n{context.program.strip()}",
        f"{REGISTRY}\n```json\n{_json(context.registry, indent=2)}\n```",
    ]
    if context.random_arm_summary:
        sections.append(f"{RANDOM_ARM}\n{context.random_arm_summary.strip()}")
    if context.history:
        runs = "\n".join(_json(run) for run in context.history)
        sections.append(
            f"{HISTORY} ({len(context.history)}; one JSON object per line, oldest first)\n```jsonl\n{runs}\n```"
        )
    else:
        sections.append(f"{HISTORY} (0)\nNo runs yet.")
    sections.append(f"{CURRENT}\n```json\n{_json(context.current_values, indent=2)}\n```")
    return "\n\n".join(sections) + "\n"
