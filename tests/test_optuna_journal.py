"""A campaign in Optuna's JournalStorage: exported after the fact and fed live, read back by
Optuna itself and served by a real optuna-dashboard while the loop runs."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import optuna
import pytest
from loop_helpers import TOY_OPTIMUM, ScriptedProposer, copy_toy, run_loop

from autoresearch.campaign import Campaign, CampaignMeta, Status
from autoresearch.family import Family
from autoresearch.optuna_journal import export_campaign

ROOT = Path(__file__).resolve().parents[1]


def load(path: Path, name: str) -> optuna.Study:
    storage = optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(path)))
    return optuna.load_study(study_name=name, storage=storage)


def test_export_gives_optuna_the_campaigns_trials(tmp_path):
    toy = copy_toy(tmp_path)
    script = [{"EPOCHS": 0}, {"EPOCHS": 12}, "not a dict", TOY_OPTIMUM]  # a failure and a refusal among them
    run_loop(toy, ScriptedProposer(script), tmp_path / "c", max_iters=5)
    CampaignMeta.new(Family.load(toy), "scripted", {}).write(tmp_path / "c")
    journal = tmp_path / "c.log"
    _, added = export_campaign(tmp_path / "c", journal)
    records = [r for r in Campaign(tmp_path / "c").records() if r.status.started_a_run]
    study = load(journal, "c")
    assert added == len(records) == len(study.trials) and study.direction.name == "MINIMIZE"
    assert study.metric_names == [Family.load(toy).metric]
    for trial, record in zip(study.trials, sorted(records, key=lambda r: r.iteration), strict=True):
        assert trial.user_attrs["run_id"] == record.run_id and trial.params == record.config
        if record.status is Status.RAN:
            assert trial.state.name == "COMPLETE" and trial.value == record.metric
        else:
            assert trial.state.name == "FAIL" and "exited" in trial.user_attrs["reason"]
    assert (
        study.best_trial.user_attrs["run_id"] == Campaign(tmp_path / "c").state(Family.load(toy)).best.run_id
    )
    # Derived, not a second record of truth: exporting again adds nothing.
    assert export_campaign(tmp_path / "c", journal)[1] == 0 and len(load(journal, "c").trials) == added


def test_a_committed_campaign_exports_with_its_graded_constraints(tmp_path):
    root = ROOT / "results" / "evidence" / "docking-gp"
    journal = tmp_path / "docking.log"
    export_campaign(root, journal)
    study = load(journal, root.name)
    runs = [r for r in Campaign(root).records() if r.status.started_a_run]
    assert len(study.trials) == len(runs)
    feasible = [t for t in study.trials if t.user_attrs.get("feasible")]
    assert feasible and all(max(t.constraints.values()) <= 0 for t in feasible)
    assert set(feasible[0].constraints) == {"success_shortfall", "violation_rate", "clearance_deficit"}
    infeasible = [t for t in study.trials if t.user_attrs.get("feasible") is False]
    assert infeasible and all(max(t.constraints.values()) > 0 for t in infeasible)
    stopped = [t for t in study.trials if t.state.name == "PRUNED"]
    assert all(t.intermediate_values for t in stopped)  # early-stopped runs keep their curve


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _get(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=5) as reply:
        return json.loads(reply.read())


@pytest.mark.slow
def test_a_real_dashboard_serves_the_campaign_while_the_loop_runs(tmp_path):
    toy = copy_toy(tmp_path)
    journal = tmp_path / "live.log"
    loop = subprocess.Popen(
        [sys.executable, "-m", "autoresearch", "loop", "--family", str(toy), "--proposer", "random",
         "--max-iters", "6", "--campaign", str(tmp_path / "c"), "--optuna-journal", str(journal), "--plain"],
        env={**os.environ, "TOY_SLEEP_S": "1.0"}, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    port = _free_port()
    deadline = time.monotonic() + 60
    while not journal.exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    dashboard = subprocess.Popen(
        [str(Path(sys.executable).with_name("optuna-dashboard")), str(journal), "--port", str(port), "--quiet"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        seen = []
        while loop.poll() is None and time.monotonic() < deadline:
            try:
                studies = _get(f"http://127.0.0.1:{port}/api/studies")["study_summaries"]
            except OSError:  # the server is starting
                time.sleep(0.2)
                continue
            detail = _get(f"http://127.0.0.1:{port}/api/studies/{studies[0]['study_id']}")
            seen.append(len(detail["trials"]))
            time.sleep(0.3)
        assert loop.wait(timeout=60) == 0, loop.stderr.read()
        runs = len(Campaign(tmp_path / "c").started())
        assert any(0 < n < runs for n in seen), seen  # the dashboard saw the campaign grow while it ran
        while time.monotonic() < deadline:  # the server re-reads the journal as it is asked
            detail = _get(f"http://127.0.0.1:{port}/api/studies/{studies[0]['study_id']}")
            if len(detail["trials"]) == runs:
                break
            time.sleep(0.2)
        assert len(detail["trials"]) == runs >= 5 and studies[0]["study_name"] == "c"
    finally:
        dashboard.terminate()
        dashboard.wait(timeout=10)
        if loop.poll() is None:
            loop.kill()


def test_two_campaigns_of_one_name_are_two_studies_never_merged(tmp_path):
    toy = copy_toy(tmp_path)
    maximizing = copy_toy(tmp_path, "toy-max")
    registry = json.loads((maximizing / "family.json").read_text())
    (maximizing / "family.json").write_text(
        json.dumps({**registry, "name": "toy-max", "direction": "maximize"})
    )
    journal = tmp_path / "both.log"
    exported = {}
    for family, script in ((toy, [{"EPOCHS": 12}]), (maximizing, [{"EPOCHS": 14}, {"EPOCHS": 15}])):
        campaign = tmp_path / family.name / "camp"  # both directories are called camp
        run_loop(family, ScriptedProposer(script), campaign, max_iters=len(script) + 1)
        CampaignMeta.new(Family.load(family), "scripted", {}).write(campaign)
        study, added = export_campaign(campaign, journal)
        exported[family.name] = (campaign, study.study.study_name, added)
    (first, name, added), (second, other, added_too) = exported["toy"], exported["toy-max"]
    assert name == "camp" and other.startswith("camp [") and (added, added_too) == (2, 3)
    assert load(journal, name).direction.name == "MINIMIZE" and len(load(journal, name).trials) == 2
    assert load(journal, other).direction.name == "MAXIMIZE" and len(load(journal, other).trials) == 3
    # Each finds its own study again, and adds nothing to it.
    assert export_campaign(first, journal)[0].study.study_name == name
    assert export_campaign(second, journal)[1] == 0
    assert (
        len(
            optuna.get_all_study_names(
                optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(journal)))
            )
        )
        == 2
    )


def test_an_audited_campaign_shows_its_certified_result_in_the_dashboard(tmp_path):
    """Issue 39, item 7: after an audit the live journal (and any export) carry what was certified:
    the audit's verdict, certified metric, split and margin as study user attributes, and every
    reseeded run as a trial of '<study> (reseeded)'."""
    toy, campaign, journal = copy_toy(tmp_path), tmp_path / "c", tmp_path / "live.log"
    cli = [sys.executable, "-m", "autoresearch"]
    loop = [*cli, "loop", "--family", str(toy), "--proposer", "random", "--max-iters", "4", "--seed", "3"]
    done = subprocess.run([*loop, "--campaign", str(campaign), "--plain", "--optuna-journal", str(journal)])
    assert done.returncode == 0
    audit = [*cli, "audit", "--campaign", str(campaign), "--noise-seeds", "3", "--seeds", "3", "--top", "2"]
    done = subprocess.run([*audit, "--count", "2"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "[optuna-journal] audit: " in done.stdout
    audited = json.loads((campaign / "audit.json").read_text())
    verify, prune = audited["verify"], audited["prune"]
    # what the audit promoted: the pruned recipe when pruning promoted it, else verify's candidate
    promoted = (
        prune["pruned"]
        if prune.get("promotes_pruned")
        else next(c for c in verify["candidates"] if c["config_id"] == verify["promoted"])
    )
    attrs = load(journal, "c").user_attrs
    assert attrs["audit_verdict"] == "PASS" and attrs["audit_split"] == "search"
    assert attrs["audit_metric"] == promoted["mu_r"] and attrs["audit_margin_sigma"] == promoted["margin"]
    assert attrs["audit_config_id"] == promoted["config_id"] and attrs["audit_n"] == 3
    reseeded = load(journal, "c (reseeded)")
    runs = [
        r
        for c in [*verify["candidates"], *([prune["pruned"]] if prune.get("pruned") else [])]
        for r in c["reseeds"]
    ]
    assert sorted(t.user_attrs["run_id"] for t in reseeded.trials) == sorted(r["run_id"] for r in runs)
    assert sorted(t.value for t in reseeded.trials if t.user_attrs["promoted"]) == sorted(
        r["metric"] for r in promoted["reseeds"]
    )
    # An export after the fact writes the same into a fresh journal, and adds nothing the second time.
    fresh = tmp_path / "fresh.log"
    for added in (f"({len(runs)} added)", "(0 added)"):
        done = subprocess.run(
            [*cli, "export", "--campaign", str(campaign), "--optuna-journal", str(fresh)],
            capture_output=True,
            text=True,
        )
        assert done.returncode == 0 and added in done.stdout, done.stdout + done.stderr
    assert load(fresh, "c").user_attrs["audit_metric"] == promoted["mu_r"]
