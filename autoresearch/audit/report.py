"""The audit report of a campaign: report.md and its figures, written into the campaign directory.

report.md reads on its own: the audit table in the shape of the paper's Tables 2 and 3, the mean
difference with its confidence interval, the verified candidates, the pruning decisions, and
the figures: the search (paper Fig. hero a: every experiment's metric and each arm's running
best), the recipe (Fig. hero b: how each parameter moved), and, when the family ships a
report.py plotting hook, its domain figure for the promoted configuration's saved policy.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from autoresearch.audit.figures import (
    COLORS,
    PlottedArm,
    family_hook,
    load_arm,
    random_arms,
    recipe_figure,
    search_figure,
)
from autoresearch.audit.inputs import AuditedCampaign, open_campaign
from autoresearch.audit.outcome import certified
from autoresearch.audit.prune import DECIDED_BY, RULES
from autoresearch.audit.prune import STEP as PRUNE_STEP
from autoresearch.audit.tails import OUTLIER_UNITS, PAPER, RUNAWAY
from autoresearch.campaign import portable_path
from autoresearch.campaign.audit_log import read_audit
from autoresearch.family import Family
from autoresearch.verdicts import CONFIRMED, REGRESSED, WITHIN_NOISE, best_feasible


def _fmt(x: float | None, digits: int = 4) -> str:
    return "n/a" if x is None else f"{x:.{digits}g}"


def _mean_sd(mean: float | None, sd: float | None, n: int | None) -> str:
    return f"{_fmt(mean)} ± {_fmt(sd, 2)} (n={n})"


def _best_of(arm_part: dict[str, Any]) -> str:
    best = arm_part["best"]
    if best:
        return _fmt(best["metric"])
    any_best = arm_part["best_any"]
    return f"{_fmt(any_best['metric'])} (none feasible)" if any_best else "no successful run"


def _sealed(audit: dict[str, Any]) -> bool:
    """Whether the audit scored its runs on a sealed test split (its table then has both columns)."""
    return bool((audit.get("verify") or {}).get("sealed_split"))


def _on(entry: dict[str, Any] | None, split: str) -> str:
    """An entry's reseeded mean ± sd on ``split`` (from its by_split), or —."""
    part = ((entry or {}).get("by_split") or {}).get(split)
    if not part or part.get("mu_r") is None:
        return "—"
    return f"{_fmt(part['mu_r'])} ± {_fmt(part['sigma_r'], 2)}"


def _both(entry: dict[str, Any], gated: str, split: str) -> list[str]:
    """The search and test cells of a reseeded entry: ``gated`` on the split that decided."""
    return [gated if on == split else _on(entry, on) for on in ("search", "test")]


def shown_noise(audit: dict[str, Any], family: Family) -> dict[str, Any] | None:
    """The seed noise the report shows (the table's reference row, the search figure's band, the verdict
    note), as the audit recorded it, never the family's as it is now (measured again since, it would
    change a committed report's numbers): the audit's noise step, else the noise verification gated
    against, which it recorded on its gated split only (mean, sd and k), marked ``gated_only``. The
    family's noise only before verification ran."""
    if audit.get("noise"):
        return audit["noise"]
    verify = audit.get("verify") or {}
    gated = verify.get("noise")
    if not gated:
        return family.seed_noise
    if verify.get("split", "search") == "test":
        return {"k": gated["k"], "test": dict(gated), "gated_only": "test"}
    return {**gated, "gated_only": "search"}


def noise_note(noise: dict[str, Any] | None) -> str | None:
    """A sentence when the reference row shows only what verification recorded (:func:`shown_noise`)."""
    split = (noise or {}).get("gated_only")
    if not split:
        return None
    missing = "its search-split part and feasible count were" if split == "test" else "its feasible count was"
    return (
        f"The seed-noise row is what verification recorded of the noise it gated against: its mean, sd and k on "
        f"the {split} split. {missing[0].upper() + missing[1:]} not recorded with this audit, and the family's "
        "noise as it is now may be a later measurement (`autoresearch audit` records the whole measurement)."
    )


