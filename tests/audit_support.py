"""Helpers for the audit tests: family copies and campaigns made by the real loop (with the
campaign.json that ``autoresearch loop`` writes, which the audit reads)."""

from __future__ import annotations

import shutil
from pathlib import Path

from loop_helpers import TOY_FAMILY, ScriptedProposer

from autoresearch.campaign import CampaignMeta
from autoresearch.family import Family
from autoresearch.loop.orchestrator import LoopSettings, Orchestrator
from autoresearch.loop.stopping import Budgets
from autoresearch.proposers.base import Proposer

AUDIT_FAMILY = Path(__file__).resolve().parent / "audit_family"
__all__ = [
    "AUDIT_FAMILY",
    "P1",
    "P1W",
    "P2",
    "TOY_FAMILY",
    "ScriptedProposer",
    "copy_family",
    "family_best",
    "run_campaign",
]

# tests/audit_family's designed edits (see its train.py): P1 edits one parameter per
# Eq. loodecision case; P2 adds the pair that matters only jointly; P1W is P1 made erratic.
P1 = {"EPOCHS": 60, "SAFE": True, "HITCH": "b", "BORDER": 1.0, "DAGGER": 1, "GAP": 1.0}
P2 = {**P1, "JOINT_A": True, "JOINT_B": True}
P1W = {**P1, "WIDE": True}


def copy_family(src: Path, dest: Path) -> Family:
    """A private copy: the audit writes the family's best and its ledger."""
    shutil.copytree(src, dest, ignore=shutil.ignore_patterns("runs.jsonl*", "__pycache__"))
    return Family.load(dest)


def family_best(family_dir: Path) -> dict | None:
    """The ledger's entry of the family's best, as the audit left it."""
    family = Family.load(family_dir)
    return family.ledger.current(family.best)


def run_campaign(
    family: Family,
    root: Path,
    proposer: Proposer,
    iterations: int,
    timeout: float = 60.0,
    time_budget: float | None = None,
    protocol: str | None = None,
) -> Path:
    """A campaign directory as ``autoresearch loop`` writes it (campaign.json included)."""
    root.mkdir(parents=True)
    settings = {"timeout_per_run": timeout, "seed": 0, "max_iters": iterations, "time_budget": time_budget}
    family = family.under_protocol(protocol)
    CampaignMeta.new(family, proposer.name, {**settings, "protocol": protocol}).write(root)
    budgets = Budgets(max_iters=iterations, plateau_window=10**6)
    loop = LoopSettings(proposer.name, budgets, timeout_per_run=timeout, time_budget=time_budget)
    Orchestrator(family, proposer, root, loop).run()
    return root
