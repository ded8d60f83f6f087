"""Every committed campaign's report regenerates (issue 57, item 6).

Each campaign under results/ that holds a report.md is copied, as a clone has it, into a scratch
tree laid out like the repository (its family directories beside it, the working directory at its
root, so that every relative path the campaign recorded resolves inside the copy), and
``autoresearch report`` writes its report again there, with the arms its committed report drew.
The test fails when the command fails, when the regenerated report.md differs from the committed
one, or when a figure autoresearch draws is not written again at the committed size (the recipe
figure's size counts the parameters the campaign recorded). A family that grew parameters since a
campaign ran must not break it: the report reads only what the campaign recorded.

One part of a report may legitimately differ: the family's hooks (report.py's domain figure,
export.py's policy) need the promoted policy's saved run, which is never committed (the run
directories are git-ignored). Without it a committed figure or policy file is kept as it is, and
a hook line is replaced by the sentence that the saved run is not here; the committed line may
instead say what the hook said when the run was there (rendezvous-gp-cold-costate's export
failed on an ONNX tolerance). Every other line, numbers included, must match byte for byte.

The figures' pixels are not compared: they depend on the installed matplotlib and FreeType.
"""

from __future__ import annotations

import difflib
import json
import shutil
import struct
from pathlib import Path

import pytest
from audit_support import AUDIT_FAMILY, P1, ScriptedProposer, copy_family, run_campaign

from autoresearch.audit.inputs import open_campaign
from autoresearch.audit.noise import measure_noise
from autoresearch.audit.verify import verify
from autoresearch.cli import main
from autoresearch.execution.executors import LocalExecutor
from autoresearch.journal import read_json

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGNS = sorted(str(p.parent.relative_to(ROOT)) for p in (ROOT / "results").glob("**/report.md"))

# The arms a committed report drew beside its campaign (--arm): results/run_recipe.sh and
# results/run_pruning.sh for the hand recipes; the rendezvous random arm's report drew the TPE
# campaign it took its budget from. Every other report was written without --arm.
ARMS = {
    "results/docking/hand": ("results/docking/tpe", "results/docking/tpe-random"),
    "results/rendezvous/hand": ("results/rendezvous/tpe", "results/rendezvous/tpe-random"),
    "results/rendezvous/tpe-random": ("results/rendezvous/tpe",),
}
FIGURES = ("search.png", "recipe.png")
HOOK_LINES = ("No family figure: ", "No exported policy: ")
RUN_NOT_HERE = "is not here; re-run"  # autoresearch.audit.figures.family_hook without the saved run


def test_every_committed_report_is_listed():
    assert len(CAMPAIGNS) >= 32, CAMPAIGNS  # the issue counted 32; a lost glob would pass vacuously
    assert set(ARMS) <= set(CAMPAIGNS)


def _copy_campaign(source: Path, target: Path) -> None:
    """``source`` as a clone holds it: without the run directories .gitignore keeps out
    (results/**/audit/*/*/: patched train.py, stdout, weights) and without weights or locks."""
    shutil.copytree(source, target, ignore=shutil.ignore_patterns("*.pt", "*.lock", "runs", "__pycache__"))
    audit = target / "audit"
    if audit.is_dir():
        for step in audit.iterdir():
            for run in step.iterdir() if step.is_dir() else ():
                if run.is_dir():
                    shutil.rmtree(run)


def _recorded_dirs(campaign: Path) -> list[str]:
    """The other campaigns the report reads by a recorded path: the audit's random arms (none for a
    campaign not audited yet, whose report is its search alone)."""
    if not (campaign / "audit.json").exists():
        return []
    audit = json.loads((campaign / "audit.json").read_text(encoding="utf-8"))
    return [
        part["dir"] for part in audit.values() if isinstance(part, dict) and isinstance(part.get("dir"), str)
    ]


