"""Provenance: what produced every record is kept, compared on resume and re-run, and reproduces."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import numpy
import pytest
from audit_support import AUDIT_FAMILY, P1, ScriptedProposer, copy_family, run_campaign
from loop_helpers import copy_toy

from autoresearch import provenance
from autoresearch.audit.inputs import open_campaign
from autoresearch.audit.noise import measure_noise
from autoresearch.audit.prune import prune
from autoresearch.audit.random_arm import run_random_arm
from autoresearch.campaign.audit_log import read_audit
from autoresearch.execution.executors import LocalExecutor
from autoresearch.execution.runner import run_locally
from autoresearch.execution.spec import RunSpec
from autoresearch.family import Family
from autoresearch.journal import read_json, read_jsonl, write_json_atomic

ROOT = Path(__file__).resolve().parents[1]


def cli(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "autoresearch", *args], capture_output=True, text=True, timeout=300, env=env
    )


def test_collect_reads_versions_without_importing_and_hashes_the_family(tmp_path):
    toy = copy_toy(tmp_path)
    record = provenance.collect(toy)
    assert record["packages"]["numpy"] == numpy.__version__
    torch_installed = importlib.util.find_spec("torch") is not None  # the base install has none
    assert record["packages"]["torch"] == (metadata.version("torch") if torch_installed else None)
    assert set(record["packages"]) == set(provenance.PACKAGES)
    assert record["git"] is None  # a copy under /tmp is in no repository
    assert len(provenance.collect(ROOT / "families" / "docking")["git"]["commit"]) == 40
    assert all(len(h) == 16 for name, h in record["family_files"].items() if name != "program_blind.md")

    # family.json is hashed without the fields the audit writes, so an audit does not change it ...
    registry = read_json(toy / "family.json")
    write_json_atomic(toy / "family.json", {**registry, "seed_noise": {"mean": 1.0, "std": 0.1, "k": 2}})
    assert provenance.family_hashes(toy) == record["family_files"]
    # ... while the problem and every code file do.
    write_json_atomic(toy / "family.json", {**registry, "target": 0.01})
    (toy / "train.py").write_text((toy / "train.py").read_text() + "\n# an edit\n")
    changed = provenance.differences(record, provenance.collect(toy))
    assert [line.split(":")[0] for line in changed] == ["family train.py", "family family.json"]


def test_differences_name_every_change_and_an_unrecorded_environment():
    now = provenance.collect(ROOT / "families" / "rendezvous")
    then = json.loads(json.dumps(now))
    then["packages"]["numpy"], then["packages"]["optuna"] = "1.0.0", None
    then["git"]["commit"], then["python"] = "0" * 40, "3.9.0"
    lines = provenance.differences(then, now)
    assert f"numpy: 1.0.0 -> {numpy.__version__}" in lines
    assert any(line.startswith("optuna: not installed -> ") for line in lines)
    assert any(line.startswith("git commit: 0000") for line in lines) and any("python" in x for x in lines)
    assert provenance.differences(now, now) == []
    assert provenance.differences(None, now) == [
        "no provenance was recorded (made before provenance was kept)"
    ]
    with pytest.raises(provenance.ProvenanceError, match=r"numpy: 1\.0\.0"):
        provenance.report([("campaign.json", then)], now, strict=True)


def test_resume_lists_the_differences_and_strict_refuses(tmp_path):
    toy, campaign = copy_toy(tmp_path), tmp_path / "c"
    start = ["loop", "--family", str(toy), "--proposer", "random", "--max-iters", "2", "--plain"]
    assert cli(*start, "--campaign", str(campaign)).returncode == 0
    meta = read_json(campaign / "campaign.json")
    assert meta["sessions"][0]["provenance"] == provenance.collect(toy)
    # The campaign's environment, as if it had run under another numpy and another train.py.
    meta["sessions"][0]["provenance"]["packages"]["numpy"] = "1.0.0"
    write_json_atomic(campaign / "campaign.json", meta)
    (toy / "train.py").write_text((toy / "train.py").read_text() + "\n# edited after the campaign ran\n")
    resume = ["loop", "--resume", "--campaign", str(campaign), "--max-iters", "3", "--plain"]

    checked = cli("check", "--campaign", str(campaign))
    assert (
        checked.returncode == 0 and "provenance: campaign.json, first session: numpy: 1.0.0" in checked.stdout
    )
    assert cli("check", "--campaign", str(campaign), "--strict-provenance").returncode == 1

    refused = cli(*resume, "--strict-provenance")
    assert refused.returncode == 2 and "--strict-provenance" in refused.stderr
    assert "numpy: 1.0.0 -> " in refused.stderr and "family train.py: sha256" in refused.stderr
    assert len(read_json(campaign / "campaign.json")["sessions"]) == 1  # nothing was written

    resumed = cli(*resume)
    assert resumed.returncode == 0, resumed.stderr
    assert "[provenance] campaign.json, first session: numpy: 1.0.0" in resumed.stderr
    sessions = read_json(campaign / "campaign.json")["sessions"]
    assert len(sessions) == 2 and sessions[1]["provenance"] == provenance.collect(toy)


def test_every_audit_step_records_its_provenance_and_a_rerun_compares(tmp_path):
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2)
    measure_noise(family, LocalExecutor(1), k=4, campaign=open_campaign(root))
    verify = ["verify", "--campaign", str(root), "--top", "1", "--seeds", "2"]
    assert cli(*verify).returncode == 0
    prune(open_campaign(root), LocalExecutor(1))
    run_random_arm(open_campaign(root), LocalExecutor(1), count=3)
    audit = read_audit(root)
    steps = ("noise", "verify", "prune", "random")
    assert all(audit[step]["provenance"] == provenance.collect(family.path) for step in steps)
    (family.path / "program.md").write_text((family.path / "program.md").read_text() + "\nEdited.\n")
    refused = cli(*verify, "--strict-provenance")
    assert refused.returncode == 2
    assert "audit.json verify: family program.md: sha256" in refused.stderr
    assert "audit.json noise: family program.md" in refused.stderr
    # Re-run without --strict-provenance: every trial is already logged, so nothing is measured
    # again, and the parts keep the provenance they were measured under (not the edited family's).
    before = read_audit(root)
    rerun = cli(*verify)
    assert rerun.returncode == 0 and "0 of 2 runs to do" in rerun.stderr
    measure_noise(family, LocalExecutor(1), k=4, campaign=open_campaign(root))
    prune(open_campaign(root), LocalExecutor(1))
    run_random_arm(open_campaign(root), LocalExecutor(1), count=3)
    after = read_audit(root)
    for step in steps:
        assert after[step]["provenance"] == before[step]["provenance"] != provenance.collect(family.path)
    assert after["noise"]["measured_at"] == before["noise"]["measured_at"]
    # A re-run that measures something new (the random arm drawn again) records what it ran under.
    shutil.rmtree(tmp_path / "campaign-random")
    run_random_arm(open_campaign(root), LocalExecutor(1), count=3)
    assert read_audit(root)["random"]["provenance"] == provenance.collect(family.path)


@pytest.mark.slow
def test_a_recorded_run_reruns_to_the_same_metric_bit_for_bit(tmp_path, monkeypatch):
    """A real rendezvous run recorded by the loop, re-run under the same provenance: the same metric,
    the same data (content keys), to the last bit."""
    from test_families import run

    family_dir = tmp_path / "rendezvous"
    shutil.copytree(
        ROOT / "families" / "rendezvous", family_dir, ignore=shutil.ignore_patterns("runs.jsonl*")
    )
    cache = tmp_path / "cache"
    run(family_dir / "prepare.py", "--warm-cache", cache=cache, check=True)
    env = {**os.environ, "CWH_ENVS_CACHE": str(cache), "OMP_NUM_THREADS": "1"}
    campaign = tmp_path / "c"
    done = cli(
        "loop", "--family", str(family_dir), "--proposer", "random", "--max-iters", "1", "--plain",
        "--campaign", str(campaign), env=env,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    record = read_jsonl(campaign / "proposals.jsonl")[0]  # the baseline: a real training, seconds
    recorded = read_json(campaign / "campaign.json")["sessions"][0]["provenance"]
    family = Family.load(family_dir)
    assert provenance.differences(recorded, provenance.collect(family.path)) == []
    monkeypatch.setenv("CWH_ENVS_CACHE", str(cache))
    again = run_locally(RunSpec(
        family, record["config"], "again", record["seed"], tmp_path / "again", tmp_path / "again.jsonl", 300
    ))  # fmt: skip
    assert again.ok and again.metric == record["metric"]
    assert again.final_metric["datasets"] == record["final_metric"]["datasets"]
    assert again.final_metric["best_train_loss"] == record["final_metric"]["best_train_loss"]
