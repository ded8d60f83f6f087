"""What the audit writes into a campaign directory: audit.json (one part per step) and each step's
log of trials (one :class:`TrialRow` per finished run, under ``audit/<step>/``).

audit.json is read-modify-written under its lock and replaced atomically, so two steps never lose
each other's parts. A step log is append-only (autoresearch.journal). Rows written before the
split's one shape (``eval_split``, the search split's ``metric`` and ``feasible`` on top, the test
split's under ``test``, the FINAL_METRIC object under ``record``) read into the same TrialRow.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from autoresearch.campaign.paths import CampaignPaths
from autoresearch.journal import Journal, read_json, update_json
from autoresearch.splits import Score, ScoredRun, Split


def read_audit(root: str | os.PathLike[str]) -> dict[str, Any]:
    """audit.json of the campaign in ``root``: {step: its part}, {} before the audit wrote one."""
    path = CampaignPaths(Path(root)).audit_json
    return read_json(path) if path.exists() else {}


def write_step(root: str | os.PathLike[str], step: str, part: dict[str, Any]) -> dict[str, Any]:
    """Replace audit.json[step] with ``part``."""
    return update_json(CampaignPaths(Path(root)).audit_json, lambda data: data.__setitem__(step, part))


@dataclass(frozen=True)
class TrialRow:
    """One trial of an audit step and how its run ended. ``split`` is the split the run was scored
    on; ``scores`` (a run that finished: ``status`` ok) hold its score on each split."""

    key: str  # e.g. "verify-c1-s11": the resumption key, also the run id and run directory name
    run_id: str
    seed: int
    status: str
    split: Split
    scores: ScoredRun | None
    best_train_loss: float | None
    reason: str | None
    wall_seconds: float | None
    returncode: int | None
    config: dict[str, Any]
    final_metric: dict[str, Any] | None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def on(self, split: Split) -> Score | None:
        """The run's score on ``split``; None when it has none there (it failed, or was not scored on it)."""
        return self.scores.on(split) if self.scores is not None else None

    def to_json(self) -> dict[str, Any]:
        data = {field.name: getattr(self, field.name) for field in fields(self)}
        return {**data, "split": self.split.value, "scores": self.scores and self.scores.to_json()}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> TrialRow:
        if "scores" in data:
            scores = data["scores"] and ScoredRun.from_json(data["scores"])
            return cls(**{**data, "split": Split(data["split"]), "scores": scores})
        test = data.get("test")
        scores = None
        if data["status"] == "ok":
            scores = ScoredRun(
                Score(data["metric"], bool(data["feasible"])),
                Score(test["metric"], bool(test["feasible"])) if test else None,
            )
        return cls(
            key=data["key"],
            run_id=data["run_id"],
            seed=data["seed"],
            status=data["status"],
            split=Split(data.get("eval_split", Split.SEARCH)),
            scores=scores,
            best_train_loss=data.get("best_train_loss"),
            reason=data.get("reason"),
            wall_seconds=data.get("wall_seconds"),
            returncode=data.get("returncode"),
            config=data["config"],
            final_metric=data.get("record"),
        )


class StepLog:
    """An audit step's log of trials, opened by the step that appends to it (append-only; a torn
    last line is repaired on opening)."""

    def __init__(self, path: str | os.PathLike[str]):
        self._journal = Journal(path)
        self._journal.repair()

    def read(self) -> list[TrialRow]:
        return [TrialRow.from_json(row) for row in self._journal.read()]

    def append(self, row: TrialRow) -> None:
        self._journal.append(row.to_json())
