"""Mark every committed number by the starts it was scored on (issue 57, item 4).

Committed runs written before the families pinned their splits (family.json's split_ids) record no
split identity, only the content keys of the data sets they read (FINAL_METRIC's ``datasets``), which
hash the expert's floats too. A run whose content key equals the key this machine computes from the
shipped starts (cwh_envs/data) was scored on exactly those starts: the key covers the starts. A run
whose key differs was scored on another build: other starts, or the same starts with other expert
floats (an older expert, or another machine's rounding); this script cannot tell which, and says
"another build".

    python results/splits/mark.py      # writes results/splits/marks.json and marks.md

Reads every runs.jsonl under results/; builds (or reads from the cwh_envs cache) the evaluation sets
at the sizes the families have used: search 128 and 512, test 1024.
"""

from __future__ import annotations

import json
import sys
from collections import Counter, defaultdict
from pathlib import Path

from cwh_envs.datasets import evaluation_set

HERE = Path(__file__).resolve().parent
RESULTS = HERE.parent
sys.path.insert(0, str(RESULTS.parent / "scripts"))
from make_splits import SPLITS  # noqa: E402

SIZES = {"search": (128, 512), "test": (1024,)}
FIELDS = {"search_split": "search", "test_split": "test"}


def shipped_keys() -> dict[str, str]:
    """content key -> which shipped split (and size) it is, as computed on this machine."""
    keys = {}
    for name, (task, problem, split, size) in SPLITS.items():
        for n in SIZES[split]:
            if n <= size:
                keys[evaluation_set(task, n, problem=problem, split=split).content_key] = (
                    f"{name}-v0, first {n}"
                )
    return keys


def main() -> int:
    known = shipped_keys()
    marks: dict[str, Counter] = defaultdict(Counter)
    for log in sorted(RESULTS.rglob("runs.jsonl")):
        if HERE / "runs" in log.parents:
            continue  # this folder's own re-measurements (not committed): family_bests.md holds them
        where = str(log.parent.relative_to(RESULTS.parent))
        for line in log.read_text(errors="replace").splitlines():
            try:
                record = json.loads(line)
            except ValueError:
                continue
            data = record.get("datasets") if isinstance(record, dict) else None
            for field, split in FIELDS.items():
                if field == "test_split" and "test" not in (record.get("splits") or {}):
                    continue
                key = (data or {}).get(field)
                if key is None:
                    mark = "no content key recorded" if split == "search" else None
                else:
                    mark = f"shipped starts ({known[key]})" if key in known else f"another build ({key})"
                if mark:
                    marks[where][f"{split}: {mark}"] += 1
    (HERE / "marks.json").write_text(json.dumps({k: dict(v) for k, v in marks.items()}, indent=1) + "\n")
    totals: Counter = Counter()
    for counts in marks.values():
        for mark, count in counts.items():
            totals[mark.split(" (")[0]] += count
    lines = [
        "# Which starts each committed number was scored on",
        "",
        "Written by `python results/splits/mark.py` (see its docstring). Runs per log, by split and mark.",
        "",
        "| runs of | " + " | ".join(sorted(totals)) + " |",
        "|---|" + "---:|" * len(totals),
        "| all committed logs | " + " | ".join(str(totals[m]) for m in sorted(totals)) + " |",
        "",
        "| log directory | marks |",
        "|---|---|",
    ]
    for where, counts in sorted(marks.items()):
        lines.append(f"| {where} | " + "; ".join(f"{c} {m}" for m, c in sorted(counts.items())) + " |")
    (HERE / "marks.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines[:8]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
