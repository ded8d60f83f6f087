"""Audit test family: a loss whose every edit has a designed effect in units of the seed noise.

The seed noise is +S at even seeds and -S at odd seeds (S = 0.01), so any even run of consecutive
seeds averages to exactly zero: with K = 4 noise seeds the measured sigma is S * sqrt(4/3), the
reseeded means equal the noise-free loss, and the two leave-one-out probe seeds (odd, then even)
give Delta1 = -h + S and Delta2 = -h for an edit whose reversion raises the loss by h. The
effects below are chosen so each edit lands in one case of the paper's Eq. loodecision:

EPOCHS >= 50   saves 0.5        keep at one seed (clearly load-bearing)
SAFE           the feasibility  keep: reverting it makes the run infeasible
HITCH          nothing          drop (a hitchhiker)
BORDER         saves 0.75 sigma keep-borderline
DAGGER         costs 2 sigma    drop-dagger (moved the wrong way)
GAP            saves 1.5 sigma  keep, seen only at two seeds (the equation's gap)
JOINT_A/B      save 0.3 only together: each alone is inert, both reverted regress
WIDE           erratic: the noise is ten times larger and of the opposite sign
AUDIT_THROTTLE_SEED (environment): that seed reports a tripled best_train_loss (parity guard).
AUDIT_SLEEP_S (environment): every run sleeps this long first (an audit made slow on purpose).
AUDIT_TEST_SHIFT (environment), e.g. 'WIDE=true:-0.5' or 'GAP=1.0,WIDE=false:0.6': a run whose
config has every NAME=VALUE listed (VALUE read as JSON) scores DELTA more on the sealed split only
(a test split that ranks recipes differently from the search split).
AUDIT_SPLIT_IDS (environment), e.g. '{"search": "a", "test": "b"}': the record's split_ids, the
data it says it was scored on (autoresearch.splits; none when unset).

--eval-split test (a copy whose family.json sets test_split): the sealed split's loss is the search
loss plus TEST_OFFSET, so every designed effect holds on it unchanged, and a value of at least
1000 anywhere a proposer looks is a test-split value that leaked.
"""

# ===== Editable Configuration (the agent may change these values only) =====
EPOCHS = 10  # training budget
SAFE = False  # run-time safety filter
HITCH = "a"  # an inert choice
BORDER = 0.0  # a borderline-useful knob
DAGGER = 0  # a knob that only hurts
GAP = 0.0  # a knob visible only at two seeds
JOINT_A = False  # useful only together with JOINT_B
JOINT_B = False  # useful only together with JOINT_A
WIDE = False  # erratic across seeds
# ===== Fixed Configuration (immutable below this line) =====

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from filelock import FileLock  # noqa: E402

CONFIG = {
    "EPOCHS": EPOCHS,
    "SAFE": SAFE,
    "HITCH": HITCH,
    "BORDER": BORDER,
    "DAGGER": DAGGER,
    "GAP": GAP,
    "JOINT_A": JOINT_A,
    "JOINT_B": JOINT_B,
    "WIDE": WIDE,
}
S = 0.01
SIGMA4 = S * math.sqrt(4 / 3)  # the sample sd of four alternating +-S values
TEST_OFFSET = 1000.0


def train(config: dict, seed: int) -> dict:
    loss = (
        1.0
        + (0.0 if config["EPOCHS"] >= 50 else 0.5)
        - 0.75 * SIGMA4 * config["BORDER"]
        + 2.0 * SIGMA4 * config["DAGGER"]
        - 1.5 * SIGMA4 * config["GAP"]
        + (0.0 if config["JOINT_A"] or config["JOINT_B"] else 0.3)
    )
    noise = S if seed % 2 == 0 else -S
    if config["WIDE"]:
        noise *= -10
    throttled = os.environ.get("AUDIT_THROTTLE_SEED") == str(seed)
    return {
        "loss": loss + noise,
        "feasible": bool(config["SAFE"]),
        "best_train_loss": loss * (3 if throttled else 1),
    }


def test_shift(config: dict, spec: str) -> float:
    """AUDIT_TEST_SHIFT's DELTA when ``config`` matches every NAME=VALUE of ``spec``, else 0."""
    if not spec:
        return 0.0
    conditions, delta = spec.rsplit(":", 1)
    pairs = (item.split("=", 1) for item in conditions.split(","))
    return float(delta) if all(config[name] == json.loads(value) for name, value in pairs) else 0.0


def main() -> int:
    here = Path(__file__).resolve().parent
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--run-id", default="manual")
    parser.add_argument("--runs-log", default=str(here / "runs.jsonl"))
    parser.add_argument("--out", default="out")
    parser.add_argument("--eval-split", choices=("search", "test"), default="search")
    args = parser.parse_args()
    time.sleep(float(os.environ.get("AUDIT_SLEEP_S", "0")))
    scores = train(CONFIG, args.seed)
    splits = {"search": {"loss": scores["loss"], "feasible": scores["feasible"]}}
    if args.eval_split == "test":
        test_loss = scores["loss"] + TEST_OFFSET + test_shift(CONFIG, os.environ.get("AUDIT_TEST_SHIFT", ""))
        splits["test"] = {"loss": test_loss, "feasible": scores["feasible"]}
    record = {
        "run_id": args.run_id,
        **scores,
        **splits[args.eval_split],
        "splits": splits,
        "eval_split": args.eval_split,
        "seed": args.seed,
        "config": CONFIG,
    }
    if os.environ.get("AUDIT_SPLIT_IDS"):
        record["split_ids"] = json.loads(os.environ["AUDIT_SPLIT_IDS"])
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "policy.json").write_text(json.dumps(CONFIG))
    line = json.dumps(record)
    print(f"FINAL_METRIC: {line}", flush=True)
    with FileLock(f"{args.runs_log}.lock"), open(args.runs_log, "a", encoding="utf-8") as log:
        log.write(line + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