def audit_table(campaign: AuditedCampaign, audit: dict[str, Any], other_arms: list[PlottedArm]) -> list[str]:
    """The paper's Tables 2 and 3: one row per arm, the reseeded headline last. With a sealed test
    split, a column per split: the search split (selected on) and the test split (gated on)."""
    family = campaign.family
    sealed = _sealed(audit)
    split = (audit.get("verify") or {}).get("split", "search")
    columns = f"{family.metric}, search split | {family.metric}, test split" if sealed else family.metric
    rows = [
        f"| Arm | {columns} | Strict-feasible | vs. seed noise |",
        "|---|---|" + "---|" * (3 if sealed else 2),
    ]

    def row(name: str, search: str, test: str, feasible: str, verdict: str) -> None:
        rows.append(
            f"| {name} | {search} | {test} | {feasible} | {verdict} |"
            if sealed
            else f"| {name} | {search} | {feasible} | {verdict} |"
        )

    noise = shown_noise(audit, family)
    if noise:
        feas = f"{noise['n_feasible']} of {noise['k']}" if "n_feasible" in noise else "n/a"
        test = noise.get("test")
        row(
            f"Seed noise (n={noise['k']})",
            f"{_fmt(noise['mean'])} ± {_fmt(noise['std'], 2)}" if "mean" in noise else "—",
            f"{_fmt(test['mean'])} ± {_fmt(test['std'], 2)}" if test else "—",
            feas,
            "reference",
        )
    for step, name in (("random", "Random search"), ("random_matched", "Matched-range random")):
        part = audit.get(step)
        if part:
            units = f", {part['units']:+.1f}σ" if part.get("units") is not None else ""
            on = " on test" if part.get("split") == "test" else ""
            judged = (part.get("judged") or {}).get("random") or {}
            missing = part["count"] - part["n_ran"]
            row(
                f"{name} (best of {part['count']} draws"
                + (f"; {missing} did not finish" if missing else "")
                + ")",
                _best_of(part),
                _fmt(judged.get("test_metric")),
                f"{part['n_feasible']} of {part['n_ran']}",
                f"not gated ({part['verdict'] or 'no verdict'}{on}{units})",
            )
    sign = family.direction
    for arm in other_arms:
        ran = arm.ran
        feasible = [r for r in ran if r.feasible]
        best = best_feasible(ran, sign)
        row(
            f"{arm.label} (best of {len(ran)})",
            _fmt(best and best.metric),
            "—",
            f"{len(feasible)} of {len(ran)}",
            "not gated",
        )
    single = campaign.single_seed_best()
    if single:
        judged = ((audit.get("random") or {}).get("judged") or {}).get("agent") or {}
        row(
            "Agent, single-seed best",
            _fmt(single.metric),
            _fmt(judged.get("test_metric")),
            "yes",
            "not gated",
        )
    verify = audit.get("verify") or {}
    shown = _shown(verify)
    if shown:
        verdict = "PASS" if shown["passed"] else "FAIL"
        gated = f"**{_fmt(shown['mu_r'])} ± {_fmt(shown['sigma_r'], 2)}**"
        row(
            f"Agent, reseeded (n={shown['n']})",
            *_both(shown, gated, split),
            f"{shown['n_feasible']} of {shown['n']}",
            f"**{shown['margin']:.1f}σ{f' on {split}' if sealed else ''}, {verdict}**",
        )
    for rule in RULES:  # the paper's rule first: the row of the paper's tables
        part = audit.get(rule.key) or {}
        pruned = part.get("pruned")
        if pruned and "mu_r" in pruned:
            verdict = (
                ("published, promoted" if part.get("promotes_pruned") else "published")
                if part["published"]
                else "not published"
            )
            which = "" if rule.key == "prune" else f" ({rule.name} rule)"
            gated = f"{_fmt(pruned['mu_r'])} ± {_fmt(pruned['sigma_r'], 2)}"
            row(
                f"Pruned recipe{which}, reseeded (n={pruned['n']})",
                *_both(pruned, gated, split),
                f"{pruned['n_feasible']} of {pruned['n']}",
                f"{pruned['margin']:.1f}σ, {verdict}",
            )
    return rows


