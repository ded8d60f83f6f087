"""Where a campaign's files are, and the error every part of the campaign store raises."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


class CampaignError(RuntimeError):
    """The campaign directory is inconsistent or cannot be used."""


@dataclass(frozen=True)
class CampaignPaths:
    root: Path

    @property
    def campaign_json(self) -> Path:
        return self.root / "campaign.json"

    @property
    def family_json(self) -> Path:
        return self.root / "family.json"

    @property
    def proposals(self) -> Path:
        return self.root / "proposals.jsonl"

    @property
    def runs_log(self) -> Path:
        return self.root / "runs.jsonl"

    @property
    def runs_dir(self) -> Path:
        return self.root / "runs"

    def run_dir(self, run_id: str) -> Path:
        return self.runs_dir / run_id

    @property
    def audit_json(self) -> Path:
        return self.root / "audit.json"

    def step_dir(self, step: str) -> Path:
        """Where an audit step keeps its log and its runs."""
        return self.root / "audit" / step
