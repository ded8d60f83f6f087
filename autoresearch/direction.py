"""Which way a metric improves: one type for the sign arithmetic and for Optuna's study direction."""

from __future__ import annotations

from enum import IntEnum


class Direction(IntEnum):
    """sigma_dir: +1 when larger metric values are better, -1 when smaller are. An int, so that
    ``direction * (a - b) > 0`` reads "a is better than b"; ``study`` is the name Optuna and
    family.json use."""

    MINIMIZE = -1
    MAXIMIZE = 1

    @classmethod
    def of(cls, name: str) -> Direction:
        """From family.json's "minimize" / "maximize"."""
        try:
            return cls[str(name).upper()]
        except KeyError:
            raise ValueError(f"direction must be 'maximize' or 'minimize', got {name!r}") from None

    @property
    def study(self) -> str:
        return self.name.lower()

    def worst(self, values):
        """The worst of ``values`` (min or max)."""
        return min(values) if self is Direction.MAXIMIZE else max(values)