def png_size_of(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    return struct.unpack(">II", data[16:24])


def png_size(path: Path) -> tuple[int, int]:
    return png_size_of(path.read_bytes())


def _same(old: str, new: str) -> bool:
    """The same line, or the same hook's line where the regenerated one says the saved run is not
    here (the committed one may say what the hook did with it when it was)."""
    if old == new:
        return True
    hook = next((h for h in HOOK_LINES if new.startswith(h)), None)
    return hook is not None and RUN_NOT_HERE in new and old.startswith(hook)


def _differences(committed: list[str], regenerated: list[str]) -> list[str]:
    """The lines that differ, as a unified diff; nothing when every line is :func:`_same`."""
    if len(committed) == len(regenerated) and all(map(_same, committed, regenerated)):
        return []
    return list(difflib.unified_diff(committed, regenerated, "committed", "regenerated", lineterm="", n=1))


@pytest.mark.parametrize("campaign", CAMPAIGNS)
def test_committed_report_regenerates(campaign, tmp_path, monkeypatch):
    shutil.copytree(
        ROOT / "families", tmp_path / "families", ignore=shutil.ignore_patterns("out", "__pycache__")
    )
    arms = ARMS.get(campaign, ())
    for rel in dict.fromkeys((campaign, *arms, *_recorded_dirs(ROOT / campaign))):
        if (ROOT / rel).is_dir():
            _copy_campaign(ROOT / rel, tmp_path / rel)
    copy = tmp_path / campaign
    for figure in FIGURES:  # drawn again, not left over from the copy
        (copy / figure).unlink(missing_ok=True)
    monkeypatch.chdir(tmp_path)  # the paths the campaign recorded are relative to the repository root
    argv = ["report", "--campaign", campaign, *(a for arm in arms for a in ("--arm", arm))]
    assert main(argv) == 0, f"`autoresearch {' '.join(argv)}` failed"

    committed = (ROOT / campaign / "report.md").read_text(encoding="utf-8").splitlines()
    regenerated = (copy / "report.md").read_text(encoding="utf-8").splitlines()
    diff = _differences(committed, regenerated)
    assert not diff, (
        f"{campaign}/report.md does not regenerate; if the change is intended, run "
        f"`autoresearch {' '.join(argv)}` from the repository root and commit the report and its figures:\n"
        + "\n".join(diff)
    )
    for figure in FIGURES:
        assert png_size(copy / figure) == png_size(ROOT / campaign / figure), f"{campaign}/{figure}"


def test_a_report_reads_only_what_its_campaign_recorded(tmp_path):
    """A verify-only audit, then the family grows (a new parameter, a new choice of a categorical) and
    its seed noise is measured again: the report is written again unchanged, the recipe figure keeps
    the parameters and choices the campaign searched, and the reference row stays the noise the gate
    used (the family's later measurement is never shown as this audit's)."""
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2)
    measure_noise(family, LocalExecutor(1), k=3, out_dir=tmp_path / "noise")
    verify(open_campaign(root), LocalExecutor(1), top=1, n_seeds=2)
    assert main(["report", "--campaign", str(root)]) == 0
    before = {name: (root / name).read_bytes() for name in ("report.md", "recipe.png")}
    gated = read_json(root / "audit.json")["verify"]["noise"]
    assert f"| Seed noise (n=3) | {gated['mean']:.4g} ± {gated['std']:.2g} | n/a | reference |" in (
        before["report.md"].decode()
    )

    registry = read_json(family.path / "family.json")
    registry["search_space"]["GROWN"] = {"type": "bool", "axis": "architecture"}
    registry["search_space"]["HITCH"]["choices"].append("c")
    registry["baseline"]["config"]["GROWN"] = False
    (family.path / "family.json").write_text(json.dumps(registry, indent=2), encoding="utf-8")
    train = family.path / "train.py"
    text = train.read_text(encoding="utf-8")
    train.write_text(text.replace("WIDE = False", "WIDE = False\nGROWN = False", 1), encoding="utf-8")
    ledger = read_json(family.path / "ledger.json")
    ledger["seed_noise"] = {**ledger["seed_noise"], "mean": 2 * gated["mean"], "measured_at": "later"}
    (family.path / "ledger.json").write_text(json.dumps(ledger, indent=2), encoding="utf-8")

    assert main(["check", "--campaign", str(root)]) == 0  # the family only grew: the same campaign
    assert main(["report", "--campaign", str(root)]) == 0
    assert (root / "report.md").read_bytes() == before["report.md"]
    assert png_size(root / "recipe.png") == png_size_of(before["recipe.png"])


def test_prune_and_the_matched_arm_read_a_grown_familys_old_runs(tmp_path):
    """A run recorded before its family grew lacks the new parameter: it held the baseline value, so
    it edits nothing there (pruning's edit list) and spans only that value (the matched arm's range)."""
    from autoresearch.audit.inputs import changed_params
    from autoresearch.audit.random_arm import matched_ranges

    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2)
    registry = read_json(family.path / "family.json")
    registry["search_space"]["MORE_EPOCHS"] = {"type": "int", "low": 0, "high": 9, "axis": "training_budget"}
    registry["baseline"]["config"]["MORE_EPOCHS"] = 3
    (family.path / "family.json").write_text(json.dumps(registry, indent=2), encoding="utf-8")
    train = family.path / "train.py"
    text = train.read_text(encoding="utf-8")
    train.write_text(text.replace("WIDE = False", "WIDE = False\nMORE_EPOCHS = 3", 1), encoding="utf-8")
    campaign = open_campaign(root)
    assert changed_params(campaign.family, P1) == list(P1)
    assert matched_ranges(campaign)["MORE_EPOCHS"] == {"low": 3, "high": 3}
