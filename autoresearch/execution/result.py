"""RunResult: how one training run ended, as the runner saves it in the run's result.json."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any, Literal

RunStatus = Literal["ok", "failed", "timeout", "early_stopped"]
RUN_STATUSES = ("ok", "failed", "timeout", "early_stopped")
RESULT_FILE = "result.json"
_LEGACY_KEYS = {"record": "final_metric"}  # result.json written before the rename


@dataclass(frozen=True)
class RunResult:
    """``final_metric`` is the run's FINAL_METRIC object and ``metric`` its primary metric on the
    split it was scored on, both only when ``status`` is ok; ``progress`` holds its PROGRESS points."""

    status: RunStatus
    run_id: str
    final_metric: dict[str, Any] | None
    reason: str | None
    wall_seconds: float | None
    returncode: int | None
    metric: float | None = None
    progress: list[dict[str, Any]] | None = None  # the PROGRESS points, as {"step", "value"}

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> RunResult:
        return cls(**renamed(data))


RESULT_FIELDS = tuple(field.name for field in fields(RunResult))


def renamed(data: dict[str, Any]) -> dict[str, Any]:
    """A saved result's fields under their current names."""
    return {_LEGACY_KEYS.get(key, key): value for key, value in data.items()}
