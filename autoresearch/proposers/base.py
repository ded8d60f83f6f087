"""The one interface every proposer implements (an Optuna-sampler-like strategy object).

A proposer reads the campaign state and returns one :class:`Proposal`: an experiment or
a stop request. Its output is untrusted: the orchestrator validates ``overrides`` against
the family's search space before anything is written or run.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Literal


@dataclass(frozen=True)
class Usage:
    """Tokens and money one proposal cost (zero for key-free proposers)."""

    input_tokens: int = 0
    output_tokens: int = 0
    cost_usd: float = 0.0

    def __add__(self, other: Usage) -> Usage:
        return Usage(
            self.input_tokens + other.input_tokens,
            self.output_tokens + other.output_tokens,
            self.cost_usd + other.cost_usd,
        )


@dataclass(frozen=True)
class Proposal:
    """One turn of the proposer.

    kind: "propose" (an experiment), "stop" (the proposer asks to end the campaign) or
        "invalid" (the proposer produced nothing usable; ``error`` says why).
    overrides: raw, untrusted {NAME: value} for "propose".
    annotation: "propose": hypothesis, axes, expected_mechanism, comparison_to_best,
        failure_prediction; "stop": status, conclusion, axes_tested.
    """

    kind: Literal["propose", "stop", "invalid"]
    overrides: dict[str, Any] = field(default_factory=dict)
    annotation: dict[str, Any] = field(default_factory=dict)
    usage: Usage = field(default_factory=Usage)
    error: str | None = None


@dataclass(frozen=True)
class ProposerContext:
    """What a proposer may read, in the order an LLM is shown it (paper Sec. 3.3).

    warnings: orchestrator warnings for this turn (e.g. why the last proposal was refused).
    program: program.md, or program_blind.md in blind mode.
    registry: family.json as shown to the proposer (blind mode: no target, baseline or best).
    random_arm_summary: a compact text summary of a random-search arm, when one exists.
    history: the campaign's runs as dicts (blind mode: only {"config", <metric>} pairs).
    current_values: the editable values the next overrides apply to (the best configuration).
    running: experiments started but not finished yet (``loop --workers K``), as dicts with
        at least ``iteration``, ``run_id``, ``overrides``, ``config`` and ``hypothesis``; a
        proposer must not repeat them and an Optuna-backed one treats them as pending trials.
    """

    iteration: int
    warnings: tuple[str, ...]
    program: str
    registry: dict[str, Any]
    random_arm_summary: str | None
    history: tuple[dict[str, Any], ...]
    current_values: dict[str, Any]
    blind: bool = False
    running: tuple[dict[str, Any], ...] = ()


class Proposer(ABC):
    """Strategy interface. ``tell`` reports the outcome of the last proposal."""

    name: str = "proposer"

    @abstractmethod
    def propose(self, context: ProposerContext) -> Proposal: ...

    def tell(self, overrides: dict[str, Any], metric: float | None, feasible: bool) -> None:  # noqa: B027
        """Outcome of a proposal that ran (metric None when it failed). Stateless proposers ignore it."""
