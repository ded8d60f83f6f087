"""Reseeded verification (paper Eq. reseedgate) and promotion of the family best.

The configurations are rebuilt from proposals.jsonl (each record carries the full config),
deduplicated with the seed removed, ranked under the feasibility rule, and the top few are
re-run at fresh seeds shared by all candidates (a paired design). A candidate passes when its
reseeded mean clears the seed noise by m >= 2 and it is feasible on every valid reseed.

Promotion rule: of the passing candidates, the most reproducible one is promoted, i.e. the one
whose 95 % confidence interval of the reseeded mean has the best pessimistic end (for a
minimized metric, the lowest upper bound). It may differ from the single-seed best: a lucky,
erratic configuration loses to a tight one, as in both of the paper's campaigns.

The splits: the search split chooses, the sealed test split gates. For a family with a sealed
test split every reseed is scored on both splits from one training. The gate runs on the test
split, against the seed noise measured there; it can refuse a candidate but never ranks one: the
promotion rule reads each candidate's reseeded search-split mean (:func:`pick_key`), so which
recipe is promoted is decided without the sealed split, and its test-split numbers are a
measurement of that choice, not the best of several (``--gate-split search`` gates on the search
split too: the paper's protocol). Each candidate carries ``by_split``: its reseeded mean on every
split it was scored on, the selection gap side by side.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

from autoresearch import ledger
from autoresearch.audit import stats, tails
from autoresearch.audit.inputs import (
    AuditedCampaign,
    AuditError,
    changed_params,
    config_id,
    gate_split,
    seed_noise,
)
from autoresearch.audit.noise import stale_noise
from autoresearch.audit.seeds import fresh_seeds, used_seeds
from autoresearch.audit.trials import Trial, run_trials
from autoresearch.campaign import Record
from autoresearch.campaign.audit_log import TrialRow, write_step
from autoresearch.execution.executors import Executor
from autoresearch.family import Family
from autoresearch.ledger import Ledger, best_of
from autoresearch.splits import Split
from autoresearch.verdicts import best_feasible, ranking

STEP = "verify"
PICK_SPLIT = Split.SEARCH  # what ranks candidates; the sealed split only gates (module docstring)


def on_split(candidate: dict[str, Any], split: Split) -> dict[str, Any]:
    """A reseeded candidate's {mu_r, sigma_r, n} on ``split`` (an entry written before ``by_split``
    was scored on the search split alone)."""
    return (candidate.get("by_split") or {}).get(split.value) or candidate


def pick_key(candidate: dict[str, Any], sign: int) -> tuple[float, float]:
    """The promotion rule's key for a reseeded candidate, on the search split: the pessimistic end
    of its reseeded mean's 95 % interval, then the mean (higher is better)."""
    on = on_split(candidate, PICK_SPLIT)
    if on.get("sigma_r") is None:  # a single valid reseed: no interval, ranked last
        return -math.inf, sign * on["mu_r"]
    return stats.reproducibility_bound(on["mu_r"], on["sigma_r"], on["n"], sign), sign * on["mu_r"]


def rank_candidates(campaign: AuditedCampaign, top: int) -> list[dict[str, Any]]:
    """The ``top`` best distinct feasible configurations other than the baseline, each with the run
    that produced it (its best run, were a configuration run more than once)."""
    family, sign = campaign.family, campaign.family.direction
    best: dict[str, Record] = {}
    for record in campaign.ran:
        if changed_params(family, record.config):
            cid = config_id(record.config)
            best[cid] = best_feasible([best.get(cid), record], sign)
    ranked = sorted((r for r in best.values() if r is not None), key=ranking(sign))[:top]
    return [
        {
            "config_id": config_id(r.config),
            "config": r.config,
            "changed": changed_params(family, r.config),
            "source": {
                "iteration": r.iteration,
                "run_id": r.run_id,
                "seed": r.seed,
                "metric": r.metric,
                "best_train_loss": (r.final_metric or {}).get("best_train_loss"),
            },
        }
        for r in ranked
    ]


def split_summary(values: list[float], feasible: list[bool]) -> dict[str, Any]:
    """Mean, sd and feasible count of one split's values over the valid reseeds (ungated)."""
    n = len(values)
    mean = sum(values) / n if n else None
    sd = (sum((v - mean) ** 2 for v in values) / (n - 1)) ** 0.5 if n >= 2 else None
    return {"mu_r": mean, "sigma_r": sd, "n": n, "n_feasible": sum(feasible)}


