"""The hand recipe reseeded at seeds 11-20 on the rendezvous test split as built on this machine, two at a time.

OMP_NUM_THREADS=1 .venv/bin/python results/keyfree-search/hand_reseed.py > results/logs/keyfree_hand_reseed.txt
"""

import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

root = Path(__file__).resolve().parents[2]
# the hand recipe as the ledger promoted it (summarize.py's reference)
ledger = json.loads((root / "families/rendezvous/ledger.json").read_text())
hand = next(p for p in ledger["promotions"] if p["source"]["campaign"] == "results/rendezvous/hand")["config"]
d = Path(tempfile.mkdtemp(prefix="keyfree-hand-"))  # a copy of the family, the hand recipe written in
shutil.copytree(root / "families/rendezvous", d, ignore=shutil.ignore_patterns("runs", "logs"))
src = (root / "families/rendezvous/train.py").read_text()
for k, v in hand.items():
    src, n = re.subn(rf"^{k} = [^#\n]*", f"{k} = {v!r} ", src, count=1, flags=re.M)
    assert n == 1
(d / "train.py").write_text(src)
env = {**os.environ, "OMP_NUM_THREADS": "1"}
out = {}
seeds = list(range(11, 21))
for i in range(0, 10, 2):
    ps = {
        s: subprocess.Popen(
            [
                sys.executable,
                "train.py",
                "--seed",
                str(s),
                "--eval-split",
                "test",
                "--out",
                str(d / f"out{s}"),
            ],
            cwd=d,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for s in seeds[i : i + 2]
    }
    for s, p in ps.items():
        o, e = p.communicate()
        r = json.loads(next(x for x in o.splitlines() if x.startswith("FINAL_METRIC")).split(":", 1)[1])
        out[s] = (
            r["splits"]["test"]["mean_terminal_distance"],
            r["splits"]["search"]["mean_terminal_distance"],
            r["datasets"],
        )
        print(s, round(out[s][0], 5), round(out[s][1], 5), flush=True)
t = [v[0] for v in out.values()]
print(
    "test mean",
    statistics.mean(t),
    "sd",
    statistics.stdev(t),
    "search mean",
    statistics.mean(v[1] for v in out.values()),
)
print("datasets", next(iter(out.values()))[2])
