"""results/ as a pipeline (issue 59, item 5): every script under results/ is named in the index of
results/README.md, as the pipeline behind a README or leaderboard claim, as the research log's, or
as a probe; a new script left out of the index fails here."""

from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _scripts() -> list[str]:
    listed = subprocess.run(
        ["git", "ls-files", "results"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.split()
    return [p.removeprefix("results/") for p in listed if p.endswith((".py", ".sh"))]


def test_every_script_under_results_is_in_the_index():
    readme = (ROOT / "results" / "README.md").read_text(encoding="utf-8")
    index = readme.split("## Index", 1)[1].split("\n## ", 1)[0]
    scripts = _scripts()
    assert len(scripts) >= 40  # a lost listing would pass vacuously
    missing = [s for s in scripts if f"`{s}`" not in index and f"results/{s}" not in index]
    assert not missing, f"scripts under results/ not in results/README.md's index: {missing}"