def headline(campaign: AuditedCampaign, audit: dict[str, Any]) -> str:
    """The audit's outcome in one sentence: what it promoted (the configuration the figures and the
    exported policy show), certified on which split, by how many noise units."""
    verify = audit.get("verify") or {}
    if not verify:
        return "not audited yet (`autoresearch audit --campaign DIR`)"
    outcome = certified(audit)
    if outcome is None:
        return f"nothing promoted: {verify.get('reason')}"
    what = "the pruned recipe" if outcome["step"] == PRUNE_STEP else "candidate"
    text = (
        f"{what} {outcome['config_id']} ({_changes(outcome['config'], campaign.family)}) reseeded on the "
        f"{outcome['split']} split {_mean_sd(outcome['metric'], outcome['sigma_r'], outcome['n'])}, "
        f"m = {outcome['margin_sigma']:.1f}σ: {outcome['verdict']}"
    )
    search = outcome["by_split"].get("search") or {}
    if outcome["split"] == "test" and search.get("mu_r") is not None:
        text += f" (search split {_fmt(search['mu_r'])})"
    if not outcome["promoted"]:
        tried = next(c for c in verify["candidates"] if c["config_id"] == outcome["config_id"])
        return f"nothing promoted: {text} ({tried['reason']})"
    # where the promotion was written: the deciding prune rule's part, or verification's
    part = (
        audit.get((audit.get(DECIDED_BY) or {}).get("key", PRUNE_STEP))
        if outcome["step"] == PRUNE_STEP
        else verify
    )
    best = (part or {}).get("family_best")
    text += ", promoted"
    if isinstance(best, dict) and not best.get("updated", True):
        text += f"; the family's best is unchanged: {best.get('why')}"
    return text


def mismatch_note(campaign: AuditedCampaign, audit: dict[str, Any]) -> str | None:
    """A sentence when the single-seed best and the reseeded row are different configurations."""
    verify = audit.get("verify") or {}
    single, shown = verify.get("single_seed_best"), _shown(verify)
    if not single or not shown or single["config_id"] == shown["config_id"]:
        return None
    return (
        f"The single-seed best ({single['config_id']}, run {single['run_id']}) and the reseeded row "
        f"({shown['config_id']}) are different configurations: reseeding revised which one is best "
        '(docs/audit.md, "How to read the report").'
    )


def verdict_note(arms: list[PlottedArm], noise: dict[str, Any] | None) -> str | None:
    """A sentence when run verdicts were judged against other noise than the audit's: a verdict is a
    single-seed judgement in the noise unit of its day (its record names it), so one judged before
    the seed noise was measured can differ from a later verdict of the same configuration."""
    measured = (noise or {}).get("measured_at")
    if not measured:
        return None
    counts = []
    for arm in arms:
        judged = [r for r in arm.ran if r.verdict in (CONFIRMED, REGRESSED, WITHIN_NOISE)]
        older = sum((r.verdict_noise or {}).get("measured_at") != measured for r in judged)
        if older:
            counts.append(f"{older} of {len(judged)} in {arm.label}")
    if not counts:
        return None
    return (
        f"Run verdicts judged before the seed noise this audit used was measured ({measured}), against 5% "
        f"of the best or an older measurement: {'; '.join(counts)}. Each record names the noise its verdict "
        "was judged against (`verdict_noise`); the same configuration judged against this noise may get "
        'another verdict (docs/audit.md, "How to read the report").'
    )


def _feasibility(family: Family) -> str:
    field, limits = family.feasibility_field, family.limits
    within = " and ".join(f"`{name}` <= {limit:g}" for name, limit in limits.items())
    if field is None and not limits:
        return "every run counts as feasible (the family declares no feasibility field)"
    if field is None:
        return f"a run counts as feasible only when it reports {within} (the protocol's limits)"
    return f"a run counts as feasible only when its `{field}` is true" + (
        f" and it reports {within} (the protocol's limits)" if limits else ""
    )


def split_note(audit: dict[str, Any]) -> str:
    """Which split decided, in a sentence."""
    verify = audit.get("verify") or {}
    split = verify.get("split", "search")
    if not verify.get("sealed_split"):
        return (
            "No sealed split: this audit's runs were scored on the search split only (the family declared no "
            "test split when they ran), so the gate, the pruning and the promoted best use the search split "
            "the campaign selected on (the paper's protocol)."
        )
    if split == "test" and verify.get("picked_on") is None and len(verify.get("candidates", [])) > 1:
        return (  # an audit.json from before the search split chose (its prune part says what decided it)
            "**The test split decided**: every reseed was also scored on the family's sealed test split, which "
            "no proposer ever saw; the gate and the promotion among the candidates used it, against the seed "
            "noise measured on it, so the promoted recipe's test-split mean is the best of several. The search "
            "split, which the campaign selected on, is shown beside it: the difference is the selection gap."
        )
    if split == "test":
        return (
            "**The search split chose, the sealed test split gated**: every reseed was also scored on the "
            "family's sealed test split, which no proposer ever saw. The gate and the pruned recipe's "
            "re-verification run on it, against the seed noise measured on it, and can refuse a recipe; which "
            "candidate is promoted and which edits are pruned are decided on the search split, so the test "
            "split measures that choice instead of making it. The difference between the two is the selection gap."
        )
    return (
        "**The search split decided** (`--gate-split search`, the paper's protocol), although the family has "
        "a sealed test split: the test-split column shows what the gate would have seen there."
    )


