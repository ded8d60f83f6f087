"""Re-gate the top-3 verification (top3.sh, gated on the search split) on the sealed test split, as
verify's default now does, from the logged reseeds (nothing is trained): every candidate's test-split
gate (Eq. reseedgate against the rendezvous family's test-split seed noise, and the runaway gate),
and which candidate the default then promotes (the search split picks among those that pass).

    python results/keyfree-search/top3_test_gate.py [ROOT]   # ROOT: results/keyfree-search
"""

import json
import sys
from pathlib import Path

from autoresearch.audit import tails
from autoresearch.audit.inputs import seed_noise
from autoresearch.audit.verify import assess, pick_key
from autoresearch.campaign.audit_log import StepLog
from autoresearch.family import Family
from autoresearch.splits import Split

root = Path(sys.argv[1] if len(sys.argv) > 1 else "results/keyfree-search")
family = Family.load(Path("families/rendezvous"))
noise, sign = seed_noise(family, Split.TEST), family.direction
print(f"test-split seed noise {noise['mean']:.4f} ± {noise['std']:.4f} (K = {noise['k']})\n")
print(
    "| repeat | candidate | test gate | m (test) | runaway starts | promoted (search pick, test gate) | recorded |"
)
print("|---|---|---|---:|---|---|---|")
for audit in sorted(root.glob("top3-search/repeat-*/audit.json")):
    verify = json.loads(audit.read_text())["verify"]
    rows = StepLog(audit.parent / "audit" / "verify" / "verify.jsonl").read()
    gated = []
    for c in verify["candidates"]:
        own = [row for row in rows if row.key.startswith(f"verify-{c['config_id']}-")]
        source_loss = c["source"]["best_train_loss"]
        gated.append(
            (
                c["config_id"],
                assess(own, source_loss, noise, sign, Split.TEST, family.tail_fields, tails.RUNAWAY),
            )
        )
    passing = [(cid, x) for cid, x in gated if x["passed"]]
    promoted = max(passing, key=lambda p: pick_key(p[1], sign))[0] if passing else None
    for cid, x in gated:
        runaways = len(x["tails"].get("runaways", []))
        print(
            f"| {audit.parent.name} | {cid} | {x['reason']} | {x['margin']:.1f} | {runaways} of {x['n']} reseeds "
            f"| {'**yes**' if cid == promoted else ''} | {'yes' if cid == verify['promoted'] else ''} |"
        )
