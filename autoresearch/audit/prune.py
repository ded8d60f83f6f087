"""Leave-one-out pruning of the promoted configuration (paper Eqs. loo, loodecision, prunereverify).

The paper's rule (the default): each edited parameter is reverted alone to its family default and
probed at one fresh seed shared by all parameters; an inconclusive probe escalates to a second
seed (Delta2 is the two-seed mean), Delta measured against the candidate's reseeded mean mu_R in
units of the baseline's seed noise. Two options sharpen it (issue 14), each kept under its own
audit.json key beside the paper's:

- paired: every parameter gets its own probe seeds, and the full configuration runs at the same
  seeds; Delta is the mean paired difference, so no one unlucky seed decides for every parameter
  and the seed's luck cancels to the extent the two runs share it (common random numbers).
- noise at the candidate: the unit is the spread of the candidate's own reseeds (sigma_R from
  verification) instead of the baseline's, which can be far wider (rendezvous: 0.38 m at the
  4.1 m baseline against 0.0065 m at the 0.072 m recipe).

Dropped edits are then reverted together and the pruned recipe is re-verified at fresh seeds: it
is published only if it clears the same gate (against the baseline noise) and keeps the target.
Otherwise the full configuration stands and the dropped group is reported as mattering jointly.
A published recipe that also ranks above the full configuration by verification's promotion rule
(the better pessimistic end of its reseeded search-split mean's 95 % interval) is promoted in its place: it
becomes the family best, and the report's figures and exported policy are its. Otherwise it is
recorded beside the full configuration as its distilled recipe. The rule that runs last decides.

The splits, as in verification: the search split decides, the sealed test split gates. Every
probe and re-verification is scored on both splits (where the family has a sealed one) from one
training. Which edits are dropped is decided on the search split (probes against the candidate's
reseeded search-split mean, in units of the seed noise measured there), and so is whether the
pruned recipe ranks above the full one; the pruned recipe's re-verification is gated on the split
verification gated on, against that split's noise, and can refuse it there. A probe's record keeps
its test-split value beside the deciding one (``test_metric``).

Two cases the metric-only equation does not cover, both resolved as keep: a reverted run that
fails to train, and one that is infeasible (reverting breaks the safety constraint, e.g. the
docking family's run-time filter). A paired probe whose full-configuration run failed is kept too
(a re-run retries it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from autoresearch import ledger
from autoresearch.audit import stats, tails
from autoresearch.audit.inputs import AuditedCampaign, AuditError, Rereading, config_id, seed_noise
from autoresearch.audit.seeds import fresh_seeds, used_seeds
from autoresearch.audit.trials import Trial, run_trials
from autoresearch.audit.verify import PICK_SPLIT, assess, is_this_campaign, on_split, pick_key, promote
from autoresearch.audit.verify import STEP as VERIFY_STEP
from autoresearch.campaign.audit_log import TrialRow, read_audit, write_step
from autoresearch.execution.executors import Executor
from autoresearch.journal import read_json
from autoresearch.ledger import Ledger
from autoresearch.splits import Split
from autoresearch.verdicts import reaches_target

STEP = "prune"  # the paper rule's audit.json key; the log and run directories of every rule
DECIDED_BY = "prune_decided_by"  # audit.json: the key of the rule that ran last (it decides)
N_PROBES = 2  # Eq. loodecision: one probe seed, escalated to two
NOISE_AT = ("baseline", "candidate")


@dataclass(frozen=True)
class Rule:
    """Which leave-one-out rule: the paper's (unpaired, baseline noise) or a sharpened one."""

    paired: bool = False
    noise_at: str = "baseline"

    def __post_init__(self) -> None:
        if self.noise_at not in NOISE_AT:
            raise ValueError(f"--noise-at must be one of {', '.join(NOISE_AT)} (got {self.noise_at!r})")

    @property
    def key(self) -> str:
        """Its audit.json key: "prune" for the paper's rule, then "_paired" and "_candidate" suffixes."""
        return (
            STEP + ("_paired" if self.paired else "") + ("_candidate" if self.noise_at == "candidate" else "")
        )

    @property
    def name(self) -> str:
        base = "paired" if self.paired else "paper"
        return base + (", noise at the candidate" if self.noise_at == "candidate" else "")

    @property
    def plan_group(self) -> tuple[str, ...]:
        """The rules that share this one's seed plan, hence its runs (the unit changes no run)."""
        return tuple(Rule(self.paired, at).key for at in NOISE_AT)