def _promoted(verify: dict[str, Any]) -> dict[str, Any] | None:
    return next((c for c in verify.get("candidates", []) if c["config_id"] == verify.get("promoted")), None)


def _shown(verify: dict[str, Any]) -> dict[str, Any] | None:
    """The candidate the table's reseeded row shows: the promoted one, else the first reseeded."""
    return _promoted(verify) or next((c for c in verify.get("candidates", []) if "mu_r" in c), None)


def _value(value: Any) -> str:
    """A parameter's value as a reader wants it: floats to 4 significant digits (the full value is in
    the records), strings quoted as the editable block writes them."""
    if isinstance(value, float):
        return repr(float(f"{value:.4g}"))  # 0.0019101141930370157 -> 0.00191; 1.0 stays 1.0
    return repr(value)


def _changes(config: dict[str, Any], family: Family) -> str:
    """The edits of ``config`` from the family's baseline, among the parameters it records (one recorded
    before the family declared a parameter has none of it: that parameter is not an edit)."""
    baseline = family.baseline_config
    return (
        ", ".join(
            f"{k}={_value(config[k])}" for k in family.space.names if k in config and config[k] != baseline[k]
        )
        or "(baseline)"
    )


def _excluded(c: dict[str, Any]) -> str:
    """The reseeds left out of a candidate's mean, said in words ("none" when none was)."""
    parts = []
    if c["n_failed"]:
        parts.append(f"{c['n_failed']} failed to run")
    if c["n_parity_excluded"]:  # verify.py: trained far worse than the run it repeats (parity guard)
        parts.append(f"{c['n_parity_excluded']} trained to over 2x the original run's loss")
    return ", ".join(parts) or "none"


