"""Leave-one-out pruning of the promoted configuration (paper Eqs. loo, loodecision, prunereverify).

Each edited parameter is reverted alone to its family default and probed at one fresh seed;
an inconclusive probe escalates to a second seed (Delta2 is the two-seed mean). Dropped edits
are then reverted together and the pruned recipe is re-verified at fresh seeds: it is published
only if it clears the same gate and keeps the target. Otherwise the full configuration stands
and the dropped group is reported as mattering jointly.

Two cases the metric-only equation does not cover, both resolved as keep: a reverted run that
fails to train, and one that is infeasible (reverting breaks the safety constraint, e.g. the
docking family's run-time filter).
"""

from __future__ import annotations

from typing import Any

from autoresearch.audit import stats
from autoresearch.audit.auditjson import read_audit, set_family_field, write_step
from autoresearch.audit.inputs import AuditError, Campaign, config_id
from autoresearch.audit.seeds import fresh_seeds, used_seeds
from autoresearch.audit.trials import Trial, run_trials
from autoresearch.audit.verify import assess
from autoresearch.executors import Executor
from autoresearch.journal import read_json
from autoresearch.verdicts import reaches_target

STEP = "prune"
N_PROBES = 2  # Eq. loodecision: one probe seed, escalated to two


def _probe(row: dict[str, Any]) -> dict[str, Any]:
    return {k: row[k] for k in ("seed", "run_id", "status", "metric", "feasible")}


def _blocked(row: dict[str, Any]) -> str | None:
    """Why a probe cannot be read as a metric change (then the edit is kept), or None."""
    if row["status"] != "ok":
        return f"the reverted configuration failed to run ({row['reason']})"
    if not row["feasible"]:
        return "the reverted configuration is infeasible: the edit carries the constraint"
    return None


def leave_one_out(
    campaign: Campaign, executor: Executor, full: dict[str, Any], sigma: float, probe_seeds: list[int]
) -> dict[str, dict[str, Any]]:
    """Eqs. loo and loodecision for every edit of ``full``: {param: its decision record}."""
    family, sign = campaign.family, campaign.family.direction
    config, mu_r, baseline = full["config"], full["mu_r"], family.baseline_config
    root = campaign.step_dir(STEP)

    def probe(names: list[str], seed: int) -> list[dict[str, Any]]:
        trials = [
            Trial(f"loo-{full['config_id']}-{name}-s{seed}", {**config, name: baseline[name]}, seed)
            for name in names
        ]
        return run_trials(family, trials, executor, root / "prune.jsonl", root, campaign.timeout)

    decisions = {
        name: {
            "param": name,
            "axis": family.space.params[name].axis,
            "value": config[name],
            "default": baseline[name],
        }
        for name in full["changed"]
    }
    stage = list(decisions)  # stage 1: every edit at the first probe seed; stage 2: the escalated
    for seed in probe_seeds:
        for name, row in zip(stage, probe(stage, seed), strict=True):
            d = decisions[name]
            d.setdefault("probes", []).append(_probe(row))
            d["note"] = _blocked(row)
            if d["note"]:
                d["decision"] = stats.KEEP
                continue
            key = "delta1" if len(d["probes"]) == 1 else "delta2"  # Delta2: the two-seed mean
            d[key] = stats.loo_delta([p["metric"] for p in d["probes"]], mu_r, sign)
            d[f"{key}_sigma"] = d[key] / sigma
            d["decision"] = stats.loo_decision(d["delta1"], sigma, d.get("delta2"))
        stage = [name for name in stage if decisions[name]["decision"] == stats.ESCALATE]
    return decisions


