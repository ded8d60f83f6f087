"""summary.json of the key-free search comparison (results/keyfree-search/run.sh, issue 37 item 7).

    python results/keyfree-search/summarize.py [ROOT]   # ROOT: results/keyfree-search

Per arm and repeat: the campaign directory, its audited best (the configuration verify promoted, else
its one reseeded candidate) with its config and its test_metric (the reseeded mean on the sealed test
split), the search split's beside it and the gate's verdict. Then the issue's target, the hand recipe's
certified test metric plus 15 %, met or not by each repeat of the new arm, and the difference of the
mean test metric of the new arm and of random search with a 95 % bootstrap interval (separable when
the interval excludes 0); the same for each later variant of the new arm (``later_arms``). Writes ROOT/summary.json and prints a Markdown table.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from scipy import stats

from autoresearch.campaign.audit_log import read_audit
from autoresearch.campaign.group import repeat_dirs
from autoresearch.family import Family

REPO = Path(__file__).resolve().parents[2]
ARMS = ("random", "tpe", "tpe-hyperband", "tpe-hyperband-off")
NEW_ARM, REFERENCE_ARM = "tpe-hyperband", "random"
# A later session's variant of the new arm (--off-at-zero, the paced schedule), judged the same way
LATER_ARMS = ("tpe-hyperband-off",)
HAND = "results/rendezvous/hand"  # the hand recipe's campaign: its promotion is the reference
WITHIN = 0.15  # the target: the new arm's audited best at most 15 % above the hand recipe


def audited_best(campaign: Path) -> dict:
    """The campaign's audited best: the promoted candidate, else the reseeded one (None: not audited)."""
    verify = read_audit(campaign).get("verify") or {}
    # no machine's path in summary.json: repo-relative where it can be (a ROOT outside keeps its own)
    name = (
        campaign.resolve().relative_to(REPO).as_posix()
        if campaign.resolve().is_relative_to(REPO)
        else campaign.as_posix()
    )
    candidates = [c for c in verify.get("candidates", []) if "mu_r" in c]
    if not candidates:
        return {"campaign": name, "config": None, "test_metric": None, "audited": False}
    best = next((c for c in candidates if c["config_id"] == verify.get("promoted")), candidates[0])
    by_split = best.get("by_split") or {}
    return {
        "campaign": name,
        "config": best["config"],
        "test_metric": (by_split.get("test") or {}).get("mu_r"),
        "test_sd": (by_split.get("test") or {}).get("sigma_r"),
        "search_metric": (by_split.get("search") or {}).get("mu_r"),
        "n": best["n"],
        "passed": best["passed"],
        "gate": verify.get("gate", "paper"),
        "reason": best["reason"],
        "runaway_reseeds": [r["seed"] for r in (best.get("tails") or {}).get("runaways", [])],
    }


def hand_recipe() -> dict:
    family = Family.load(REPO / "families" / "rendezvous")
    entry = next(p for p in family.ledger.promotions if p["source"]["campaign"] == HAND)
    return {"campaign": HAND, "config": entry["config"], "test_metric": entry["by_split"]["test"]["mu_r"]}


def difference_interval(new: list[float], reference: list[float]) -> list[float] | None:
    """95 % bootstrap interval of mean(new) - mean(reference), resampling each arm's repeats."""
    if len(new) < 2 or len(reference) < 2:
        return None
    result = stats.bootstrap(
        (np.array(new), np.array(reference)),
        lambda x, y, axis: np.mean(x, axis=axis) - np.mean(y, axis=axis),
        n_resamples=10000,
        method="percentile",
        random_state=0,
    )
    return [float(result.confidence_interval.low), float(result.confidence_interval.high)]


def within(values: list[float], target: float) -> str:
    return f"{sum(v <= target for v in values)} of {len(values)}"


def against(new: list[float], reference: list[float]) -> dict:
    """mean(new) - mean(reference) with its bootstrap interval; separable when it excludes 0."""
    interval = difference_interval(new, reference)
    return {
        "mean_difference": float(np.mean(new) - np.mean(reference)) if new and reference else None,
        "bootstrap_95": interval,
        "separable": bool(interval is not None and (interval[1] < 0 or interval[0] > 0)),
    }


def main() -> int:
    root = Path(sys.argv[1] if len(sys.argv) > 1 else REPO / "results" / "keyfree-search")
    hand = hand_recipe()
    target = hand["test_metric"] * (1 + WITHIN)
    arms = {arm: [audited_best(d) for d in repeat_dirs(root / arm)] for arm in ARMS if (root / arm).is_dir()}
    values = {
        arm: [r["test_metric"] for r in rows if r["test_metric"] is not None] for arm, rows in arms.items()
    }
    summary = {
        "command": "bash results/keyfree-search/run.sh",
        "hand_recipe": hand,
        "target": {"test_metric_at_most": target, "within": WITHIN},
        "arms": arms,
        "new_arm": NEW_ARM,
        "new_arm_within_target": within(values[NEW_ARM], target),
        "not_audited": {arm: len(rows) - len(values[arm]) for arm, rows in arms.items()},
        "new_arm_minus_random": against(values[NEW_ARM], values[REFERENCE_ARM]),
        "later_arms": {
            arm: {
                "within_target": within(values[arm], target),
                "minus_random": against(values[arm], values[REFERENCE_ARM]),
            }
            for arm in LATER_ARMS
            if arm in values
        },
    }
    (root / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    print(f"hand recipe: {hand['test_metric']:.4g} m on the test split; target <= {target:.4g} m\n")
    print("| arm | repeat | campaign | audited best, test split | search split | verdict |")
    print("|---|---|---|---|---|---|")
    for arm, rows in arms.items():
        for i, row in enumerate(rows):
            test = (
                "not audited"
                if row["test_metric"] is None
                else f"{row['test_metric']:.4g} ± {row['test_sd']:.2g}"
            )
            search = "" if row.get("search_metric") is None else f"{row['search_metric']:.4g}"
            print(f"| {arm} | {i} | {row['campaign']} | {test} | {search} | {row.get('reason', '')} |")
    diff = summary["new_arm_minus_random"]
    print(
        f"\n{NEW_ARM} within the target in {summary['new_arm_within_target']} audited repeats "
        f"(not audited yet: {summary['not_audited']}); mean difference to random "
        f"{diff['mean_difference']}, 95 % bootstrap {diff['bootstrap_95']}, separable: {diff['separable']}"
    )
    for arm, later in summary["later_arms"].items():
        diff = later["minus_random"]
        print(
            f"{arm} within the target in {later['within_target']} audited repeats; mean difference to "
            f"random {diff['mean_difference']}, 95 % bootstrap {diff['bootstrap_95']}, separable: {diff['separable']}"
        )
    print(f"written: {root / 'summary.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
