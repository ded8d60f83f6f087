"""Which data a campaign's runs were scored on, against what its family pins (``split_ids``).

Every FINAL_METRIC line a campaign's runs left (its runs.jsonl and each audit step's) is read, and
each is compared with the family's pins (:meth:`autoresearch.family.Family.off_split`). ``check
--family`` lists the campaigns some of whose numbers were scored on other data: another build of a
split, or a record written before the family pinned its splits.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

from autoresearch.campaign.meta import CampaignMeta
from autoresearch.campaign.paths import CampaignError, CampaignPaths
from autoresearch.family import Family

_NAMES = CampaignPaths(Path())  # the file names of a campaign directory, and of each audit step's runs


def family_campaigns(family: Family, under: list[Path]) -> list[Path]:
    """Campaign directories of ``family`` (by the name their campaign.json records) under ``under``."""
    found = []
    for top in under:
        for meta in sorted(top.rglob(_NAMES.campaign_json.name)) if top.is_dir() else []:
            try:
                name = CampaignMeta.read(meta.parent).family_name
            except CampaignError:
                continue  # unreadable: `check --campaign` reports it
            if name == family.name:
                found.append(meta.parent)
    return found


def off_split_runs(root: Path, family: Family) -> Counter[str]:
    """How many of the campaign's logged runs were scored on data other than the family pins, by the
    reason (one per split that differs); empty when every run matches or the family pins nothing."""
    reasons: Counter[str] = Counter()
    if not family.split_ids:
        return reasons
    for log in sorted(root.rglob(_NAMES.runs_log.name)):
        for line in log.read_text(encoding="utf-8", errors="replace").splitlines():
            try:
                record = json.loads(line)
            except ValueError:
                continue  # a torn last line: `check --campaign` reports it
            if isinstance(record, dict):
                reasons.update(family.off_split(record))
    return reasons