RULES = tuple(Rule(paired, at) for paired in (False, True) for at in NOISE_AT)


def _probe(row: TrialRow, split: Split) -> dict[str, Any]:
    score, test = row.on(split), row.on(Split.TEST)
    return {
        "seed": row.seed,
        "run_id": row.run_id,
        "status": row.status,
        "metric": score and score.metric,
        "feasible": score and score.feasible,
        **({"test_metric": test.metric} if test and split is not Split.TEST else {}),
    }


def _blocked(row: TrialRow, full_row: TrialRow | None, split: Split) -> str | None:
    """Why a probe cannot be read as a metric change (then the edit is kept), or None."""
    if not row.ok:
        return f"the reverted configuration failed to run ({row.reason})"
    if not row.on(split).feasible:
        return "the reverted configuration is infeasible: the edit carries the constraint"
    if full_row is not None and not full_row.ok:
        return f"the full configuration failed at the paired seed ({full_row.reason}); re-run to retry"
    return None


def _run_trials(campaign: AuditedCampaign, trials: list[Trial], executor: Executor) -> list[TrialRow]:
    """The pruning step's trials, each run as the campaign's runs were (its limit, its time budget)."""
    root = campaign.step_dir(STEP)
    return run_trials(
        campaign.family,
        trials,
        executor,
        root / "prune.jsonl",
        root,
        campaign.audit_timeout,
        time_budget=campaign.time_budget,
    )


def leave_one_out(
    campaign: AuditedCampaign,
    executor: Executor,
    full: dict[str, Any],
    sigma: float,
    probe_seeds: dict[str, list[int]],
    paired: bool = False,
    split: Split = Split.SEARCH,
) -> dict[str, dict[str, Any]]:
    """Eqs. loo and loodecision for every edit of ``full``: {param: its decision record}.

    ``probe_seeds[name]`` are that edit's probe seeds in escalation order (the paper's rule gives
    every edit the same two); ``paired`` also runs the full configuration at each probe seed and
    decides on the paired differences, in units of ``sigma``; every value is read on ``split``.
    """
    family, sign = campaign.family, campaign.family.direction
    config, mu_r, baseline = full["config"], on_split(full, split)["mu_r"], family.baseline_config
    cid = full["config_id"]

    def probe(names: list[str], stage: int) -> tuple[list[TrialRow], dict[int, TrialRow]]:
        # Each reversion is followed by the full configuration at its seed, so that a stopped
        # step leaves complete pairs behind (the paper's rule runs no full configuration).
        trials, full_at = [], {}
        for name in names:
            seed = probe_seeds[name][stage]
            trials.append(Trial(f"loo-{cid}-{name}-s{seed}", {**config, name: baseline[name]}, seed))
            if paired and seed not in full_at:
                full_at[seed] = len(trials)
                trials.append(Trial(f"full-{cid}-s{seed}", config, seed))
        rows = _run_trials(campaign, trials, executor)
        reverted = [row for row in rows if row.key.startswith("loo-")]
        return reverted, {seed: rows[i] for seed, i in full_at.items()}

    decisions = {
        name: {
            "param": name,
            "axis": family.space.params[name].axis,
            "value": config[name],
            "default": baseline[name],
        }
        for name in full["changed"]
    }
    stage = list(decisions)  # stage 1: every edit at its first probe seed; stage 2: the escalated
    for k in range(N_PROBES):
        if not stage:
            break
        reverted, at_seed = probe(stage, k)
        for name, row in zip(stage, reverted, strict=True):
            d = decisions[name]
            full_row = at_seed.get(row.seed)
            d.setdefault("probes", []).append(_probe(row, split))
            if full_row is not None:
                full_score = full_row.on(split)
                d["probes"][-1].update(
                    full_run_id=full_row.run_id, full_metric=full_score and full_score.metric
                )
            d["note"] = _blocked(row, full_row, split)
            if d["note"]:
                d["decision"] = stats.KEEP
                continue
            key = "delta1" if len(d["probes"]) == 1 else "delta2"  # Delta2: the two-seed mean
            values = [p["metric"] for p in d["probes"]]
            if paired:
                d[key] = stats.paired_loo_delta(values, [p["full_metric"] for p in d["probes"]], sign)
            else:
                d[key] = stats.loo_delta(values, mu_r, sign)
            d[f"{key}_sigma"] = d[key] / sigma
            d["decision"] = stats.loo_decision(d["delta1"], sigma, d.get("delta2"))
        stage = [name for name in stage if decisions[name]["decision"] == stats.ESCALATE]
    return decisions


