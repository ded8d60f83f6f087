"""What an LLM proposer is shown each turn (paper Sec. 3.3), laid out for prompt caching.

The user message comes in three parts, most stable first, so that a provider's prefix cache
(Anthropic's ``cache_control`` breakpoints, OpenAI's and vLLM's automatic prefix caches) serves all
but the newest part of every request:

1. **stable** (fixed for the whole campaign): the program (program.md, or program_blind.md in blind
   mode), the family.json registry without its moving ``best`` entry, the random-search arm's summary,
   the earlier campaigns' summary (``loop --warm-start``).
2. **history**, append-only blocks: one block per run, one JSON line each, oldest first. To stay
   bounded, runs older than the newest :data:`DETAIL_RUNS` are folded, :data:`CHUNK` at a time, into
   compact table blocks (iteration, status, metric, feasibility, verdict, the run's cost in seconds,
   whether its time budget cut it, and the configuration as a delta from the first run), so a block's
   text never changes once written and a long campaign costs about 150 characters per old run. Every string is cut to :data:`MAX_STRING_CHARS`.
3. **tail** (changes every turn): runs in flight, orchestrator warnings (the budget line among them),
   the best run so far in full, and the current editable values.

Everything comes from the ProposerContext as given: redaction for blind mode is the context
builder's job, and this module adds no fact of its own.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from autoresearch.direction import Direction
from autoresearch.proposers.base import ProposerContext
from autoresearch.proposers.tools import PROPOSE, STOP, safe_text

PROGRAM = "## Program"
REGISTRY = "## Registry (family.json)"
RANDOM_ARM = "## Random-search arm"
WARM_START = "## Earlier campaigns (warm start)"
HISTORY = "## Runs so far"
RUNNING = "## Runs in flight"
WARNINGS = "## Orchestrator warnings"
BEST = "## Best run so far"
CURRENT = "## Current editable values"

DETAIL_RUNS = 20  # the newest runs are shown in full
CHUNK = 10  # older runs are folded into compact blocks this many at a time
MAX_STRING_CHARS = 300  # per string in a history line (hypothesis, reason, ...)
MAX_PROGRESS_POINTS = 8  # of an early-stopped run's learning curve
COMPACT_KEYS = ("iteration", "status", "feasible", "verdict", "seconds", "budget_exhausted")

SYSTEM_PROMPT = f"""\
You are a research agent tuning the hyperparameters of a training script, one experiment at a time.
Each turn you see, in order: the research program, the family registry (metric, direction, axes and
search space), a summary of a random-search baseline and of earlier campaigns when there are any, every
run so far (older runs in a compact table, configurations as changes from the first run; `seconds` is
what a run cost, and `budget_exhausted` marks a run cut at its training time budget and scored as it
stood), the runs still in flight, warnings from the orchestrator about your previous turn, the best run
so far, and the current values of the editable parameters.

Every turn you must call exactly one tool, and write nothing else:
- {PROPOSE}: change one or more parameters of the current configuration. Use only names from the
  search space, stay within their bounds, and never repeat a configuration already run or in flight.
  State a falsifiable hypothesis, the axes the move touches, the mechanism, how it compares to the
  best run so far, and a numerical kill criterion on the metric, fixed before the run.
- {STOP}: end the campaign, when the target is met or the search is exhausted. A stop is accepted
  only with the target met, or after enough experiments across several axes; a refused stop comes
  back as a warning.

Proposals that break these rules are refused and count against the campaign's budget of failures."""


@dataclass(frozen=True)
class Prompt:
    """The user message in its three parts; ``text`` joins them."""

    stable: str
    history: tuple[str, ...]
    tail: str

    @property
    def text(self) -> str:
        return self.stable + "".join(self.history) + self.tail


def _json(value: Any, indent: int | None = None) -> str:
    # default=str: a path or date in a run record must not crash the turn.
    separators = None if indent else (",", ":")
    return json.dumps(value, indent=indent, separators=separators, default=str)


