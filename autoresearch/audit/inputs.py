"""What every audit step reads: the campaign, its family (fresh from disk), the seed noise."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from autoresearch import provenance
from autoresearch.campaign import Campaign, CampaignError, CampaignMeta, CampaignPaths, Record
from autoresearch.campaign.audit_log import read_audit
from autoresearch.campaign.check import trail_refusal
from autoresearch.family import Family
from autoresearch.ledger import LEDGER_FILE
from autoresearch.space import canonical_key
from autoresearch.splits import Split
from autoresearch.verdicts import best_feasible


class AuditError(RuntimeError):
    """An audit step cannot run; the message says what to do first."""


def config_id(config: dict[str, Any]) -> str:
    """A short, stable name for a configuration (run ids and resumption keys)."""
    return hashlib.sha1(canonical_key(config).encode()).hexdigest()[:8]


def changed_params(family: Family, config: dict[str, Any]) -> list[str]:
    """The parameters ``config`` edits relative to the family defaults, in family.json order. A parameter
    the config lacks was declared since it ran, and held its baseline value (the family only grew)."""
    baseline = family.baseline_config
    return [name for name in family.space.names if config.get(name, baseline[name]) != baseline[name]]


def audit_split(family: Family) -> Split:
    """The split the audit's runs are scored on: the sealed test split where the family has one
    (the search split comes with it), else the search split."""
    return Split.TEST if family.has_test_split else Split.SEARCH


def gate_split(family: Family, chosen: str | None = None) -> Split:
    """The split the audit gates on: ``chosen`` (``--gate-split``), else :func:`audit_split` (the
    search split where the family has no sealed one: the paper's protocol)."""
    if chosen is None:
        return audit_split(family)
    try:
        split = Split(chosen)
    except ValueError:
        raise AuditError(f"--gate-split must be {Split.SEARCH} or {Split.TEST} (got {chosen!r})") from None
    if split is Split.TEST and not family.has_test_split:
        raise AuditError(
            f"--gate-split test: family {family.name!r} declares no sealed test split (family.json test_split)"
        )
    return split


def has_noise(family: Family, split: Split) -> bool:
    """Whether the family's seed noise is measured on ``split``."""
    noise = family.seed_noise or {}
    part = noise.get(Split.TEST.value) if split is Split.TEST else noise
    return isinstance(part, dict) and all(isinstance(part.get(k), (int, float)) for k in ("mean", "std", "k"))


def seed_noise(family: Family, split: Split = Split.SEARCH) -> dict[str, Any]:
    """The family's seed noise on ``split``: {"mean", "std", "k", ...}."""
    if not has_noise(family, split):
        what = (
            "measured seed noise" if split is Split.SEARCH else "seed noise measured on its sealed test split"
        )
        raise AuditError(
            f"family {family.name!r} has no {what} (mean, std, k) in {family.path / LEDGER_FILE}; "
            f"run `autoresearch noise --family {family.path}` first"
        )
    return family.seed_noise if split is Split.SEARCH else family.seed_noise[Split.TEST.value]


class Rereading:
    """A step's earlier part and the row counts of its append-only logs when it started again. A re-run
    that appends no row (every trial already logged) only re-read the finished step: its part keeps the
    provenance it was measured under, and when, instead of being re-stamped with a later commit."""

    def __init__(self, earlier: Any, logs: tuple[Path, ...]) -> None:
        self.earlier = earlier if isinstance(earlier, dict) and earlier.get("status") == "done" else {}
        self._logs = logs
        self._rows = self._count()

    def _count(self) -> list[int]:
        return [path.read_bytes().count(b"\n") if path.exists() else 0 for path in self._logs]

    def kept(self, key: str, current: Any) -> Any:
        """The earlier part's ``key`` if nothing new was measured since, else ``current``."""
        if self._count() == self._rows and self.earlier.get(key) is not None:
            return self.earlier[key]
        return current


@dataclass(frozen=True)
class AuditedCampaign:
    store: Campaign
    meta: CampaignMeta  # campaign.json
    family: Family
    records: list[Record]  # proposals.jsonl
    provenance: dict[str, Any] | None = None  # what this audit runs under (each step records it)

    @property
    def paths(self) -> CampaignPaths:
        return self.store.paths

    @property
    def root(self) -> Path:
        return self.paths.root

    def step_dir(self, step: str) -> Path:
        return self.paths.step_dir(step)

    def rereading(self, step: str, *logs: Path) -> Rereading:
        """``step``'s earlier part, to be kept if this run of it measures nothing new (none of its
        append-only ``logs`` grows). Call before the step writes its "running" part over it."""
        return Rereading(read_audit(self.root).get(step), logs)

    @property
    def timeout(self) -> float:
        """The campaign's hard limit of one of its runs (and of a matched arm's)."""
        return self.meta.run_timeout

    @property
    def audit_timeout(self) -> float:
        """The hard limit of one audit run: the campaign's, plus its evaluation allowance where the
        audit also scores the sealed test split (:func:`audit_split`), which no search run did. Without
        it a recipe the search ran near its limit fails reseeds for the audit's own evaluation
        (measured: 2 of 10 reseeds on rendezvous at a 120 s limit, results/keyfree-search)."""
        extra = self.meta.eval_allowance if audit_split(self.family) is Split.TEST else 0.0
        return self.timeout + extra

    @property
    def time_budget(self) -> float | None:
        """The training seconds the campaign granted each run: every audit run is granted the same, so a
        reseed repeats the experiment the search scored (a budget-cut run included)."""
        return self.meta.time_budget

    @property
    def ran(self) -> list[Record]:
        """Runs with a result: a failed or early-stopped run is never a candidate."""
        return [r for r in self.records if r.ran]

    def single_seed_best(self) -> Record | None:
        """The campaign's best feasible run (a one-seed claim), the earliest iteration on ties."""
        return best_feasible(self.ran, self.family.direction)


def open_campaign(campaign_dir: str | Path, read_only: bool = False) -> AuditedCampaign:
    """The campaign in ``campaign_dir`` for an audit step, or read-only (``check``, ``report``): then
    its provenance runs nothing of the family's repository (autoresearch.provenance)."""
    store = Campaign(Path(campaign_dir).resolve())
    if not store.exists() or not store.paths.proposals.exists():
        raise AuditError(f"{campaign_dir}: not a campaign directory (no campaign.json or proposals.jsonl)")
    refusal = trail_refusal(campaign_dir)  # a repeated or missing record would count runs twice or not at all
    if refusal:
        raise AuditError(refusal)
    try:
        meta = store.meta()
        family = meta.open_family(store.root)
        records = store.records()
    except CampaignError as err:
        raise AuditError(str(err)) from None
    return AuditedCampaign(store, meta, family, records, provenance.collect(family.path, read_only))


def provenance_report(campaign: AuditedCampaign, strict: bool) -> list[str]:
    """Differences between the environment now and the one recorded for the campaign's runs and for
    each audit step already done (autoresearch.provenance.report)."""
    recorded = [("campaign.json, first session", campaign.meta.provenance)]
    audit = read_audit(campaign.root)
    recorded += [
        (f"audit.json {step}", part["provenance"])
        for step, part in audit.items()
        if isinstance(part, dict) and part.get("provenance")
    ]
    return provenance.report(
        recorded, campaign.provenance or provenance.collect(campaign.family.path), strict
    )
