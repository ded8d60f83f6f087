"""ledger.json: what the audit measured and decided about a family, kept beside its family.json.

family.json is the paper's registry: the declaration (metric, direction, target, search space,
baseline, ...) and the current best, its configuration and certified number. The audit's working
data lives in the ledger, which the audit alone writes (docs/audit.md):

```
{
  "seed_noise": {mean, std, k, seeds, values, n_feasible, metric, measured_at, runs_dir, failed,
                 pinned: {baseline, files}, test: {mean, std, k, values, n_feasible}},
  "promotions": [{config, metric, std, n, split, by_split: {search: ..., test: ...},
                  source: {campaign, run_id, step}, time_budget?: seconds, distilled?: {...},
                  remeasured?: "...", pruned_from?: config_id, dropped?: [...]}, ...]
}
```

A promotion certified under a training time budget (the campaign's ``time_budget``: every run it
reseeded was granted it) keeps it, in both files: the recipe is defined with it.

``promotions`` is the history of the family best, oldest first; the last is the current best's
entry when family.json's best has its configuration. A family written before the ledger kept both in
family.json (``seed_noise``, and ``best`` with every field of a promotion): it reads as the same
:class:`Ledger`, and the audit's first write moves them here.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

from autoresearch.journal import JournalError, locked, read_json, write_json_atomic

LEDGER_FILE = "ledger.json"
BEST_FIELDS = ("config", "metric", "time_budget", "limits")  # what family.json keeps of a promotion
T = TypeVar("T")


@dataclass(frozen=True)
class Ledger:
    seed_noise: dict[str, Any] | None = None
    promotions: tuple[dict[str, Any], ...] = ()

    def current(self, best: dict[str, Any] | None) -> dict[str, Any] | None:
        """The promotion behind family.json's ``best``: the last one, when the best is its certified
        number and its configuration (plus any parameter the search space gained since, set beside
        it); None for a best the audit did not promote (or none at all)."""
        last = self.promotions[-1] if self.promotions else None
        if last is None or not best or best.get("metric") != last.get("metric"):
            return None
        config = best.get("config") or {}
        return last if all(config.get(k) == v for k, v in last.get("config", {}).items()) else None

    def measured(self, seed_noise: dict[str, Any]) -> Ledger:
        return replace(self, seed_noise=seed_noise)

    def promoted(self, entry: dict[str, Any]) -> Ledger:
        return replace(self, promotions=(*self.promotions, entry))

    def restated(self, entry: dict[str, Any]) -> Ledger:
        """This ledger with the current best's entry replaced by ``entry``."""
        return replace(self, promotions=(*self.promotions[:-1], entry))

    def to_json(self) -> dict[str, Any]:
        return {"seed_noise": self.seed_noise, "promotions": list(self.promotions)}

    @classmethod
    def read(cls, family_dir: str | os.PathLike[str], registry: dict[str, Any]) -> Ledger:
        """The family's ledger, or the same read from the old layout's ``registry`` (family.json)."""
        path = Path(family_dir) / LEDGER_FILE
        if path.exists():
            data = read_json(path)
            if not isinstance(data, dict) or not isinstance(data.get("promotions", []), list):
                raise JournalError(f"{path}: must hold an object with a 'promotions' list")
            return cls(data.get("seed_noise"), tuple(data.get("promotions") or ()))
        best = registry.get("best")
        promoted = isinstance(best, dict) and set(best) - set(BEST_FIELDS)  # more than a declared best
        return cls(registry.get("seed_noise"), (best,) if promoted else ())


def best_of(promotion: dict[str, Any]) -> dict[str, Any]:
    """What family.json holds of a promotion: the configuration, its certified number, and the training
    time budget and the protocol's limits it was certified under (when it had them)."""
    best = {"config": promotion.get("config"), "metric": promotion.get("metric")}
    return {**best, **{k: promotion[k] for k in ("time_budget", "limits") if k in promotion}}


def update(
    family_dir: str | os.PathLike[str], decide: Callable[[dict[str, Any], Ledger], tuple[Ledger, T]]
) -> T:
    """Read-modify-write a family's family.json and ledger.json together under family.json's lock, so
    two audits of one family never decide on a state the other has since changed. ``decide(registry,
    ledger)`` may set the registry's best and returns the new ledger and what to return. A family in
    the old layout is moved to the new one by its first write."""
    family_json = Path(family_dir) / "family.json"
    with locked(family_json):
        registry = read_json(family_json)
        ledger, outcome = decide(registry, Ledger.read(family_dir, registry))
        registry.pop("seed_noise", None)  # the old layout's, now the ledger's
        if isinstance(registry.get("best"), dict):
            registry["best"] = best_of(registry["best"])
        written = {Path(family_dir) / LEDGER_FILE: ledger.to_json(), family_json: registry}
        for path, data in written.items():  # both checked before either is written
            _require_finite(path, data)
        for path, data in written.items():
            write_json_atomic(path, data)
    return outcome


def _require_finite(path: Path, data: Any) -> None:
    """Refuse what every reader of a family would then refuse: NaN or Infinity (not JSON)."""
    try:
        json.dumps(data, allow_nan=False)
    except ValueError:
        raise JournalError(
            f"{path}: the audit's result holds a number that is not finite (NaN or Infinity); nothing was "
            "written"
        ) from None
