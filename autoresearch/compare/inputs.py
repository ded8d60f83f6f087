"""The arms of ``autoresearch compare``, read from campaign directories.

It reads only what every campaign directory holds, whoever ran it (key-free arms here, an LLM arm
recorded elsewhere): campaign.json, family.json (the campaign's copy of the registry: metric, direction,
target, feasibility field, seed noise) and proposals.jsonl. The family directory is never needed.

An *experiment* is an attempted training run (a ``ran`` or ``failed`` record, the shared baseline
included); proposals refused before running cost no experiment.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from autoresearch.campaign import Campaign, CampaignError, CampaignPaths
from autoresearch.campaign.group import repeat_dirs

FAMILY_KEYS = ("name", "metric", "direction", "target", "feasibility_field")


class CompareError(ValueError):
    """The arms cannot be compared; the message says why."""


@dataclass(frozen=True)
class Repeat:
    """One campaign, reduced to what the comparison needs (one entry per experiment)."""

    dir: Path
    proposer: str
    registry: dict[str, Any]
    metrics: np.ndarray  # NaN for a failed run
    feasible: np.ndarray
    elapsed: np.ndarray  # loop seconds when each experiment's record was written
    ended: str | None  # the trigger (or status) that ended the campaign; None while unfinished

    @property
    def n(self) -> int:
        return len(self.metrics)


@dataclass(frozen=True)
class RepeatedArm:
    name: str
    repeats: list[Repeat]
    unstarted: list[Path]  # repeats of a group that have not run yet: left out

    @property
    def proposers(self) -> str:
        return ", ".join(sorted({r.proposer for r in self.repeats}))


def campaign_dirs(path: Path) -> tuple[list[Path], list[Path]]:
    """(campaigns, unstarted repeats): a campaign directory itself, or the repeat-*/ campaigns of a group,
    less those without a proposals.jsonl yet (an interrupted group that had not reached them)."""
    if CampaignPaths(path).campaign_json.is_file():
        return [path], []
    found = repeat_dirs(path)
    if not found:
        raise CompareError(f"{path}: no campaign here (no campaign.json) and no repeat-*/ sub-campaigns")
    started = [d for d in found if CampaignPaths(d).proposals.is_file()]
    return started, [d for d in found if d not in started]


def read_repeat(path: Path) -> Repeat:
    store = Campaign(path)
    paths = store.paths
    for needed in (paths.campaign_json, paths.family_json, paths.proposals):
        if not needed.is_file():
            raise CompareError(f"{path}: not a campaign directory: {needed.name} is missing")
    try:
        records, proposer = store.records(), store.meta().proposer
    except CampaignError as err:
        raise CompareError(str(err)) from None
    runs = [r for r in records if r.status.started_a_run]
    last = records[-1] if records else None
    return Repeat(
        dir=path,
        proposer=proposer,
        registry=store.registry(),
        metrics=np.array([r.metric if r.ran else math.nan for r in runs], dtype=float),
        feasible=np.array([r.ran and bool(r.feasible) for r in runs], dtype=bool),
        elapsed=np.array([r.elapsed_s or 0.0 for r in runs], dtype=float),
        ended=(last.trigger or last.status.value) if last and last.status.ends_campaign else None,
    )


def load_arms(specs: list[tuple[str, list[Path]]]) -> list[RepeatedArm]:
    """Arms from (name, directories): each directory a campaign or a group of repeats."""
    names = [name for name, _ in specs]
    duplicated = sorted({n for n in names if names.count(n) > 1})
    if duplicated:
        raise CompareError(f"two arms are named {duplicated[0]!r}; name them with --arm NAME=DIR[,DIR...]")
    arms = []
    for name, dirs in specs:
        found, unstarted = [], []
        for path in dirs:
            started, waiting = campaign_dirs(Path(path))
            found += started
            unstarted += waiting
        if not found:
            raise CompareError(f"arm {name}: none of its repeats has started ({', '.join(map(str, dirs))})")
        arms.append(RepeatedArm(name, [read_repeat(d) for d in found], unstarted))
    return arms


def common_family(arms: list[RepeatedArm]) -> dict[str, Any]:
    """The registry fields every campaign must share to be compared."""
    first = arms[0].repeats[0]
    family = {k: first.registry.get(k) for k in FAMILY_KEYS}
    for arm in arms:
        for rep in arm.repeats:
            other = {k: rep.registry.get(k) for k in FAMILY_KEYS}
            if other != family:
                diff = ", ".join(
                    f"{k} {family[k]!r} vs {other[k]!r}" for k in FAMILY_KEYS if family[k] != other[k]
                )
                raise CompareError(f"{rep.dir} cannot be compared with {first.dir}: {diff}")
    return family


def noise_reference(arms: list[RepeatedArm], sigma: float | None) -> dict[str, Any] | None:
    """The seed noise the comparison is denominated in: {sigma, reference, note}, or None.

    From the campaigns' registry copies (the latest measurement when they differ), or ``sigma``; the
    reference is the baseline's mean over the noise seeds, else the baseline's recorded metric.
    """
    measured = {
        json.dumps(r.registry["seed_noise"], sort_keys=True): r.registry["seed_noise"]
        for arm in arms
        for r in arm.repeats
        if r.registry.get("seed_noise")
    }
    noise = max(measured.values(), key=lambda n: str(n.get("measured_at", "")), default=None)
    baseline = arms[0].repeats[0].registry.get("baseline") or {}
    reference = (noise or {}).get("mean", baseline.get("metric"))
    if sigma is not None:
        note = "given with --sigma"
    elif noise is not None:
        sigma = noise["std"]
        k = f", K = {noise['k']} seeds" if "k" in noise else ""
        note = f"measured by `autoresearch noise`{k}" + (
            f" (the latest of {len(measured)} measurements the campaigns carry)" if len(measured) > 1 else ""
        )
    if sigma is None or not sigma > 0 or reference is None:
        return None
    return {"sigma": float(sigma), "reference": float(reference), "note": note}