def _compact_value(value: Any) -> Any:
    """Strings cut, floats to 6 significant digits (json.dumps then escapes control characters)."""
    if isinstance(value, str):
        return value if len(value) <= MAX_STRING_CHARS else value[:MAX_STRING_CHARS] + "…"
    if isinstance(value, float):
        return float(f"{value:.6g}") if math.isfinite(value) else str(value)
    if isinstance(value, dict):
        return {str(k)[:MAX_STRING_CHARS]: _compact_value(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_compact_value(v) for v in value]
    return value


def _delta(config: Any, reference: dict[str, Any] | None) -> dict[str, Any] | None:
    if not isinstance(config, dict) or reference is None:
        return None
    return {k: v for k, v in config.items() if reference.get(k, object()) != v}


def _subsample(curve: list[Any]) -> list[Any]:
    if len(curve) <= MAX_PROGRESS_POINTS:
        return curve
    step = (len(curve) - 1) / (MAX_PROGRESS_POINTS - 1)
    return [curve[round(i * step)] for i in range(MAX_PROGRESS_POINTS)]


def run_line(run: dict[str, Any], reference: dict[str, Any] | None) -> str:
    """One run in full: the configuration as a delta from ``reference`` (the first run's), the
    proposer's overrides left out (the delta says what ran), a learning curve cut to a few points."""
    item = dict(run)
    delta = _delta(item.get("config"), reference)
    if delta is not None:
        item.pop("config")
        item.pop("overrides", None)
        item["config_delta"] = delta
    if isinstance(item.get("progress"), list):
        item["progress"] = _subsample(item["progress"])
    return _json(_compact_value(item))


def compact_line(run: dict[str, Any], reference: dict[str, Any] | None, metric: str) -> str:
    """One old run as a table row: no hypothesis, reason or auxiliary metrics."""
    item = {k: run[k] for k in COMPACT_KEYS if k in run}
    item[metric] = run.get(metric)
    delta = _delta(run.get("config"), reference)
    item["config_delta" if delta is not None else "config"] = (
        delta if delta is not None else run.get("config")
    )
    return _json(_compact_value(item))


def _history_blocks(history: tuple[dict[str, Any], ...], metric: str) -> tuple[str, ...]:
    if not history:
        return ("No runs yet.\n",)
    first = history[0]
    reference = first.get("config") if isinstance(first.get("config"), dict) else None
    lines = [run_line(first, None)] + [None] * (len(history) - 1)
    folded = max(0, (len(history) - DETAIL_RUNS) // CHUNK) * CHUNK
    blocks = []
    for start in range(0, folded, CHUNK):
        rows = [
            compact_line(run, reference, metric) if i else lines[0]
            for i, run in enumerate(history[start : start + CHUNK], start)
        ]
        blocks.append("".join(row + "\n" for row in rows))
    for i in range(folded, len(history)):
        blocks.append((lines[i] if i == 0 else run_line(history[i], reference)) + "\n")
    return tuple(blocks)  # a block never changes once written: the blank line after is the tail's


def _best(context: ProposerContext, metric: str) -> dict[str, Any] | None:
    """The best run of the history: feasible first, then by the registry's direction."""
    sign = Direction.of(context.registry.get("direction", "maximize"))
    ran = [
        r
        for r in context.history
        if isinstance(r.get(metric), (int, float))
        and math.isfinite(r[metric])
        and r.get("feasible", True)
        and r.get("status", "ok") == "ok"  # a pruned run's metric is a partial one
    ]
    return max(ran, key=lambda r: sign * r[metric], default=None)


def render_prompt(context: ProposerContext) -> Prompt:
    """The user message for one turn, in its cacheable parts."""
    metric = str(context.registry.get("metric", "metric"))
    program_file = "program_blind.md" if context.blind else "program.md"
    # the running best moves every turn: it is in the tail
    registry = {k: v for k, v in context.registry.items() if k != "campaign_best"}
    stable = [
        f"{PROGRAM} ({program_file})\n{context.program.strip()}",
        f"{REGISTRY}\n```json\n{_json(registry, indent=2)}\n```",
    ]
    if context.random_arm_summary:
        stable.append(f"{RANDOM_ARM}\n{context.random_arm_summary.strip()}")
    if context.warm_start_summary:
        stable.append(f"{WARM_START}\n{context.warm_start_summary.strip()}")
    stable.append(
        f"{HISTORY}\nOne JSON object per line, oldest first; configurations as changes from the first "
        f"run; the oldest runs in compact form."
    )
    history = _history_blocks(context.history, metric)

    reference = context.history[0].get("config") if context.history else None
    reference = reference if isinstance(reference, dict) else None
    running = "\n".join(run_line(r, reference) for r in context.running) or "(none)"
    warnings = "\n".join(f"- {safe_text(w)}" for w in context.warnings) or "(none)"
    best = _best(context, metric)
    tail = [
        f"{RUNNING} ({len(context.running)})\n{running}",
        f"{WARNINGS}\n{warnings}",
        f"{BEST}\n{run_line(best, reference) if best else '(none yet)'}",
        f"{CURRENT}\n```json\n{_json(context.current_values, indent=2)}\n```",
    ]
    return Prompt("\n\n".join(stable) + "\n", history, "\n" + "\n\n".join(tail) + "\n")


def render_context(context: ProposerContext) -> str:
    """The whole user message for one turn."""
    return render_prompt(context).text
