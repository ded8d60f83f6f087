"""What a campaign's audit came to, read from its audit.json: the configuration it promoted (the
pruned recipe the deciding leave-one-out rule promoted in place of the full configuration, else
verification's promoted candidate), certified on which split and by how much, and every reseeded
run behind it; for the report, the figures, the exported policy and the Optuna study."""

from __future__ import annotations

from typing import Any

from autoresearch.audit.prune import DECIDED_BY
from autoresearch.audit.prune import STEP as PRUNE_STEP
from autoresearch.audit.verify import STEP as VERIFY_STEP


def promoted(audit: dict[str, Any]) -> tuple[str, dict[str, Any]] | None:
    """The promoted configuration's entry and the step whose runs hold its reseeds; None when
    nothing passed."""
    decided = audit.get((audit.get(DECIDED_BY) or {}).get("key", PRUNE_STEP)) or {}
    if decided.get("promotes_pruned"):
        return PRUNE_STEP, decided["pruned"]
    verify = audit.get("verify") or {}
    found = next((c for c in verify.get("candidates", []) if c["config_id"] == verify.get("promoted")), None)
    return (VERIFY_STEP, found) if found else None


def certified(audit: dict[str, Any]) -> dict[str, Any] | None:
    """The audit's outcome as plain data: the promoted configuration (PASS), else the first one
    reseeded (FAIL), with its reseeded mean, sd and margin on the gated split; None before any
    configuration was reseeded."""
    verify = audit.get("verify") or {}
    found = promoted(audit)
    if found is None:
        tried = next((c for c in verify.get("candidates", []) if "mu_r" in c), None)
        found = (VERIFY_STEP, tried) if tried else None
    if found is None:
        return None
    step, entry = found
    return {
        "verdict": "PASS" if entry["passed"] else "FAIL",
        "promoted": entry["passed"],
        "step": step,
        "config_id": entry["config_id"],
        "config": entry["config"],
        "split": verify.get("split", "search"),
        "metric": entry["mu_r"],
        "sigma_r": entry["sigma_r"],
        "n": entry["n"],
        "margin_sigma": entry["margin"],
        "by_split": entry.get("by_split") or {},
    }


def reseeded_runs(audit: dict[str, Any]) -> list[dict[str, Any]]:
    """Every reseeded run of the audit: each verification candidate's and each pruned recipe's
    re-verification, as {step, config_id, config, promoted, split, seed, run_id, status, metric,
    feasible, excluded}."""
    verify = audit.get("verify") or {}
    entries = [(VERIFY_STEP, c) for c in verify.get("candidates", []) if "reseeds" in c]
    decided = (audit.get(DECIDED_BY) or {}).get("key", PRUNE_STEP)
    pruned = (audit.get(decided) or {}).get("pruned")
    if pruned and "reseeds" in pruned:
        entries.append((PRUNE_STEP, pruned))
    found = promoted(audit)
    runs = []
    for step, entry in entries:
        for reseed in entry["reseeds"]:
            runs.append(
                {
                    "step": step,
                    "config_id": entry["config_id"],
                    "config": entry["config"],
                    "promoted": found is not None and found[1] is entry,
                    "split": entry.get("split", verify.get("split", "search")),
                    **{
                        k: reseed.get(k)
                        for k in ("seed", "run_id", "status", "metric", "feasible", "excluded")
                    },
                }
            )
    return runs
