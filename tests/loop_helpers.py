"""Shared helpers for the agent-loop tests: the toy family, a scripted proposer, snapshots."""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

from autoresearch.execution.executors import Executor
from autoresearch.family import Family
from autoresearch.journal import read_jsonl
from autoresearch.loop.orchestrator import LoopSettings, Orchestrator, Outcome
from autoresearch.loop.stopping import Budgets
from autoresearch.loop.warm_start import WarmStart
from autoresearch.proposers.base import Proposal, Proposer, ProposerContext, RunOutcome, Usage
from autoresearch.templates import MINIMAL_TEMPLATE

TOY_FAMILY = MINIMAL_TEMPLATE  # the toy family is the minimal template `autoresearch init` writes

# A feasible configuration of the toy family whose loss is far below its target (0.05).
TOY_OPTIMUM = {
    "EPOCHS": 30,
    "LEARNING_RATE": 0.003,
    "MOMENTUM": 0.8,
    "BATCH_SIZE": 32,
    "ACTIVATION": "gelu",
    "USE_NORM": True,
    "DROPOUT": 0.1,
}


def copy_toy(dest: Path, name: str = "toy") -> Path:
    target = dest / name
    shutil.copytree(TOY_FAMILY, target, ignore=shutil.ignore_patterns("runs.jsonl*", "__pycache__"))
    return target


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` with its bytes, to prove a directory was not modified."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


class ScriptedProposer(Proposer):
    """Plays a fixed script. An item is a Proposal, an override dict, or an exception to raise."""

    name = "scripted"

    def __init__(self, script: list[Any], usage: Usage | None = None):
        self.script = list(script)
        self.usage = usage or Usage()
        self.contexts: list[ProposerContext] = []
        self.tells: list[tuple[dict[str, Any], float | None, bool]] = []
        self.constraints: list[dict[str, float] | None] = []  # the graded constraints of each tell

    def propose(self, context: ProposerContext) -> Proposal:
        self.contexts.append(context)
        if not self.script:
            return Proposal(kind="invalid", error="script exhausted", usage=self.usage)
        item = self.script.pop(0)
        if isinstance(item, BaseException):
            raise item
        if isinstance(item, Proposal):
            return item
        return Proposal(
            kind="propose", overrides=item, annotation={"hypothesis": "scripted"}, usage=self.usage
        )

    def tell(self, outcome: RunOutcome) -> None:
        self.tells.append((outcome.config, outcome.metric, outcome.feasible))
        self.constraints.append(outcome.constraints)


def stop(status: str = "plateau") -> Proposal:
    return Proposal(kind="stop", annotation={"status": status, "conclusion": "done", "axes_tested": []})


def run_loop(
    family_dir: Path,
    proposer: Proposer,
    campaign: Path,
    *,
    blind: bool = False,
    timeout: float = 60.0,
    workers: int = 1,
    early_stop: str = "none",
    executor: Executor | None = None,
    time_budget: float | None = None,
    warm_start: WarmStart | None = None,
    **budgets: Any,
) -> tuple[Outcome, list[dict[str, Any]]]:
    budgets.setdefault("max_iters", 30)
    settings = LoopSettings(
        proposer_name=proposer.name,
        budgets=Budgets(**budgets),
        blind=blind,
        timeout_per_run=timeout,
        workers=workers,
        early_stop=early_stop,
        time_budget=time_budget,
        warm_start=warm_start,
    )
    outcome = Orchestrator(Family.load(family_dir), proposer, campaign, settings, executor=executor).run()
    return outcome, read_jsonl(campaign / "proposals.jsonl")


def processes_naming(text: str) -> list[tuple[int, str]]:
    """(pid, command line) of the live processes, other than this one, whose command line contains
    ``text`` (Linux /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            except OSError:
                continue
            if text in cmdline:  # a zombie's command line is empty
                found.append((int(entry.name), cmdline))
    return found