def assess(
    rows: list[TrialRow],
    source_loss: float | None,
    noise: dict[str, Any],
    sign: int,
    split: Split = Split.SEARCH,
    tail_fields: dict[str, str] | None = None,
    gate_name: str = tails.PAPER,
) -> dict[str, Any]:
    """Parity guard, then Eq. reseedgate and the Welch CI of the mean difference over the valid
    reseeds, on ``split`` (``noise`` is the seed noise measured on it). A reseed that failed to run
    fails the gate (re-running the step retries it). Every reseed reports its worst starts when the
    family declares ``tail_fields``; under the runaway gate (``gate_name``) a candidate with a reseed
    that has a start beyond the family's runaway bound fails too (autoresearch.audit.tails)."""
    reseeds, valid = [], []
    for row in rows:
        excluded = None
        if not row.ok:
            excluded = f"run {row.status}: {row.reason}"
        elif not stats.parity_guard(row.best_train_loss, source_loss):
            excluded = f"parity guard: best_train_loss {row.best_train_loss:.4g} > 2 x {source_loss:.4g}"
        else:
            valid.append(row)
        score = row.on(split)
        reseeds.append(
            {
                "seed": row.seed,
                "run_id": row.run_id,
                "status": row.status,
                "best_train_loss": row.best_train_loss,
                "metric": score and score.metric,
                "feasible": score and score.feasible,
                "excluded": excluded,
            }
        )
        if split is not Split.SEARCH:
            search = row.on(Split.SEARCH)
            reseeds[-1]["search_metric"] = search and search.metric
        if tail_fields:
            reseeds[-1].update(tails.run_tail(row.final_metric, split, tail_fields))
    splits = [Split.SEARCH, Split.TEST] if any(row.on(Split.TEST) for row in valid) else [Split.SEARCH]
    by_split = {}
    for name in splits:
        scores = [row.on(name) for row in valid]
        by_split[name.value] = split_summary([s.metric for s in scores], [s.feasible for s in scores])
    scores = [row.on(split) for row in valid]
    values, feasible = [s.metric for s in scores], [s.feasible for s in scores]
    n_failed = sum(not row.ok for row in rows)
    out: dict[str, Any] = {
        "split": split.value,
        "reseeds": reseeds,
        "n": len(values),
        "n_failed": n_failed,
        "n_parity_excluded": len(rows) - n_failed - len(values),
        "n_feasible": sum(feasible),
        "by_split": by_split,
        "tails": tails.summarize(reseeds, declared=bool(tail_fields), sign=sign),
    }
    if not values:
        return {**out, "passed": False, "reason": "no valid reseeds"}
    gate = stats.reseed_gate(values, feasible, noise["mean"], noise["std"], sign)
    reasons = [] if gate.passed else [gate.reason]
    if n_failed:
        reasons.append(f"{n_failed} reseed(s) failed to run")
    runaway = tails.runaway_reason(out["tails"])
    if runaway and gate_name == tails.RUNAWAY:
        reasons.append(runaway)
    out.update(
        mu_r=gate.mu_r,
        sigma_r=gate.sigma_r,
        margin=gate.margin,
        all_feasible=gate.all_feasible,
        passed=not reasons,
        reason="; ".join(reasons) or "PASS",
    )
    if gate.sigma_r is not None:
        out["bound"] = stats.reproducibility_bound(gate.mu_r, gate.sigma_r, gate.n, sign)
        if noise["k"] >= 2:
            d = stats.mean_difference_ci(
                gate.mu_r, gate.sigma_r, gate.n, noise["mean"], noise["std"], noise["k"], sign
            )
            out.update(diff=d.diff, ci_low=d.low, ci_high=d.high)
    return out


def repository_root(family: Family) -> Path:
    """The repository holding the family (the nearest ancestor with a .git), else the directory
    holding the family: what family.json's paths are written relative to."""
    for parent in family.path.resolve().parents:
        if (parent / ".git").exists():
            return parent
    return family.path.resolve().parent


def campaign_ref(campaign: AuditedCampaign) -> str:
    """The campaign's path as family.json records it: relative to the repository root, so a
    committed family.json holds no path of the machine that ran the audit."""
    return Path(os.path.relpath(campaign.root.resolve(), repository_root(campaign.family))).as_posix()


