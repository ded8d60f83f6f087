"""The one interface every proposer implements (an Optuna-sampler-like strategy object).

A proposer reads the campaign state and returns one :class:`Proposal`: an experiment or
a stop request. Its output is untrusted: the orchestrator validates ``overrides`` against
the family's search space before anything is written or run.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Literal, NamedTuple


@dataclass(frozen=True)
class Usage:
    """Tokens and money one proposal cost (zero for key-free proposers).

    ``input_tokens`` counts every input token, cached ones included; ``cache_read_tokens`` and
    ``cache_write_tokens`` say how many of them were read from or written to the provider's prompt
    cache; ``reasoning_tokens`` how many of ``output_tokens`` were thinking. ``problem`` is set when the
    server's usage block could not be trusted and the call was charged at a conservative maximum.
    """

    input_tokens: int = 0
    output_tokens: int = 0
    cost_usd: float = 0.0
    cache_read_tokens: int = 0
    cache_write_tokens: int = 0
    reasoning_tokens: int = 0
    problem: str | None = None

    def __add__(self, other: Usage) -> Usage:
        return Usage(
            self.input_tokens + other.input_tokens,
            self.output_tokens + other.output_tokens,
            self.cost_usd + other.cost_usd,
            self.cache_read_tokens + other.cache_read_tokens,
            self.cache_write_tokens + other.cache_write_tokens,
            self.reasoning_tokens + other.reasoning_tokens,
            self.problem or other.problem,
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
    # Facts about the call worth keeping in the record: a refusal's category, a truncation, a
    # server that seems to have cut the prompt, transport faults retried before this answer.
    notes: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class ProposerContext:
    """What a proposer may read, in the order an LLM is shown it (paper Sec. 3.3).

    warnings: orchestrator warnings for this turn (e.g. why the last proposal was refused).
    program: program.md, or program_blind.md in blind mode.
    registry: family.json as shown to the proposer (blind mode: no target, baseline or best).
    random_arm_summary: a compact text summary of a random-search arm, when one exists.
    warm_start_summary: the earlier campaigns of ``loop --warm-start``, summarised, when given.
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
    warm_start_summary: str | None = None

    @classmethod
    def of_configs(
        cls, iteration: int, registry: dict[str, Any], configs: list[dict[str, Any]], current: dict[str, Any]
    ) -> ProposerContext:
        """The context a key-free proposer needs outside a campaign: the configurations run so far."""
        return cls(
            iteration=iteration,
            warnings=(),
            program="",
            registry=registry,
            random_arm_summary=None,
            history=tuple({"config": c} for c in configs),
            current_values=current,
        )


class TransientAPIError(Exception):
    """A transport fault worth retrying (429, 529, 5xx, timeout, dropped connection).

    The orchestrator retries it with capped backoff (:mod:`autoresearch.proposers.retry`); it is not
    the proposer's failure. ``retry_after`` is the server's hint in seconds, when it gave one.
    """

    def __init__(self, message: str, retry_after: float | None = None) -> None:
        super().__init__(message)
        self.retry_after = retry_after


class FatalAPIError(Exception):
    """An error no retry can heal (authentication, permission, spend limit): the campaign stops."""

    def __init__(self, message: str, kind: str) -> None:
        super().__init__(message)
        self.kind = kind  # "auth" or "spend_limit"


class RunOutcome(NamedTuple):
    """What a proposer is told of an experiment that ran."""

    config: dict[str, Any]  # the full configuration
    metric: float | None  # None when the run failed or was stopped early
    feasible: bool
    constraints: dict[str, float] | None = None  # graded, <= 0 met (Family.constraints); None: none
    # A run stopped early (loop --early-stop): its learning curve {step: value}, as far as it got.
    curve: dict[int, float] | None = None
    seconds: float | None = None  # what the run cost: its wall-clock seconds
    budget_exhausted: bool = False  # it used up its training time budget and was scored as it stood


class Proposer(ABC):
    """Strategy interface. ``tell`` reports the outcome of the last proposal."""

    name: str = "proposer"

    @abstractmethod
    def propose(self, context: ProposerContext) -> Proposal: ...

    def tell(self, outcome: RunOutcome) -> None:  # noqa: B027
        """The outcome of an experiment that ran. Stateless proposers ignore it."""


def projected_cost(proposer: Proposer, context: ProposerContext) -> float:
    """An upper bound on the USD the proposer's next call costs: its ``projected_cost(context)``,
    found through wrappers that delegate to an ``inner`` proposer; 0 for one that costs nothing."""
    while not hasattr(proposer, "projected_cost") and hasattr(proposer, "inner"):
        proposer = proposer.inner
    estimate = getattr(proposer, "projected_cost", None)
    return float(estimate(context)) if estimate is not None else 0.0