def _unit(rule: Rule, noise: dict[str, Any], full: dict[str, Any], split: Split) -> dict[str, Any]:
    """The decisions' noise unit on ``split``: the baseline's seed noise ``noise`` measured there, or
    the candidate's own reseed spread there."""
    if rule.noise_at == "baseline":
        return {"at": "baseline", "split": split.value, "sigma": noise["std"], "n": noise["k"]}
    on = on_split(full, split)
    sigma_r = on.get("sigma_r")
    if not sigma_r or sigma_r <= 0:
        raise AuditError(
            f"--noise-at candidate: the promoted configuration {full['config_id']} has no positive reseed "
            f"spread sigma_R in its verification (got {sigma_r!r}); re-run `autoresearch verify` with --seeds >= 2"
        )
    return {"at": "candidate", "split": split.value, "sigma": sigma_r, "n": on["n"]}


def _plan(
    campaign: AuditedCampaign, rule: Rule, names: list[str], n_seeds: int
) -> tuple[dict[str, list[int]], list[int]]:
    """Fresh probe seeds per edit, and the re-verification seeds, shared by the rules of one plan group."""
    family = campaign.family
    used = used_seeds(family.default_seed, family.seed_noise, [campaign.root], skip_step=rule.plan_group)
    n_probe = N_PROBES * len(names) if rule.paired else N_PROBES
    seeds = fresh_seeds(used, n_probe + n_seeds)
    if rule.paired:  # edit i: seeds i then n + i, so no seed decides for two edits
        per = {name: [seeds[i + k * len(names)] for k in range(N_PROBES)] for i, name in enumerate(names)}
    else:
        per = {name: seeds[:N_PROBES] for name in names}
    return per, seeds[n_probe:]


def prune(
    campaign: AuditedCampaign, executor: Executor, *, n_seeds: int | None = None, rule: Rule = Rule()
) -> dict[str, Any]:
    """Leave-one-out over the promoted configuration under ``rule``, then re-verification of the
    pruned recipe; the result goes to audit.json[rule.key]."""
    verified = read_audit(campaign.root).get("verify")
    if not verified or verified.get("status") != "done":
        raise AuditError(
            f"no finished verification in {campaign.root}; run `autoresearch verify --campaign` first"
        )
    if verified["promoted"] is None:
        part = {"status": "skipped", "reason": "verification promoted no configuration: nothing to prune"}
        _finish(campaign, rule, part)
        return part
    family, sign = campaign.family, campaign.family.direction
    noise = verified["noise"]  # the noise the gate was judged against, on its split
    split = Split(verified.get("split", Split.SEARCH))
    full = next(c for c in verified["candidates"] if c["config_id"] == verified["promoted"])
    decide = PICK_SPLIT
    unit = _unit(rule, noise if split is decide else seed_noise(family, decide), full, decide)
    n_seeds = n_seeds or len(verified["seeds"])
    if n_seeds < 2:
        raise ValueError(f"--seeds {n_seeds}: re-verification needs >= 2 seeds")
    per_edit, reverify_seeds = _plan(campaign, rule, full["changed"], n_seeds)
    part: dict[str, Any] = {
        "rule": rule.name,
        "paired": rule.paired,
        "split": split.value,
        "decided_on": decide.value,
        "unit": unit,
        "promoted": full["config_id"],
        "mu_r": on_split(full, decide)["mu_r"],
        "noise": noise,
        "probe_seeds": sorted({s for seeds in per_edit.values() for s in seeds}),
        "reverify_seeds": reverify_seeds,
        "provenance": campaign.provenance,
    }
    earlier = campaign.rereading(rule.key, campaign.step_dir(STEP) / "prune.jsonl")
    write_step(campaign.root, rule.key, {**part, "status": "running"})
    decisions = leave_one_out(
        campaign, executor, full, unit["sigma"], per_edit, paired=rule.paired, split=decide
    )
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
        _finish(campaign, rule, part, earlier)
        return part

    pruned_config = {**full["config"], **{name: family.baseline_config[name] for name in dropped}}
    cid = config_id(pruned_config)
    trials = [Trial(f"prune-{cid}-s{seed}", pruned_config, seed) for seed in part["reverify_seeds"]]
    rows = _run_trials(campaign, trials, executor)
    # The gate verification used (an audit.json written before it had one: the paper's).
    gate = verified.get("gate", tails.PAPER)
    assessed = assess(rows, None, noise, sign, split, family.tail_fields, gate)
    pruned = {"config_id": cid, "config": pruned_config, **assessed}
    publish, retained = False, None
    if "mu_r" in pruned:
        publish, retained = stats.prune_publish(
            pruned["passed"], pruned["mu_r"], full["mu_r"], family.target, sign
        )
    promotes = publish and pick_key(pruned, sign) > pick_key(full, sign)
    part.update(pruned=pruned, published=publish, target_retained=retained, promotes_pruned=promotes)
    if publish:
        if reaches_target(full["mu_r"], family.target, sign):
            kept = "keeps the target the full recipe reached"
        elif family.target is None:
            kept = "loses no target (the family sets none)"
        else:
            kept = "loses no target (the full recipe did not reach the family's target either)"
        part["reason"] = f"the pruned recipe (without {', '.join(dropped)}) clears the gate and {kept}"
    if promotes:
        part["reason"] += (
            "; it is also the more reproducible of the two (the better end of its reseeded mean's 95% "
            "interval), so it is promoted in place of the full configuration"
        )
        candidate = {**pruned, "source": full["source"]}
        part["family_best"] = promote(
            campaign, candidate, rule.key, pruned_from=full["config_id"], dropped=dropped
        )
    if publish and not promotes:
        _attach_distilled(campaign, full, pruned, dropped, rule)
    if not publish:
        lost = pruned["reason"] if not pruned["passed"] else "it loses the target the full recipe reached"
        part["reason"] = (
            f"the dropped group {', '.join(dropped)} matters jointly: the pruned recipe fails re-verification "
            f"({lost}); the full configuration is kept"
        )
    _finish(campaign, rule, part, earlier)
    return part


