"""Audit test family plotting hook: draws the saved policy's values (called by the audit report)."""

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--policy", required=True, help="a run's saved policy directory")
    parser.add_argument("--out", required=True, help="PNG to write")
    args = parser.parse_args()
    policy = json.loads((Path(args.policy) / "policy.json").read_text())
    numeric = {k: float(v) for k, v in policy.items() if not isinstance(v, str)}
    fig, ax = plt.subplots(figsize=(5, 3))
    ax.bar(list(numeric), list(numeric.values()))
    ax.set_title("saved policy")
    ax.tick_params(axis="x", rotation=60)
    fig.tight_layout()
    fig.savefig(args.out, dpi=80)