def is_this_campaign(source: Any, campaign: AuditedCampaign) -> bool:
    """Whether a family best's ``source`` names ``campaign`` (relative, or absolute as older audits wrote)."""
    if not isinstance(source, dict) or not isinstance(source.get("campaign"), str):
        return False
    recorded = Path(source["campaign"])
    if not recorded.is_absolute():
        recorded = repository_root(campaign.family) / recorded
    return os.path.normpath(recorded) == os.path.normpath(campaign.root.resolve())


def _at_least_as_tight(limits: dict[str, float], than: dict[str, float]) -> bool:
    """Whether ``limits`` bound every field ``than`` bounds, each at most as high."""
    return all(name in limits and limits[name] <= bound for name, bound in than.items())


def _named(source: dict[str, Any]) -> str:
    """Where a best came from, in words: ``run it0010 of results/x, verified``, not a dict."""
    if not source.get("campaign"):
        return "of an earlier audit"
    run = f"run {source['run_id']} of " if source.get("run_id") else ""
    step = {"verify": "verified", "prune": "pruned"}.get(source.get("step"), source.get("step") or "")
    return f"{run}{source['campaign']}" + (f", {step}" if step else "")


def _limits(limits: dict[str, Any]) -> str:
    """``effort_ratio <= 1.5``, or ``none``."""
    return ", ".join(f"{name} <= {value:g}" for name, value in limits.items()) or "none"


def _replaces_family_best(
    current: dict[str, Any] | None, family: Family, candidate: dict[str, Any], campaign: AuditedCampaign
) -> tuple[bool, str]:
    """A promotion replaces the family's best unless another campaign's best is more reproducible on
    the same split under the same limits, is certified on the sealed split while this candidate is
    not, or met limits (a protocol's) this candidate was not held to; one certified on the sealed
    split or under tighter limits, and weaker in neither, replaces it."""
    if not current:
        return True, "the family had no best"
    source = current.get("source") or {}
    named = _named(source)
    if is_this_campaign(source, campaign):
        return True, "replaces this campaign's earlier promotion"
    if current.get("std") is None or (current.get("n") or 0) < 2:
        return True, "the family's previous best was not reseeded"
    # Neither the split nor the gate may loosen: a candidate weaker on either keeps the best, one
    # stronger on either (and weaker on neither) replaces it, and only equals compare their bounds.
    current_split, split = current.get("split", Split.SEARCH.value), candidate["split"]
    held, holds = current.get("limits") or {}, family.limits
    if current_split == Split.TEST.value and split != current_split:
        return False, f"the family's best ({named}) is certified on the sealed test split"
    if not _at_least_as_tight(holds, held):
        return (
            False,
            f"the family's best ({named}) is certified under limits ({_limits(held)}) this candidate was not held to",
        )
    if split != current_split:
        return True, "the family's previous best was certified on the search split only"
    if held != holds:
        return (
            True,
            f"certified under tighter limits ({_limits(holds)}) than the family's previous best ({_limits(held)})",
        )
    sign = family.direction
    old = stats.reproducibility_bound(current["metric"], current["std"], current["n"], sign)
    if candidate["bound"] >= old:
        return True, f"more reproducible on the {split} split than the family's previous best"
    return (
        False,
        f"the family's best ({named}) has the better bound on the {split} split ({sign * old:.4g})",
    )


def promote(
    campaign: AuditedCampaign, candidate: dict[str, Any], step: str = STEP, **extra: Any
) -> dict[str, Any]:
    """Write ``candidate`` as the family best if it replaces the one family.json holds when written
    (decided under the file's lock: a concurrent audit of another campaign cannot be overwritten
    with a worse best). ``step`` names the audit step that certified it (verify, or a prune rule's
    re-verification of a pruned recipe, whose ``extra`` fields say what it was pruned from).
    Returns {"updated", "why"}."""
    family = campaign.family

    entry = {
        "config": candidate["config"],
        "metric": candidate["mu_r"],
        "std": candidate["sigma_r"],
        "n": candidate["n"],
        "split": candidate["split"],
        "by_split": candidate["by_split"],
        "source": {"campaign": campaign_ref(campaign), "run_id": candidate["source"]["run_id"], "step": step},
        # the recipe is defined with the budget its reseeds trained under (EPOCHS may not fit in it)
        **({"time_budget": campaign.time_budget} if campaign.time_budget is not None else {}),
        **({"limits": family.limits} if family.limits else {}),  # the gate it passed
        **extra,
    }

    def decide(registry: dict[str, Any], old: Ledger) -> tuple[Ledger, dict[str, Any]]:
        best = registry.get("best")
        if old.current(best) == entry:  # the audit step run again on the same reseeds: one history entry
            return old, {"updated": False, "why": "this very certification is already the family's best"}
        write, why = _replaces_family_best(old.current(best) or best, family, candidate, campaign)
        if write:
            registry["best"], old = best_of(entry), old.promoted(entry)
        return old, {"updated": write, "why": why}

    return ledger.update(family.path, decide)