def _finish(
    campaign: AuditedCampaign, rule: Rule, part: dict[str, Any], earlier: Rereading | None = None
) -> None:
    if earlier is not None:  # a re-run that measured nothing new keeps what the step was measured under
        part["provenance"] = earlier.kept("provenance", part["provenance"])
    if not part.get("promotes_pruned"):
        _restore_full(campaign)
    write_step(campaign.root, rule.key, part)
    write_step(campaign.root, DECIDED_BY, {"key": rule.key, "rule": rule.name})


def _restore_full(campaign: AuditedCampaign) -> None:
    """The rule that runs last decides: a pruned recipe an earlier rule promoted from this campaign
    gives way to verification's promoted configuration again when this rule does not promote its own."""
    registry = read_json(campaign.family.path / "family.json")  # as it is now, after verify's write
    best = Ledger.read(campaign.family.path, registry).current(registry.get("best")) or {}
    source = best.get("source") or {}
    verified = read_audit(campaign.root).get("verify") or {}
    promoted = next(
        (c for c in verified.get("candidates", []) if c["config_id"] == verified.get("promoted")), None
    )
    if promoted and is_this_campaign(source, campaign) and source.get("step") != VERIFY_STEP:
        promote(campaign, promoted)


def _attach_distilled(
    campaign: AuditedCampaign, full: dict[str, Any], pruned: dict[str, Any], dropped: list[str], rule: Rule
) -> None:
    """A published pruned recipe is recorded beside the family best, which stays the promoted full
    configuration (the paper's docking case: the distilled recipe clears the gate, but the full one
    is the more accurate and reproducible). Decided on family.json as it is when written, under its
    lock, so a best another audit promoted meanwhile is never given this campaign's recipe."""
    distilled = {
        "config": pruned["config"],
        "metric": pruned["mu_r"],
        "std": pruned["sigma_r"],
        "n": pruned["n"],
        "split": pruned["split"],
        "by_split": pruned["by_split"],
        "rule": rule.name,
        "dropped": dropped,
    }

    def attach(registry: dict[str, Any], old: Ledger) -> tuple[Ledger, None]:
        best = old.current(registry.get("best")) or {}
        if is_this_campaign(best.get("source"), campaign) and best["config"] == full["config"]:
            return old.restated({**best, "distilled": distilled}), None
        return old, None  # the family best came from elsewhere; the distilled recipe stays in audit.json

    ledger.update(campaign.family.path, attach)