def prune(campaign: Campaign, executor: Executor, *, n_seeds: int | None = None) -> dict[str, Any]:
    """Leave-one-out over the promoted configuration, then re-verification of the pruned recipe."""
    verified = read_audit(campaign.root).get("verify")
    if not verified or verified.get("status") != "done":
        raise AuditError(
            f"no finished verification in {campaign.root}; run `autoresearch verify --campaign` first"
        )
    if verified["promoted"] is None:
        part = {"status": "skipped", "reason": "verification promoted no configuration: nothing to prune"}
        write_step(campaign.root, STEP, part)
        return part
    family, sign = campaign.family, campaign.family.direction
    noise = verified["noise"]  # the noise the promotion was judged against
    full = next(c for c in verified["candidates"] if c["config_id"] == verified["promoted"])
    n_seeds = n_seeds or len(verified["seeds"])
    if n_seeds < 2:
        raise ValueError(f"--seeds {n_seeds}: re-verification needs >= 2 seeds")
    used = used_seeds(family.default_seed, family.seed_noise, [campaign.root], skip_step=STEP)
    seeds = fresh_seeds(used, N_PROBES + n_seeds)
    part: dict[str, Any] = {
        "promoted": full["config_id"],
        "mu_r": full["mu_r"],
        "noise": noise,
        "probe_seeds": seeds[:N_PROBES],
        "reverify_seeds": seeds[N_PROBES:],
    }
    write_step(campaign.root, STEP, {**part, "status": "running"})
    decisions = leave_one_out(campaign, executor, full, noise["std"], part["probe_seeds"])
    dropped = [n for n, d in decisions.items() if d["decision"] in stats.DROPPED]
    part.update(
        decisions=list(decisions.values()),
        kept=[n for n in decisions if n not in dropped],
        dropped=dropped,
        flagged=[n for n, d in decisions.items() if d["decision"] == stats.DROP_DAGGER],
        pruned=None,
        published=False,
        status="done",
    )
    if not dropped:
        part["reason"] = "every edit is load-bearing: nothing to prune"
        write_step(campaign.root, STEP, part)
        return part

    pruned_config = {**full["config"], **{name: family.baseline_config[name] for name in dropped}}
    cid, root = config_id(pruned_config), campaign.step_dir(STEP)
    trials = [Trial(f"prune-{cid}-s{seed}", pruned_config, seed) for seed in part["reverify_seeds"]]
    rows = run_trials(family, trials, executor, root / "prune.jsonl", root, campaign.timeout)
    pruned = {"config_id": cid, "config": pruned_config, **assess(rows, None, noise, sign)}
    publish, retained = False, None
    if "mu_r" in pruned:
        publish, retained = stats.prune_publish(
            pruned["passed"], pruned["mu_r"], full["mu_r"], family.target, sign
        )
    part.update(pruned=pruned, published=publish, target_retained=retained)
    if publish:
        kept = (
            "keeps the target"
            if reaches_target(full["mu_r"], family.target, sign)
            else "has no target to keep (the full recipe did not reach it either)"
        )
        part["reason"] = f"the pruned recipe (without {', '.join(dropped)}) clears the gate and {kept}"
        _attach_distilled(campaign, full, pruned, dropped)
    else:
        lost = pruned["reason"] if not pruned["passed"] else "it loses the target the full recipe reached"
        part["reason"] = (
            f"the dropped group {', '.join(dropped)} matters jointly: the pruned recipe fails re-verification "
            f"({lost}); the full configuration is kept"
        )
    write_step(campaign.root, STEP, part)
    return part


def _attach_distilled(
    campaign: Campaign, full: dict[str, Any], pruned: dict[str, Any], dropped: list[str]
) -> None:
    """A published pruned recipe is recorded beside the family best, which stays the promoted full
    configuration (the paper's docking case: the distilled recipe clears the gate, but the full one
    is the more accurate and reproducible)."""
    best = read_json(campaign.family.path / "family.json").get("best") or {}
    source = best.get("source") or {}
    if not (
        isinstance(source, dict)
        and source.get("campaign") == str(campaign.root)
        and best["config"] == full["config"]
    ):
        return  # the family best came from elsewhere; the distilled recipe stays in audit.json
    distilled = {
        "config": pruned["config"],
        "metric": pruned["mu_r"],
        "std": pruned["sigma_r"],
        "n": pruned["n"],
    }
    set_family_field(campaign.family.path, "best", {**best, "distilled": {**distilled, "dropped": dropped}})
