"""The random-search arm (paper Eqs. randsearch and verdict): an external sanity check.

The random proposer samples the same editable surface, starting from the same first
experiment (the baseline at the family's default seed), with the campaign's per-experiment
timeout and as many experiments as the campaign ran. The arm is an ordinary loop campaign
(autoresearch.loop.orchestrator with the random proposer, the audit's workers running its draws in
parallel), so it is written, resumed and read like any other. Random draws ignore the history:
the proposer's stream depends only on its seed and the iteration. Unlike a campaign, the arm does
not stop at the target, on a plateau or on failures: it is a best-of-N over all N draws.

The arm searches the space the campaign's key-free proposer searched (its ``--space``), else each
parameter's ``random_range`` (autoresearch.space.SPACES); ``space`` overrides either.
--matched-range narrows the training-budget axis to the range the campaign actually used (the
paper's open limitation: the agent trained longer than the random sweep happened to sample).

The arm is a search, so its runs are scored on the search split only and its directory, like a
loop campaign's, holds no sealed-split value. Where the verdict is on the sealed test split, the
two bests it compares (the campaign's single-seed best and the arm's) are each trained once more
at the default seed and scored on both splits, so both sides are selected on search and judged on
test alike; the re-run's search value is the recorded one, reproduced.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from autoresearch.audit import stats
from autoresearch.audit.inputs import AuditedCampaign, AuditError, config_id, gate_split
from autoresearch.audit.trials import Trial, run_trials
from autoresearch.campaign import Campaign, CampaignMeta, CampaignState, Record, Status, portable_path
from autoresearch.campaign.audit_log import read_audit, write_step
from autoresearch.execution.executors import Executor
from autoresearch.loop.live import PlainView
from autoresearch.loop.orchestrator import LoopSettings, Orchestrator
from autoresearch.loop.stopping import Budgets
from autoresearch.proposers.random_search import ARM_STREAM, RandomProposer
from autoresearch.space import NUMERIC_TYPES
from autoresearch.splits import Split
from autoresearch.verdicts import ranking

MATCHED_AXIS = "training_budget"
PROPOSER = "random"
DEFAULT_SPACE = "random-range"


def step_name(matched_range: bool) -> str:
    """The audit.json key: a matched-range arm is kept beside the plain one."""
    return "random_matched" if matched_range else "random"


def default_arm_dir(campaign: AuditedCampaign, matched_range: bool) -> Path:
    return campaign.root.parent / f"{campaign.root.name}-{step_name(matched_range).replace('_', '-')}"


def campaign_count(campaign: AuditedCampaign) -> int:
    """Experiments the campaign ran (successful or failed, the baseline included)."""
    return sum(r.status.started_a_run for r in campaign.records)


def matched_ranges(campaign: AuditedCampaign) -> dict[str, dict[str, Any]]:
    """random_range of each training-budget parameter: the span of values the campaign ran."""
    family, ranges = campaign.family, {}
    for name, param in family.space.params.items():
        if param.axis != MATCHED_AXIS:
            continue
        # a parameter declared since a run held its baseline value there (the family only grew)
        held = family.baseline_config[name]
        used = [r.config.get(name, held) for r in campaign.records if r.status.started_a_run]
        if param.type in NUMERIC_TYPES:
            ranges[name] = {"low": min(used), "high": max(used)}
        else:
            ranges[name] = {"choices": list({json.dumps(v): v for v in used}.values())}
    if not ranges:
        raise AuditError(
            f"--matched-range: family {family.name!r} has no parameter on the {MATCHED_AXIS!r} axis"
        )
    return ranges


def arm_space(campaign: AuditedCampaign, space: str | None) -> str:
    """``space``, else the one the campaign's proposer searched when it chose one, else random-range."""
    return space or campaign.meta.settings.get("space") or DEFAULT_SPACE