def verify_section(
    campaign: AuditedCampaign, verify: dict[str, Any], final: dict[str, Any] | None = None
) -> list[str]:
    """The reseeded verification. ``final``: what the whole audit promoted (:func:`certified`), which
    pruning may have made the verified candidate's pruned recipe: the section then says so, so that
    the report names one promoted recipe."""
    family = campaign.family
    if not verify:
        return ["Not run (`autoresearch verify --campaign DIR`)."]
    if "reason" not in verify:  # stopped mid-step: its rows are partial, as prune's are
        return ["Not finished: run `autoresearch verify --campaign DIR` again to resume."]
    split = verify.get("split", "search")
    sealed = verify.get("sealed_split", False)
    lines = [f"Fresh seeds {verify.get('seeds')}; {verify['reason']}.", ""]
    reseeded = "Reseeded, search split | Reseeded, test split" if sealed else "Reseeded mean ± sd"
    lines += [
        f"| Config | Edits | Single-seed (search) | {reseeded} | m ({split}) | Feasible | Reseeds left out | Result |",
        "|---|---|---|---|---|---|---|---|" + ("---|" if sealed else ""),
    ]
    for c in verify["candidates"]:
        blank = "| — | — |" if sealed else "| — |"
        if "mu_r" not in c:
            lines.append(
                f"| {c['config_id']} | {_changes(c['config'], family)} | {_fmt(c['source']['metric'])} "
                f"{blank} — | — | — | {c.get('reason', 'not run')} |"
            )
            continue
        excluded = _excluded(c)
        mark = " (verified)" if c["config_id"] == verify["promoted"] else ""
        gated = _mean_sd(c["mu_r"], c["sigma_r"], c["n"])
        cells = " | ".join(_both(c, gated, split)) if sealed else gated
        lines.append(
            f"| {c['config_id']}{mark} | {_changes(c['config'], family)} | {_fmt(c['source']['metric'])} "
            f"| {cells} | {c['margin']:.2f} | {c['n_feasible']} of {c['n']} | {excluded} | {c['reason']} |"
        )
    lines += tails_lines(verify)
    promoted = _promoted(verify)
    single = verify.get("single_seed_best")
    lines.append("")
    if promoted:
        lines.append(
            f"Verified: **{promoted['config_id']}**, the passing candidate with the best pessimistic end of the "
            f"95% confidence interval of its reseeded mean on the {split} split (the most reproducible)."
        )
        if final and final.get("promoted") and final["config_id"] != promoted["config_id"]:
            lines.append(
                f"Pruning then promoted its pruned recipe **{final['config_id']}** in its place (below, and the "
                "headline): fewer edits, as reproducible."
            )
        elif final and final.get("promoted"):
            lines.append("It is the promoted recipe (the headline).")
        by_split = promoted.get("by_split") or {}
        if (
            sealed
            and by_split.get("search", {}).get("mu_r")
            and by_split.get("test", {}).get("mu_r") is not None
        ):
            search, test = by_split["search"]["mu_r"], by_split["test"]["mu_r"]
            lines.append(
                f"Selection gap of the promoted recipe: {_fmt(test)} on the test split against {_fmt(search)} on "
                f"the search split it was selected on ({100 * (test - search) / abs(search):+.0f} %)."
            )
        if single and single["config_id"] != promoted["config_id"]:
            lines.append(
                f"It is not the single-seed best ({single['config_id']}, {_fmt(single['metric'])} at run "
                f"{single['run_id']}): reseeding revised which configuration is best."
            )
        if "diff" in promoted:
            noise = verify["noise"]
            lines.append(
                f"\nMean difference to the seed-noise baseline on the {split} split (oriented, positive = better): "
                f"**{_fmt(promoted['diff'])}** (95% Welch CI [{_fmt(promoted['ci_low'])}, {_fmt(promoted['ci_high'])}]), "
                f"m = {promoted['margin']:.1f} units of σ = {_fmt(noise['std'], 3)} measured over K = {noise['k']} seeds."
            )
    else:
        lines.append("No candidate passed the gate: nothing was promoted and the family best is unchanged.")
    return lines


def tails_lines(verify: dict[str, Any]) -> list[str]:
    """What each candidate's reseeded mean hides (autoresearch.audit.tails): the spread over its seeds,
    a seed far outside the rest, its worst start and the reseeds with a runaway start. Nothing for an
    audit made before they were kept."""
    shown = [c for c in verify["candidates"] if (c.get("tails") or {}).get("spread")]
    if not shown:
        return []
    gate = verify.get("gate", PAPER)
    rule = (
        "the runaway gate: a reseed with a start beyond the family's runaway bound fails the candidate"
        if gate == RUNAWAY
        else "the paper's gate: runaways reported, not gated"
    )
    lines = [
        "",
        f"Per-seed spread and worst starts on the {verify.get('split', 'search')} split ({rule}; a seed is far "
        f"outside the rest when worse than the others' median by more than {OUTLIER_UNITS:g} robust sd):",
        "",
        "| Config | min / median / max | Worst start (seed) | Reseeds with a runaway start | Far outside the rest |",
        "|---|---|---|---|---|",
    ]
    for c in shown:
        t = c["tails"]
        spread = " / ".join(_fmt(t["spread"][k]) for k in ("min", "median", "max"))
        worst = t.get("worst")
        worst_text = f"{_fmt(worst['value'])} (s{worst['seed']})" if worst else "—"
        runaways = t.get("runaways")
        if runaways is None:
            runaway_text = "— (no runaway field declared)"
        else:
            runaway_text = ", ".join(f"s{r['seed']}: {r['runaway_share']:.3g}" for r in runaways) or "none"
        far = ", ".join(f"s{o['seed']}: {_fmt(o['metric'])}" for o in t["outliers"]) or "none"
        lines.append(f"| {c['config_id']} | {spread} | {worst_text} | {runaway_text} | {far} |")
    return lines


def _decision(d: dict[str, Any]) -> str:
    """A pruning decision in words: prune.py's "drop-dagger" (a mark, read as the DAgger algorithm
    beside the DAGGER_* parameters) is a drop that reverting showed to hurt: "drop, flagged"."""
    return "drop, flagged" if d["decision"] == "drop-dagger" else d["decision"]


