"""Toy family: a noisy quadratic bowl standing in for a training run (pure Python, milliseconds).

It follows docs/family-contract.md exactly and is the `minimal` template of `autoresearch init`:
keep the two banners, the command line, the single FINAL_METRIC line and the locked append to
--runs-log; replace the body of train() with real training. This repository's tests run on it.
"""

# ===== Editable Configuration (the agent may change these values only) =====
EPOCHS = 10  # passes over the data; 0 is refused (the failure mode of this toy)
LEARNING_RATE = 0.01  # step size of the optimizer (log scale)
MOMENTUM = 0.5  # heavy-ball momentum, in [0, 1)
BATCH_SIZE = 64  # examples per step
ACTIVATION = "tanh"  # hidden nonlinearity
USE_NORM = False  # layer normalisation on or off
DROPOUT = 0.0  # dropout probability
# ===== Fixed Configuration (immutable below this line) =====

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import os  # noqa: E402
import random  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from filelock import FileLock  # noqa: E402

CONFIG = {
    "EPOCHS": EPOCHS,
    "LEARNING_RATE": LEARNING_RATE,
    "MOMENTUM": MOMENTUM,
    "BATCH_SIZE": BATCH_SIZE,
    "ACTIVATION": ACTIVATION,
    "USE_NORM": USE_NORM,
    "DROPOUT": DROPOUT,
}
BATCH_PENALTY = {16: 0.05, 32: 0.0, 64: 0.02, 128: 0.08}
ACTIVATION_PENALTY = {"tanh": 0.1, "relu": 0.03, "gelu": 0.0}
NOISE_STD = 0.01
MAX_EFFECTIVE_STEP = 0.5  # lr / (1 - momentum) above this "diverges": the run is infeasible


def train(config: dict, seed: int) -> dict:
    if config["EPOCHS"] <= 0:
        raise ValueError(f"EPOCHS must be positive, got {config['EPOCHS']}")
    time.sleep(float(os.environ.get("TOY_SLEEP_S", "0")))  # a slow "training run", for tests and benchmarks
    loss = (
        0.5 * (math.log10(config["LEARNING_RATE"]) - math.log10(3e-3)) ** 2
        + (config["MOMENTUM"] - 0.8) ** 2
        + (config["EPOCHS"] - 30) ** 2 / 900
        + BATCH_PENALTY[config["BATCH_SIZE"]]
        + ACTIVATION_PENALTY[config["ACTIVATION"]]
        + (0.0 if config["USE_NORM"] else 0.05)
        + (config["DROPOUT"] - 0.1) ** 2
    )
    noise = random.Random(seed).gauss(0.0, NOISE_STD)  # the same seed shifts every config alike
    effective_step = config["LEARNING_RATE"] / (1.0 - config["MOMENTUM"])
    return {
        "loss": loss + noise,
        "feasible": effective_step <= MAX_EFFECTIVE_STEP,
        "constraints": {"step_excess": effective_step - MAX_EFFECTIVE_STEP},  # graded: <= 0 is feasible
        "effective_step": effective_step,
        "best_train_loss": loss,
        "n_params": 10 * config["BATCH_SIZE"],
    }


def main() -> int:
    here = Path(__file__).resolve().parent
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--run-id", default=None)
    parser.add_argument("--runs-log", default=str(here / "runs.jsonl"))
    parser.add_argument("--out", default="out")
    args = parser.parse_args()
    run_id = args.run_id or f"manual-{int(time.time())}-{args.seed}"
    started = time.monotonic()
    try:
        result = train(CONFIG, args.seed)
    except Exception as err:
        print(f"training failed: {err}", file=sys.stderr)
        return 1
    record = {"run_id": run_id, **result, "seed": args.seed, "config": CONFIG}
    record["train_seconds"] = time.monotonic() - started
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "policy.json").write_text(json.dumps(CONFIG))  # the "trained policy"
    line = json.dumps(record)
    print(f"FINAL_METRIC: {line}", flush=True)
    with FileLock(f"{args.runs_log}.lock"):
        with open(args.runs_log, "a", encoding="utf-8") as log:
            log.write(line + "\n")
            log.flush()
            os.fsync(log.fileno())
    return 0


if __name__ == "__main__":
    sys.exit(main())
