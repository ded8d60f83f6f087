"""Warm starts (``loop --warm-start CAMPAIGN...``): the finished runs of earlier campaigns of the same
family, told to the key-free samplers before their first turn (Optuna's ``add_trials``, through
:class:`autoresearch.proposers.tpe.TPEProposer`) and summarised for the LLM proposers.

A run of an earlier campaign is matched against the space searched now: a parameter the space has
gained since is set to the family's baseline value (the family contract: a new parameter's default
reproduces what ran before it), and a run is dropped, and counted, when it sets a parameter the
space no longer has or a value outside it (e.g. beyond a protocol's bounds). Only finished runs
count; failed and early-stopped ones carry no metric.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from autoresearch.campaign import Campaign, CampaignError, portable_path
from autoresearch.campaign.group import is_group, repeat_dirs
from autoresearch.family import Family
from autoresearch.proposers.base import RunOutcome
from autoresearch.space import SearchSpace, ValidationError

TOP_K = 5  # runs shown to an LLM proposer


@dataclass(frozen=True)
class WarmRun:
    campaign: str
    iteration: int
    outcome: RunOutcome


@dataclass(frozen=True)
class WarmStart:
    """The earlier runs in the current space, and per campaign how many were used and dropped."""

    runs: tuple[WarmRun, ...]
    sources: tuple[dict[str, Any], ...]

    @property
    def outcomes(self) -> list[RunOutcome]:
        return [run.outcome for run in self.runs]

    @classmethod
    def load(cls, paths: list[str], family: Family, space: SearchSpace) -> WarmStart:
        """The finished runs of the campaigns in ``paths`` (a group directory stands for its repeats),
        matched against ``space``; ValueError names a path that is no campaign of this family."""
        runs, sources = [], []
        for campaign_dir in _campaign_dirs(paths):
            campaign = Campaign(campaign_dir)
            try:
                name = campaign.meta().family_name
                records = campaign.records()
            except CampaignError as err:
                raise ValueError(f"--warm-start {campaign_dir}: {err}") from None
            if name != family.name:
                raise ValueError(
                    f"--warm-start {campaign_dir}: a campaign of family {name!r}, not {family.name!r}"
                )
            used, dropped, completed = 0, Counter(), 0
            finished = [r for r in records if r.ran]
            for record in finished:
                config, why, filled = _matched(record.config, family, space)
                if config is None:
                    dropped[why] += 1
                    continue
                used, completed = used + 1, completed + bool(filled)
                outcome = RunOutcome(
                    config,
                    record.metric,
                    # judged under this campaign's gate (its protocol's limits), not the one it ran under
                    family.is_feasible(record.final_metric) if record.final_metric else bool(record.feasible),
                    family.constraints(record.final_metric),
                    seconds=record.wall_seconds,
                    budget_exhausted=bool(record.budget_exhausted),
                )
                runs.append(WarmRun(portable_path(campaign_dir), record.iteration, outcome))
            sources.append(
                {
                    "campaign": portable_path(campaign_dir),
                    "finished": len(finished),
                    "used": used,
                    "completed_from_baseline": completed,
                    "dropped": dict(sorted(dropped.items())),
                }
            )
        return cls(tuple(runs), tuple(sources))

    def to_json(self) -> dict[str, Any]:
        """What campaign.json records of it (each session's entry: the campaigns may have grown since)."""
        return {"runs": len(self.runs), "campaigns": list(self.sources)}

    def summary(self, family: Family) -> str:
        """The text an LLM proposer is shown: the counts, then the best runs as changes from the baseline."""
        n_dropped = sum(sum(s["dropped"].values()) for s in self.sources)
        names = ", ".join(s["campaign"] for s in self.sources)
        lines = [
            f"Warm start: {len(self.runs)} finished runs of earlier campaigns of this family ({names}); "
            f"{n_dropped} dropped as outside the space searched now."
        ]
        baseline = family.baseline_config
        sign = family.direction
        ranked = sorted(self.runs, key=lambda r: (not r.outcome.feasible, -sign * r.outcome.metric))
        for run in ranked[:TOP_K]:
            o = run.outcome
            delta = {k: v for k, v in o.config.items() if baseline.get(k) != v}
            flag = "" if o.feasible else " (infeasible)"
            cut = ", cut at its time budget" if o.budget_exhausted else ""
            cost = f", {o.seconds:.0f} s" if o.seconds is not None else ""
            lines.append(
                f"  {family.metric}={o.metric:.6g}{flag}{cost}{cut} ({run.campaign} iteration {run.iteration}): "
                f"{json.dumps(delta)}"
            )
        return "\n".join(lines)


def _campaign_dirs(paths: list[str]) -> list[Path]:
    found = []
    for path in map(Path, paths):
        if is_group(path):
            found += repeat_dirs(path)
        elif Campaign(path).exists():
            found.append(path)
        else:
            raise ValueError(f"--warm-start {path}: not a campaign directory (no campaign.json)")
    return found


def _matched(
    config: dict[str, Any] | None, family: Family, space: SearchSpace
) -> tuple[dict[str, Any] | None, str | None, bool]:
    """(the run's configuration in ``space``, None, whether a parameter was set from the baseline), or
    (None, why it is dropped, False)."""
    if not isinstance(config, dict):
        return None, "no configuration", False
    if set(config) - set(space.names):
        return None, "sets a parameter the space no longer has", False
    filled = family.completed(config)
    try:
        full = space.validate_full(filled)
    except ValidationError:
        return None, "a value outside the space searched now", False
    return full, None, len(config) < len(space.names)