def _unit_text(prune: dict[str, Any]) -> str:
    unit = prune.get("unit") or {"at": "baseline", "sigma": prune["noise"]["std"]}
    where = (
        "the candidate's own reseed spread σ_R" if unit["at"] == "candidate" else "the baseline's seed noise"
    )
    return f"σ = {_fmt(unit['sigma'], 3)}, {where}"


def prune_section(campaign: AuditedCampaign, prune: dict[str, Any]) -> list[str]:
    if not prune:
        return ["Not run (`autoresearch prune --campaign DIR`)."]
    if prune.get("status") == "skipped":
        return [prune["reason"] + "."]
    if prune.get("status") != "done":
        flags = (" --paired" if prune.get("paired") else "") + (
            " --noise-at candidate" if (prune.get("unit") or {}).get("at") == "candidate" else ""
        )
        return [f"Not finished: run `autoresearch prune --campaign DIR{flags}` again to resume."]
    if prune.get("paired"):
        how = (
            "at its own probe seeds, each paired with the full configuration at the same seed "
            f"(seeds {prune['probe_seeds']}); Δ is the mean paired difference"
        )
    else:
        how = f"at the shared probe seeds {prune['probe_seeds']}; Δ is measured against μ_R"
    lines = [
        f"Each edit of {prune['promoted']} reverted alone {how}, on the {prune.get('decided_on', prune.get('split', 'search'))} split, "
        f"in units of {_unit_text(prune)} (negative = reverting hurts):",
        "",
        "| Parameter | Axis | Default → value | Δ1/σ | Δ2/σ | Decision | Note |",
        "|---|---|---|---|---|---|---|",
    ]
    for d in prune["decisions"]:
        d1 = f"{d['delta1_sigma']:+.2f}" if "delta1_sigma" in d else "—"
        d2 = f"{d['delta2_sigma']:+.2f}" if "delta2_sigma" in d else "—"
        label = _decision(d)
        lines.append(
            f"| {d['param']} | {d['axis']} | {_value(d['default'])} → {_value(d['value'])} | {d1} | {d2} | {label} "
            f"| {d['note'] or ''} |"
        )
    lines += [
        "",
        f"Load-bearing: {', '.join(prune['kept']) or 'none'}. Dropped: {', '.join(prune['dropped']) or 'none'}.",
    ]
    if prune["flagged"]:
        lines.append(
            f"Flagged (reverting the edit alone made the recipe better: the edit moved the metric the wrong "
            f"way): {', '.join(prune['flagged'])}."
        )
    pruned = prune.get("pruned")
    if pruned and "mu_r" in pruned:
        lines.append(
            f"Pruned recipe re-verified at seeds {prune['reverify_seeds']}: "
            f"{_mean_sd(pruned['mu_r'], pruned['sigma_r'], pruned['n'])}, m = {pruned['margin']:.2f}."
        )
    lines.append(f"**{prune['reason'][0].upper() + prune['reason'][1:]}.**")
    return lines


def pruning_sections(campaign: AuditedCampaign, audit: dict[str, Any]) -> list[str]:
    """One section per leave-one-out rule that ran; with more than one, which decided and a
    side-by-side table of their decisions."""
    ran = [rule for rule in RULES if audit.get(rule.key)]
    if len(ran) <= 1:
        return prune_section(campaign, audit.get(ran[0].key) if ran else {})
    decided = (audit.get(DECIDED_BY) or {}).get("key", "prune")
    name = next((r.name for r in ran if r.key == decided), "paper")
    lines = [
        f"{len(ran)} leave-one-out rules ran (docs/audit.md compares them); the **{name}** rule, run last, decided "
        "(the family's distilled recipe, if any, is its). Each edit's decision and its final Δ/σ:",
        "",
        "| Parameter | " + " | ".join(r.name for r in ran) + " |",
        "|---|" + "---|" * len(ran),
    ]
    decisions = {r.key: {d["param"]: d for d in audit[r.key].get("decisions", [])} for r in ran}
    for param in decisions[ran[0].key] or next(iter(decisions.values())):
        cells = []
        for r in ran:
            d = decisions[r.key].get(param)
            if d is None:
                cells.append("—")
                continue
            delta = d.get("delta2_sigma", d.get("delta1_sigma"))
            label = _decision(d)
            cells.append(label + (f" ({delta:+.2f})" if delta is not None else ""))
        lines.append(f"| {param} | " + " | ".join(cells) + " |")
    for r in ran:
        lines += ["", f"### The {r.name} rule" + (" (decided)" if r.key == decided else ""), ""]
        lines += prune_section(campaign, audit[r.key])
    return lines


