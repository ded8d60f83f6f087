"""The evaluation splits, and what a finished run scored on each (docs/family-contract.md).

A family's train.py scores a run on the search split (the starts every search selects on: 512 in
the shipped rendezvous and docking families, 128 in constrained docking) and, when the audit asks
for ``--eval-split test``, on the sealed test split too, from one training. Its
FINAL_METRIC object keeps the primary metric of the split it was scored on at the top and each
split's metrics under ``splits``. :meth:`ScoredRun.read` reads that shape and the two it replaced:
a FINAL_METRIC object written before ``splits`` (a test run kept the search split's metrics under
``search_split``) and one of a family that prints no ``splits`` (its top is the search split).

A split's **identity** is whatever the family says names its data (for cwh_envs, a hash of the
starts). A FINAL_METRIC object may carry ``split_ids`` (split name -> identity: what the run was
scored on) and family.json may pin ``split_ids`` (what the family's numbers are scored on):
:func:`split_mismatches` says where the two disagree, so that no run, noise measurement or random
arm scored on other data is compared with the family's numbers without a word.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import Enum
from typing import Any

SPLIT_IDS = "split_ids"  # FINAL_METRIC's and family.json's field: split name -> the split's identity
LEGACY_SEARCH = "search_split"  # where a test run's record kept the search split before ``splits``


class Split(str, Enum):
    """An evaluation split. A str, so that it is its own JSON value and CLI choice."""

    SEARCH = "search"  # selected on by every search and every PROGRESS line
    TEST = "test"  # sealed: only the audit's gates see it

    # Its value wherever it is printed, on every Python (format() of a str mixin changed in 3.12).
    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)


def split_parts(final_metric: Mapping[str, Any]) -> dict[Split, Any]:
    """Each split's metrics in a FINAL_METRIC object, as it holds them (not yet validated)."""
    scored = Split(final_metric.get("eval_split", Split.SEARCH))
    splits = final_metric.get("splits")
    if isinstance(splits, dict):
        return {split: splits[split.value] for split in Split if split.value in splits}
    if scored is Split.TEST:
        top = {k: v for k, v in final_metric.items() if k != LEGACY_SEARCH}
        return {Split.SEARCH: final_metric.get(LEGACY_SEARCH), Split.TEST: top}
    return {Split.SEARCH: final_metric}


@dataclass(frozen=True)
class Score:
    """A run's primary metric on one split, and whether the run is feasible there."""

    metric: float
    feasible: bool

    def to_json(self) -> dict[str, Any]:
        return {"metric": self.metric, "feasible": self.feasible}


@dataclass(frozen=True)
class ScoredRun:
    """What a finished run scored: on the search split always, on the sealed test split when asked."""

    search: Score
    test: Score | None = None

    def on(self, split: Split) -> Score | None:
        return self.search if split is Split.SEARCH else self.test

    @classmethod
    def read(
        cls, final_metric: Mapping[str, Any], metric: str, feasible: Callable[[Mapping[str, Any]], bool]
    ) -> ScoredRun:
        """The scores of a valid FINAL_METRIC object (autoresearch.execution.protocol checks it)."""
        parts = split_parts(final_metric)
        scores = {split: Score(float(part[metric]), feasible(part)) for split, part in parts.items()}
        return cls(scores[Split.SEARCH], scores.get(Split.TEST))

    def to_json(self) -> dict[str, Any]:
        return {split.value: score.to_json() for split in Split if (score := self.on(split)) is not None}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ScoredRun:
        scores = {split: Score(**data[split.value]) for split in Split if data.get(split.value)}
        return cls(scores[Split.SEARCH], scores.get(Split.TEST))


def recorded_split_ids(final_metric: Mapping[str, Any] | None) -> dict[str, str]:
    """The identity of each split a FINAL_METRIC object says it was scored on (empty: it says none)."""
    ids = (final_metric or {}).get(SPLIT_IDS)
    return {k: v for k, v in ids.items() if isinstance(v, str)} if isinstance(ids, dict) else {}


def split_mismatches(
    recorded: Mapping[str, str], pinned: Mapping[str, str], splits: tuple[Split, ...] = tuple(Split)
) -> list[str]:
    """One line per split of ``splits`` on which a run's ``recorded`` identities (what it was scored
    on) are not the family's ``pinned`` ones; empty when they agree or the family pins none."""
    found = []
    for split in splits:
        want, got = pinned.get(split.value), recorded.get(split.value)
        if want is None or got == want:
            continue
        said = (
            "records no split identity (scored before splits were pinned)"
            if got is None
            else f"was scored on {got}"
        )
        found.append(f"{split} split: {said}; the family pins {want}")
    return found
