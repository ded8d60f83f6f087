"""The committed leaderboard's deterministic rows flown again on the shipped splits (issue 57, item 4).

    .venv/bin/python benchmarks/leaderboard.py --tasks rendezvous docking docking-constrained --starts 256 \\
        --rows "open-loop expert" "closed-form feedback" "PD" "closed-form feedback + CBF" \\
        "PD + CBF" "routed feedback + CBF" --out runs/splits-reflown --work runs/splits-reflown/work
    .venv/bin/python results/splits/leaderboard_check.py runs/splits-reflown/leaderboard.json

(rendezvous and docking were flown on all 1024 sealed starts, without ``--starts``, as their rows
were.) Nothing of these rows is learned or random: the same starts and the same expert give the same
metric to the last bit, so a row that matches was scored on the shipped starts, and one that does
not was scored on another build. Prints a Markdown table.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def main(paths: list[str]) -> int:
    write = "--write" in paths
    paths = [p for p in paths if p != "--write"]
    board = ROOT / "results/leaderboard.json"
    rows = json.loads(board.read_text())
    committed = {(r["task"], r["controller"]): r for r in rows}
    print("| task | controller | starts | committed metric | on the shipped split | same to the bit |")
    print("|---|---|---:|---:|---:|---|")
    for path in paths:
        for row in json.loads(Path(path).read_text()):
            old = committed[(row["task"], row["controller"])]
            if old["n_starts"] != row["n_starts"]:
                continue  # flown on another number of starts than the committed row: not comparable
            same = (
                old["metric"] == row["metric"]
                and old["max_terminal_distance"] == row["max_terminal_distance"]
            )
            if same and write:
                old["split_id"] = row["split_id"]
            print(
                f"| {row['task']} | {row['controller']} | {row['n_starts']} | {old['metric']:.10g} | "
                f"{row['metric']:.10g} | {'yes' if same else 'no: another build'} |"
            )
    if write:
        sys.path.insert(0, str(ROOT / "benchmarks"))
        from leaderboard import markdown

        board.write_text(json.dumps(rows, indent=1, allow_nan=False) + "\n")
        (ROOT / "results/leaderboard.md").write_text(markdown(rows), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