def write_report(campaign_dir: Path, arms: list[Path] = (), out_dir: Path | None = None) -> Path:
    """Write report.md, search.png, recipe.png (and trajectories.png) and return report.md's path."""
    campaign = open_campaign(campaign_dir, read_only=True)
    family = campaign.family
    audit = read_audit(campaign.root)
    out_dir = Path(out_dir or campaign.root)
    out_dir.mkdir(parents=True, exist_ok=True)
    agent = PlottedArm(f"agent ({campaign.meta.proposer})", COLORS["agent"], campaign.records)
    extra = [load_arm(Path(d), None, COLORS["other"]) for d in arms]
    noise = shown_noise(audit, family)
    search_figure([agent, *random_arms(audit), *extra], family, noise, out_dir / "search.png")
    recipe_figure(campaign.records, family, out_dir / "recipe.png", campaign.store.registry())
    hook_note = family_hook(campaign, audit, out_dir / "trajectories.png")
    exported = None
    if (family.path / "export.py").is_file():  # the optional export hook: the audited policy as a file
        exported = family_hook(campaign, audit, out_dir / "policy.onnx", hook="export.py")
    better = "lower" if family.direction < 0 else "higher"
    n_runs = sum(r.status.started_a_run for r in campaign.records)
    lines = [
        f"# Audit report: {campaign.root.name}",
        "",
        f"Family **{family.name}** ({portable_path(family.path)}); metric `{family.metric}` ({better} is better); "
        f"{'no target' if family.target is None else f'target {family.target:g}'}; {_feasibility(family)}. "
        f"Campaign proposer: {campaign.meta.proposer}, {n_runs} experiments. "
        "How to read this report: docs/audit.md.",
        "",
        f"**Headline**: {headline(campaign, audit)}.",
        "",
        "## Audit table",
        "",
        *audit_table(campaign, audit, extra),
        "",
        "The reseeded mean is the headline number; the single-seed best is shown for traceability. "
        'The gate (docs/audit.md, "Reseeded verification"): a configuration passes when its reseeded mean '
        "beats the baseline's by m = σ_dir(μ_R − μ_0)/σ ≥ 2 units of the seed noise σ and it is feasible on "
        "every reseed. A pruned recipe is *published* when its own re-verification passes the same gate and "
        "it keeps any target the full recipe reached, and *promoted* in the full recipe's place when it is "
        'also the more reproducible of the two (docs/audit.md, "Leave-one-out pruning").',
        *(["", note] if (note := noise_note(noise)) else []),
        *(["", note] if (note := mismatch_note(campaign, audit)) else []),
        *(["", note] if (note := verdict_note([agent, *random_arms(audit)], noise)) else []),
        "",
        split_note(audit),
        "",
        "## Reseeded verification",
        "",
        *verify_section(
            campaign, audit.get("verify") or {}, certified(audit) if audit.get("verify") else None
        ),
        "",
        "## Leave-one-out pruning",
        "",
        *pruning_sections(campaign, audit),
        "",
        "## Figures",
        "",
        "![search](search.png)",
        "",
        "Every experiment of each arm on the search split, one seed each (filled: feasible, hollow: "
        "infeasible; x on the top edge: a run that failed or timed out), and each arm's running best; "
        "the gray band is the baseline's mean ± σ.",
        "",
        "![recipe](recipe.png)",
        "",
        "How each parameter the campaign searched moved over its experiments: every run's value (dots) and "
        "the value of the best run so far (line). Parameters the protocol held at the baseline are left out.",
        "",
    ]
    if hook_note is None:
        lines += [
            "![trajectories](trajectories.png)",
            "",
            "The family's own figure for the promoted policy: its first search-split starts flown beside the "
            "optimal-control expert's trajectories.",
        ]
    else:
        lines.append(f"No family figure: {hook_note}.")
    if (family.path / "export.py").is_file():
        lines += [
            "",
            "The promoted policy, exported by the family's export.py: [policy.onnx](policy.onnx) "
            "(fly it with `examples/fly_onnx.py`)."
            if exported is None
            else f"No exported policy: {exported}.",
        ]
    (out_dir / "report.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return out_dir / "report.md"