def searched_registry(registry: dict[str, Any], space: str, ranges: dict[str, Any] | None) -> dict[str, Any]:
    """A copy of ``registry`` whose random_ranges are exactly what the arm samples: none over the
    bounds, then the matched training-budget ranges on top."""
    registry = json.loads(json.dumps(registry))
    for spec in registry["search_space"].values():
        if space == "bounds":
            spec.pop("random_range", None)
    for name, sub_range in (ranges or {}).items():
        registry["search_space"][name]["random_range"] = sub_range
    return registry


def _summary_run(record: Record | None) -> dict[str, Any] | None:
    if record is None:
        return None
    return {k: getattr(record, k) for k in ("iteration", "run_id", "metric", "feasible", "config")}


def run_random_arm(
    campaign: AuditedCampaign,
    executor: Executor,
    *,
    count: int | None = None,
    matched_range: bool = False,
    seed: int = 0,
    out: Path | None = None,
    space: str | None = None,
    split: str | None = None,
) -> dict[str, Any]:
    """Run (or resume) the random arm of ``campaign``; write audit.json[random] and return it. The
    verdict is on ``split``: the split verification gated on, else the family's default."""
    family = campaign.family
    split = gate_split(family, split or (read_audit(campaign.root).get("verify") or {}).get("split"))
    count = count or campaign_count(campaign)
    if count < 1:
        raise AuditError(f"the random arm needs a count >= 1 (got {count})")
    space = arm_space(campaign, space)
    ranges = matched_ranges(campaign) if matched_range else None
    registry = searched_registry(family.registry, space, ranges)
    arm = Campaign((out or default_arm_dir(campaign, matched_range)).resolve())
    settings = {
        "timeout_per_run": campaign.timeout,
        "seed": seed,
        "count": count,
        "budget_from": portable_path(campaign.root),
        "matched_range": ranges,
        "space": space,
        # the campaign's time budget: each draw is granted what each of its runs was
        **(
            {
                "time_budget": campaign.time_budget,
                "eval_allowance": campaign.meta.settings.get("eval_allowance"),
            }
            if campaign.time_budget is not None
            else {}
        ),
    }
    if arm.exists():  # resuming: only the very same arm
        saved = arm.meta()
        saved_settings = {"space": DEFAULT_SPACE, **saved.settings}  # arms written before the choice existed
        if (saved.family_name, saved.proposer, saved_settings) != (family.name, PROPOSER, settings):
            raise AuditError(
                f"{arm.root} holds a random arm with other settings; choose another --out or remove it"
            )
        saved.resumed(family, saved_settings).write(arm.root)
    else:
        arm.root.mkdir(parents=True, exist_ok=True)
        CampaignMeta.new(family, PROPOSER, settings).write(arm.root)
    step = step_name(matched_range)
    earlier = campaign.rereading(step, arm.root / "proposals.jsonl", campaign.step_dir(step) / "judge.jsonl")
    # A best-of-N: every draw runs, whatever the target, the plateau or a run of failures says.
    budgets = Budgets(max_iters=count, max_failures=count + 1, plateau_window=count + 1)
    limits = {"timeout_per_run": campaign.timeout, "time_budget": campaign.time_budget}
    loop = LoopSettings(PROPOSER, budgets, workers=executor.workers, **limits)
    proposer = RandomProposer(registry, seed, space="random-range", stream=ARM_STREAM)
    view = PlainView(family.metric, spend=False)  # the random proposer spends nothing
    Orchestrator(family, proposer, arm.root, loop, view=view, executor=executor).run()
    state = arm.state(family)
    off = [(r.run_id, why) for r in state.records if r.ran and (why := family.off_split(r.final_metric))]
    if off:  # e.g. an arm resumed from draws scored on another build of a split
        raise AuditError(
            f"the random arm in {arm.root} holds {len(off)} draw(s) scored on data other than family "
            f"{family.name!r} pins ({off[0][0]}: {'; '.join(off[0][1])}); no verdict compares it with the "
            f"campaign: move it aside and run `autoresearch random --budget-from {campaign.root}` again"
        )
    part = summarize(campaign, arm.root, state, matched_range, ranges, seed, space)
    if split is Split.TEST:  # the paper's verdict stays beside the one on the sealed split
        part["search_verdict"] = {"verdict": part["verdict"], "units": part["units"]}
        part.update(judge_on_test(campaign, executor, state, matched_range))
    # a resumed arm that drew and judged nothing new keeps the provenance it was measured under
    part["provenance"] = earlier.kept("provenance", part["provenance"])
    write_step(campaign.root, step, part)
    return part


