"""The tails of the key-free comparison's audited bests on the sealed test split (issue 37, item 7).

The audit records each reseed's mean, median and worst start, not its 99th percentile. This flies
each reseed's saved policy (the campaign's audit/verify/<run>/out/policy.pt: kept on the machine
that ran the audit, not committed) from the 1024 sealed starts again, checks that the mean equals
the one the verification logged, and writes tails.json: per arm and repeat (and the hand recipe,
whose 10 reseeds on the test split are the sealed re-measurement's, results/sealed/rendezvous),
each reseed's mean, 99th percentile and largest terminal distance, and the same pooled over its
reseeds. With --retrain, a reseed whose policy is not here is trained again from its logged
configuration and seed (under runs/keyfree-tails/, two at a time), and the mean check allows a
relative 1e-4: the hand recipe's retrained reseeds reproduced their logged means within 4e-6
relative here, not bit for bit (the cause, likely the library builds of an earlier session, was
not traced). Each reseed's logged mean is kept beside the flown one. Without --retrain, an entry
whose policies are not on this machine keeps what an earlier tails.json holds for it (flown where
they were), so a run on a fresh checkout adds its new campaigns and loses none.

    python results/keyfree-search/tails.py [--retrain] [ROOT]   # ROOT: results/keyfree-search
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from autoresearch.campaign.audit_log import StepLog, TrialRow
from autoresearch.execution.runner import run_locally
from autoresearch.execution.spec import RunSpec
from autoresearch.family import Family
from autoresearch.splits import Split
from cwh_envs.datasets import evaluation_set
from cwh_envs.prepare import load_train

REPO = Path(__file__).resolve().parents[2]
FAMILY = REPO / "families" / "rendezvous"
# the hand recipe, re-measured on the test split
HAND = REPO / "results" / "sealed" / "rendezvous" / "6a38eb7f"
TIMEOUT = 3600.0  # s: a retrained reseed's hard limit (they took about 100 s)


def tails(distances: np.ndarray) -> dict:
    return {
        "mean": float(distances.mean()),
        "p99": float(np.percentile(distances, 99)),
        "max": float(distances.max()),
    }


def retrain(row: TrialRow, run: Path) -> None:
    """The logged reseed trained again into ``run`` by the runner the audit uses, on the test split.
    Keys its configuration predates (the algorithm axis) take the family's baseline values, which
    are the editable defaults it ran with."""
    family = Family.load(FAMILY)
    config = {**family.baseline_config, **row.config}
    result = run_locally(
        RunSpec(family, config, row.key, row.seed, run, run / "runs.jsonl", TIMEOUT, Split.TEST)
    )
    if not result.ok:
        raise SystemExit(f"{run}: the retrained reseed did not finish ({result.status}: {result.reason})")


def reseeds(log: Path, prefix: str, run_root: Path, train, test, retraining: bool) -> dict | None:
    """The ok rows of ``log`` whose key starts with ``prefix``, each run's policy flown again on the
    test split (its run directory ``run_root / key``, or retrained under runs/); None where the
    policies are not here and --retrain is not given."""
    rows = [r for r in StepLog(log).read() if r.key.startswith(prefix) and r.ok]
    runs = {r.key: run_root / r.key for r in rows}
    missing = [r for r in rows if not (runs[r.key] / "out" / "policy.pt").exists()]
    if missing and not retraining:
        print(
            f"{run_root}: {len(missing)} reseed policies not here (not committed): an earlier tails.json "
            "entry is kept; --retrain flies them again",
            file=sys.stderr,
        )
        return None
    scratch = REPO / "runs" / "keyfree-tails" / run_root.relative_to(REPO)
    runs |= {r.key: scratch / r.key for r in missing}
    todo = [r for r in missing if not (runs[r.key] / "out" / "policy.pt").exists()]
    with ThreadPoolExecutor(2) as pool:  # one training per core
        list(pool.map(lambda r: retrain(r, runs[r.key]), todo))
    per_seed, pooled = [], []
    for row in sorted(rows, key=lambda r: r.seed):
        policy, _ = train.load_policy(runs[row.key] / "out")
        distances = train.fly(policy, test.starts).terminal_distance
        logged, retrained = row.on(Split.TEST).metric, row in missing
        if not np.isclose(distances.mean(), logged, rtol=1e-4 if retrained else 1e-9, atol=0):
            raise SystemExit(
                f"{runs[row.key]}: flown mean {distances.mean()!r} differs from the logged {logged!r}"
            )
        per_seed.append({"seed": row.seed, "retrained": retrained, "logged_mean": logged, **tails(distances)})
        pooled.append(distances)
    return {"pooled": tails(np.concatenate(pooled)), "per_seed": per_seed}


def audited_best(campaign: Path, train, test, retraining: bool) -> dict | None:
    """The reseeds of the campaign's verified best; None before its verification finished."""
    audit = campaign / "audit.json"
    verify = json.loads(audit.read_text()).get("verify", {}) if audit.exists() else {}
    if verify.get("status") != "done" or not verify.get("candidates"):
        return None
    config_id = verify["candidates"][0]["config_id"]
    step = campaign / "audit" / "verify"
    found = reseeds(step / "verify.jsonl", f"verify-{config_id}-", step, train, test, retraining)
    return None if found is None else {"config_id": config_id, **found}


ARMS = ("random", "tpe", "tpe-hyperband", "tpe-hyperband-off")  # run.sh's arms, in its order


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--retrain", action="store_true", help="train again the reseeds not on this machine")
    parser.add_argument("root", nargs="?", type=Path, default=REPO / "results" / "keyfree-search")
    args = parser.parse_args()
    root = args.root.resolve()
    earlier = json.loads((root / "tails.json").read_text()) if (root / "tails.json").exists() else {}
    flown_before = {e["campaign"]: e for arm in ARMS for e in earlier.get(arm, [])}
    train = load_train(FAMILY)
    test = evaluation_set(train.TASK, train.N_TEST, problem=train.PROBLEM, split="test")
    out, lines = {}, []

    def line(label: str, repeat: str, found: dict) -> None:
        p, seeds_p99 = found["pooled"], [s["p99"] for s in found["per_seed"]]
        lines.append(
            f"| {label} | {repeat} | {p['mean']:.3f} | {p['p99']:.2f} | {p['max']:.2f} "
            f"| {min(seeds_p99):.2f}-{max(seeds_p99):.2f} |"
        )

    hand = reseeds(HAND / "trials.jsonl", f"sealed-{HAND.name}-", HAND, train, test, args.retrain)
    if hand is not None:
        out["hand_recipe"] = {"remeasured": HAND.relative_to(REPO).as_posix(), **hand}
    elif "hand_recipe" in earlier:
        out["hand_recipe"] = earlier["hand_recipe"]
    if "hand_recipe" in out:
        line("hand recipe", "-", out["hand_recipe"])
    for arm in ARMS:
        for campaign in sorted((root / arm).glob("repeat-*")):
            name = campaign.relative_to(REPO).as_posix()
            found = audited_best(campaign, train, test, args.retrain)
            if found is None and name in flown_before:
                found = {k: v for k, v in flown_before[name].items() if k != "campaign"}
            if found is not None:
                out.setdefault(arm, []).append({"campaign": name, **found})
                line(arm, campaign.name.removeprefix("repeat-"), found)
    (root / "tails.json").write_text(json.dumps(out, indent=2) + "\n")
    print("| audited best | repeat | mean | p99 | max | p99 per reseed |")
    print("|---|---:|---:|---:|---:|---|")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
