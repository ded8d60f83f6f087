"""Table the top-3 verification of results/keyfree-search/top3.sh: per repeat, each candidate's
single-seed search metric, reseeded search and test means, and which one the search split picks;
writes top3-search/summary.json.

    python results/keyfree-search/top3.py [ROOT]   # ROOT: results/keyfree-search
"""

import json
import sys
from pathlib import Path

root = Path(sys.argv[1] if len(sys.argv) > 1 else "results/keyfree-search")
summary = json.loads((root / "summary.json").read_text())
limit = summary["target"]["test_metric_at_most"]
print(
    f"hand recipe {summary['hand_recipe']['test_metric']:.4f} m on the test split; target <= {limit:.4f} m\n"
)
print(
    "| repeat | candidate | shape | single seed, search | reseeded search (n = 10) | reseeded test (n = 10) | picked on search | one-seed pick |"
)
print("|---|---|---|---:|---:|---:|---|---|")
rows, within = [], {"picked_on_search": 0, "one_seed_pick": 0}
for audit in sorted(root.glob("top3-search/repeat-*/audit.json")):
    verify = json.loads(audit.read_text())["verify"]
    first = verify["candidates"][0]["config_id"]  # ranked by the single-seed search metric
    for c in verify["candidates"]:
        search, test = c["by_split"]["search"], c["by_split"]["test"]
        cfg = c["config"]
        picked, one_seed = c["config_id"] == verify["promoted"], c["config_id"] == first
        within["picked_on_search"] += picked and test["mu_r"] <= limit
        within["one_seed_pick"] += one_seed and test["mu_r"] <= limit
        repeat = audit.parent.name
        rows.append(
            {
                "repeat": repeat,
                "config_id": c["config_id"],
                "config": cfg,
                "single_seed_search": c["source"]["metric"],
                "search": search["mu_r"],
                "test": test["mu_r"],
                "passed": c["passed"],
                "picked": picked,
            }
        )
        print(
            f"| {repeat} | {c['config_id']} | {cfg['N_DEMOS']} demos, {cfg['N_LAYERS']} x {cfg['HIDDEN_DIM']} {cfg['ACTIVATION']} "
            f"| {c['source']['metric']:.4f} | {search['mu_r']:.4f} ± {search['sigma_r']:.4f} | {test['mu_r']:.4f} ± {test['sigma_r']:.4f} "
            f"| {'**yes**' if picked else ''} | {'yes' if one_seed else ''} |"
        )
n = len({r["repeat"] for r in rows})
print(
    f"\nwithin the target: picked on the reseeded search split {within['picked_on_search']} of {n}; one-seed pick {within['one_seed_pick']} of {n}"
)
out = root / "top3-search" / "summary.json"
out.write_text(
    json.dumps(
        {
            "command": "bash results/keyfree-search/top3.sh",
            "target": summary["target"],
            "within_target": {k: f"{v} of {n}" for k, v in within.items()},
            "candidates": rows,
        },
        indent=1,
    )
    + "\n"
)
print(f"written: {out}")