def judge_on_test(
    campaign: AuditedCampaign, executor: Executor, state: CampaignState, matched_range: bool
) -> dict[str, Any]:
    """Eq. verdict on the sealed test split: each side's search-selected best, trained again at the
    default seed and scored on both splits (one training each)."""
    family, sign = campaign.family, campaign.family.direction
    bests = {"agent": campaign.single_seed_best(), "random": state.best}
    sides = {side: best for side, best in bests.items() if best is not None}
    trials = [
        Trial(f"judge-{side}-{config_id(best.config)}", best.config, family.default_seed)
        for side, best in sides.items()
    ]
    root = campaign.step_dir(step_name(matched_range))
    rows = run_trials(
        family,
        trials,
        executor,
        root / "judge.jsonl",
        root,
        campaign.audit_timeout,
        label="judge",
        time_budget=campaign.time_budget,
    )
    judged: dict[str, Any] = {}
    for (side, best), row in zip(sides.items(), rows, strict=True):
        test, search = row.on(Split.TEST), row.on(Split.SEARCH)
        judged[side] = {
            "config_id": config_id(best.config),
            "run_id": row.run_id,
            "status": row.status,
            "test_metric": test and test.metric,
            "test_feasible": test and test.feasible,
            "search_metric": search and search.metric,
            "recorded_search_metric": best.metric,
            "reproduced": row.ok and search.metric == best.metric,
        }

    def value(side: str) -> float | None:
        side_part = judged.get(side) or {}
        return side_part.get("test_metric") if side_part.get("test_feasible") else None

    out: dict[str, Any] = {"split": Split.TEST.value, "judged": judged, "verdict": None, "units": None}
    sigma = (family.seed_noise or {}).get(Split.TEST.value, {}).get("std")
    if sigma:
        out["verdict"], out["units"] = stats.random_verdict(value("agent"), value("random"), sigma, sign)
    else:
        out["verdict_note"] = "no seed noise measured on the test split: run `autoresearch noise`"
    return out


def summarize(
    campaign: AuditedCampaign,
    arm_dir: Path,
    state: CampaignState,
    matched_range: bool,
    ranges: dict[str, Any] | None,
    seed: int,
    space: str = DEFAULT_SPACE,
) -> dict[str, Any]:
    """Eq. verdict in noise units on the search split, the strict-feasible fraction, and the arm's
    bests; written to audit.json by the caller."""
    family, sign = campaign.family, campaign.family.direction
    ran = [r for r in state.records if r.ran]
    best_any = min(ran, key=ranking(sign), default=None)  # feasible or not
    best = state.best
    agent = campaign.single_seed_best()
    part: dict[str, Any] = {
        "status": "done",
        "split": Split.SEARCH.value,
        "dir": portable_path(arm_dir),
        "count": sum(r.status.started_a_run for r in state.records),
        "seed": seed,
        "space": space,
        "matched_range": ranges if matched_range else None,
        "n_ran": len(ran),
        "n_failed": sum(r.status is Status.FAILED for r in state.records),
        "n_feasible": sum(bool(r.feasible) for r in ran),
        "feasibility_field": family.feasibility_field,
        "best": _summary_run(best),
        "best_any": _summary_run(best_any),
        "agent_best": agent and agent.metric,
        "verdict": None,
        "units": None,
        "provenance": campaign.provenance,
    }
    if family.sigma:
        part["verdict"], part["units"] = stats.random_verdict(
            part["agent_best"], best and best.metric, family.sigma, sign
        )
    else:
        part["verdict_note"] = "no measured seed noise: run `autoresearch noise` for the verdict"
    return part