def verify(
    campaign: AuditedCampaign,
    executor: Executor,
    *,
    top: int = 3,
    n_seeds: int = 10,
    split: str | None = None,
    gate: str = tails.RUNAWAY,
) -> dict[str, Any]:
    """Reseed the top candidates, gate them on ``split`` (default: the sealed test split where the
    family has one) with ``gate`` (the runaway gate, or the paper's alone), promote the most
    reproducible passing one."""
    if gate not in tails.GATES:
        raise ValueError(f"--gate must be one of {', '.join(tails.GATES)} (got {gate!r})")
    if top < 1:
        raise ValueError(f"--top must be >= 1 (got {top})")
    if n_seeds < 2:
        raise ValueError(f"--seeds {n_seeds}: reseeded verification needs >= 2 seeds")
    family, sign = campaign.family, campaign.family.direction
    split = gate_split(family, split)
    noise = seed_noise(family, split)
    stale = stale_noise(family)
    if stale:  # a gate against another version's noise would certify nothing
        raise AuditError(
            f"family {family.name!r}: its seed noise was measured on another version of it ({'; '.join(stale)}); "
            f"measure it again first: `autoresearch noise --family {family.path}` (or `autoresearch audit`, "
            "which does it)"
        )
    candidates = rank_candidates(campaign, top)
    best_run = campaign.single_seed_best()
    part: dict[str, Any] = {
        "split": split.value,
        "gate": gate,
        "sealed_split": family.has_test_split,
        "noise": {k: noise[k] for k in ("mean", "std", "k")},
        "top": top,
        "picked_on": PICK_SPLIT.value,
        "single_seed_best": None,
        "candidates": candidates,
        "promoted": None,
        "provenance": campaign.provenance,
    }
    if best_run is not None:
        part["single_seed_best"] = {
            "config_id": config_id(best_run.config),
            "run_id": best_run.run_id,
            "iteration": best_run.iteration,
            "metric": best_run.metric,
        }
    if not candidates:
        part.update(
            status="done", reason="no feasible configuration other than the baseline to verify", seeds=[]
        )
        write_step(campaign.root, STEP, part)
        return part
    used = used_seeds(family.default_seed, family.seed_noise, [campaign.root], skip_step=STEP)
    part["seeds"] = fresh_seeds(used, n_seeds)
    trials = [
        Trial(f"verify-{c['config_id']}-s{s}", c["config"], s) for c in candidates for s in part["seeds"]
    ]
    root = campaign.step_dir(STEP)
    earlier = campaign.rereading(STEP, root / "verify.jsonl")
    write_step(campaign.root, STEP, {**part, "status": "running"})
    rows = run_trials(
        family,
        trials,
        executor,
        root / "verify.jsonl",
        root,
        campaign.audit_timeout,
        time_budget=campaign.time_budget,
    )
    for i, candidate in enumerate(candidates):
        own = rows[i * n_seeds : (i + 1) * n_seeds]
        source_loss = candidate["source"]["best_train_loss"]
        candidate.update(assess(own, source_loss, noise, sign, split, family.tail_fields, gate))
    passing = [c for c in candidates if c["passed"]]
    if passing:
        promoted = max(passing, key=lambda c: pick_key(c, sign))
        part["promoted"] = promoted["config_id"]
        part["family_best"] = promote(campaign, promoted)
    part.update(
        status="done",
        reason=f"{len(passing)} of {len(candidates)} candidate(s) passed the gate on the {split} split"
        + (f"; of those, the best bound on the {PICK_SPLIT} split is promoted" if len(passing) > 1 else ""),
        provenance=earlier.kept("provenance", campaign.provenance),
    )
    write_step(campaign.root, STEP, part)
    return part
