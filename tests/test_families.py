"""The two research families end to end: prepare, train, the FINAL_METRIC contract, reload, report.

Every test works on a copy of the family whose train.py is patched by plain text replacement:
tiny budgets in the editable region and tiny data pools in the fixed part, so the real torch
training and the real cwh_envs experts run in seconds against a private cache directory.
"""

from __future__ import annotations

import ast
import importlib.util
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from autoresearch.family import Family
from autoresearch.loop.editable import read_region
from autoresearch.loop.runner import parse_progress

ROOT = Path(__file__).resolve().parents[1]
FAMILIES = ("rendezvous", "docking")
METRICS = {"rendezvous": "mean_terminal_distance", "docking": "score"}
TINY_DATA = {"POOL_DEMOS": 8, "N_EVAL": 12, "POOL_RECOVERY": 4}
TINY_BUDGET = {"N_DEMOS": 4, "EPOCHS": 2, "BATCH_SIZE": 64, "HIDDEN_DIM": 16, "N_LAYERS": 1}


def patch_source(source: str, values: dict) -> str:
    """Replace ``NAME = value`` at the start of a line (keeping any comment); every name must exist."""
    for name, value in values.items():
        source, count = re.subn(
            rf"^{name} = .*?(\s+#.*)?$", rf"{name} = {value}\1", source, count=1, flags=re.M
        )
        assert count == 1, name
    return source


def family_copy(name: str, where: Path, **values) -> Path:
    """A copy of families/<name> with tiny data pools and the given train.py overrides."""
    target = where / name
    shutil.copytree(
        ROOT / "families" / name, target, ignore=shutil.ignore_patterns("runs.jsonl*", "out", "__pycache__")
    )
    tiny = {k: v for k, v in TINY_DATA.items() if k != "POOL_RECOVERY" or name == "docking"}
    source = (target / "train.py").read_text()
    (target / "train.py").write_text(patch_source(source, {**tiny, **values}))
    return target


def run(script: Path, *args: str, cache: Path, check: bool = False) -> subprocess.CompletedProcess:
    env = {**os.environ, "CWH_ENVS_CACHE": str(cache), "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    result = subprocess.run(
        [sys.executable, str(script), *args],
        cwd=script.parent,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    if check:
        assert result.returncode == 0, result.stderr
    return result


def final_metric(stdout: str) -> dict:
    lines = [line for line in stdout.splitlines() if line.startswith("FINAL_METRIC: ")]
    assert len(lines) == 1, stdout
    return json.loads(lines[0].removeprefix("FINAL_METRIC: "))


def import_train(path: Path):
    spec = importlib.util.spec_from_file_location(f"train_under_test_{abs(hash(path))}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def warm(tmp_path_factory):
    """{family: (tiny family dir, warm cache dir)} shared by the tests that need data."""
    made = {}
    for name in FAMILIES:
        root = tmp_path_factory.mktemp(name)
        budget = {**TINY_BUDGET, **({"RECOVERY_AUGMENT_FRAC": 0.5} if name == "docking" else {})}
        family = family_copy(name, root, **{k: repr(v) for k, v in budget.items()})
        run(family / "prepare.py", "--warm-cache", cache=root / "cache", check=True)
        made[name] = (family, root / "cache")
    return made


@pytest.mark.parametrize("name", FAMILIES)
def test_prepare_check_names_what_is_missing_then_passes_once_warm(name, tmp_path):
    family = family_copy(name, tmp_path)
    cache = tmp_path / "cache"
    cold = run(family / "prepare.py", "--check", cache=cache)
    assert cold.returncode != 0
    assert "training pool" in cold.stderr and "evaluation starts" in cold.stderr and "missing" in cold.stderr
    assert ("recovery pool" in cold.stderr) == (name == "docking")
    assert not cache.exists() or not any(cache.iterdir()), "--check must not build anything"
    run(family / "prepare.py", "--warm-cache", cache=cache, check=True)
    assert run(family / "prepare.py", "--check", cache=cache, check=True).returncode == 0


@pytest.mark.slow
@pytest.mark.parametrize("name", FAMILIES)
def test_train_prints_one_final_metric_appends_one_line_and_is_deterministic(name, warm, tmp_path):
    family, cache = warm[name]
    log = tmp_path / "runs.jsonl"
    records = []
    for i in range(2):
        result = run(
            family / "train.py", "--seed", "3", "--run-id", f"r{i}", "--runs-log", str(log),
            "--out", str(tmp_path / f"out{i}"), cache=cache, check=True,
        )  # fmt: skip
        records.append(final_metric(result.stdout))
        # PROGRESS (optional contract): the metric at up to 4 evenly spaced epochs, the last one included
        curve = [
            parse_progress(line, METRICS[name]) for line in result.stdout.splitlines() if "PROGRESS" in line
        ]
        steps = [point["step"] for point in curve]
        assert (
            1 <= len(curve) <= 4
            and steps == sorted(set(steps))
            and steps[-1] == records[-1]["config"]["EPOCHS"]
        )
    logged = [json.loads(line) for line in log.read_text().splitlines()]
    assert logged == records
    first, second = records
    assert first["run_id"] == "r0" and first["seed"] == 3
    assert math.isfinite(first[METRICS[name]]) and first[METRICS[name]] == second[METRICS[name]]
    assert first["best_train_loss"] == second["best_train_loss"]
    defaults = read_region((family / "train.py").read_text()).values()
    assert first["config"] == defaults
    for field in ("success_rate", "best_train_loss", "train_seconds", "n_params"):
        assert field in first
    if name == "docking":
        assert {"violation_rate", "min_clearance", "strict_feasible"} <= set(first)


@pytest.mark.slow
@pytest.mark.parametrize("name", FAMILIES)
def test_saved_policy_reloads_and_reproduces_the_metric(name, warm, tmp_path, monkeypatch):
    family, cache = warm[name]
    result = run(
        family / "train.py", "--runs-log", str(tmp_path / "log"), "--out", str(tmp_path / "out"), cache=cache
    )
    record = final_metric(result.stdout)
    monkeypatch.setenv("CWH_ENVS_CACHE", str(cache))
    train = import_train(family / "train.py")
    policy, saved = train.load_policy(tmp_path / "out")
    assert saved["config"] == record["config"] and saved["record"] == record
    starts, goals = train.evaluation_starts(train.TASK, train.N_EVAL, problem=train.PROBLEM)
    if name == "rendezvous":
        metrics = train.rendezvous_metrics(train.fly(policy, starts))
    else:
        metrics = train.evaluate(policy, starts, goals, record["config"]["RUNTIME_CBF_FILTER"])
    assert metrics[METRICS[name]] == pytest.approx(record[METRICS[name]], rel=1e-9, abs=1e-12)

    png = tmp_path / "report.png"
    run(
        family / "report.py",
        "--policy",
        str(tmp_path / "out"),
        "--out",
        str(png),
        "--starts",
        "2",
        cache=cache,
        check=True,
    )
    assert png.stat().st_size > 0


@pytest.mark.slow
@pytest.mark.parametrize("name", FAMILIES)
@pytest.mark.parametrize(
    ("learning_rate", "message"), [("float('nan')", "invalid configuration"), ("1e30", "training diverged")]
)
def test_a_failed_run_exits_nonzero_without_final_metric(name, learning_rate, message, warm, tmp_path):
    family, cache = warm[name]
    broken = tmp_path / "train.py"
    broken.write_text(patch_source((family / "train.py").read_text(), {"LEARNING_RATE": learning_rate}))
    log = tmp_path / "runs.jsonl"
    result = run(broken, "--runs-log", str(log), "--out", str(tmp_path / "out"), cache=cache)
    assert result.returncode != 0
    assert "FINAL_METRIC" not in result.stdout
    assert message in result.stderr
    assert not log.exists()


def test_docking_score_and_strict_gate(monkeypatch):
    train = import_train(ROOT / "families" / "docking" / "train.py")
    problem = train.PROBLEM
    horizon, n = problem.horizon, 10
    goals = np.tile([problem.goal_radius, 0.0, 0.0], (n, 1))
    states = np.zeros((n, horizon + 1, 6))
    states[:, :, :3] = goals[:, None, :]  # parked on the docking point: clearance 3 m throughout

    perfect = train.docking_metrics(states, goals)
    assert perfect["score"] == 0.0 and perfect["success_rate"] == 1.0 and perfect["strict_feasible"] is True

    grazing = states.copy()
    grazing[0, 5, :3] = [problem.koz_radius, 0.0, 0.0]  # on the sphere: clearance 0 is not a violation
    assert train.docking_metrics(grazing, goals)["strict_feasible"] is True

    inside = states.copy()
    inside[0, 5:7, :3] = [problem.koz_radius - 1.0, 0.0, 0.0]  # two steps inside the keep-out
    metrics = train.docking_metrics(inside, goals)
    assert metrics["violation_rate"] == pytest.approx(2 / horizon / n)
    assert metrics["score"] == pytest.approx(10.0 * 2 / horizon / n)
    assert metrics["min_clearance"] == pytest.approx(-1.0)
    assert metrics["success_rate"] == 0.9  # a violating start is never a success
    assert metrics["strict_feasible"] is False

    missed = states.copy()
    missed[:3, -1, 0] += 2.0  # three of ten starts end 2 m from the docking point: success 0.7 < 0.8
    metrics = train.docking_metrics(missed, goals)
    assert metrics["violation_rate"] == 0.0 and metrics["min_clearance"] >= 0.0
    assert metrics["success_rate"] == pytest.approx(0.7) and metrics["strict_feasible"] is False
    assert metrics["score"] == pytest.approx(0.6)

    slow = states.copy()
    slow[:, -1, 3] = 0.06  # at the dock but too fast: not a success
    assert train.docking_metrics(slow, goals)["success_rate"] == 0.0

    # The graded constraints are the same gate: all <= 0 exactly when strict_feasible, and they say
    # by how much each case misses (family.json's constraints_field, read by the key-free arms).
    family = Family.load(ROOT / "families" / "docking")
    for case in (states, grazing, inside, missed, slow):
        metrics = train.docking_metrics(case, goals)
        graded = family.constraints(metrics)
        assert (max(graded.values()) <= 0.0) is metrics["strict_feasible"] is family.is_feasible(metrics)
    assert family.constraints(train.docking_metrics(missed, goals))["success_shortfall"] == pytest.approx(0.1)
    assert family.constraints(train.docking_metrics(inside, goals))["clearance_deficit"] == pytest.approx(1.0)


@pytest.mark.parametrize("name", FAMILIES)
def test_family_json_matches_the_contract_and_train_py(name):
    path = ROOT / "families" / name
    family = Family.load(path)  # the loader's own checks: schema, search space, baseline == defaults
    registry = json.loads((path / "family.json").read_text())
    defaults = read_region((path / "train.py").read_text()).values()
    assert set(registry["search_space"]) == set(defaults)
    assert registry["baseline"]["config"] == defaults
    assert family.metric == METRICS[name] and family.direction == -1
    # Only `autoresearch noise` and the audit's promotion write these; when present they must be whole.
    noise = registry["seed_noise"]
    if noise is not None:
        assert noise["k"] >= 2 and len(noise["values"]) == noise["k"] and noise["std"] > 0
    if registry["best"] is not None:
        family.space.validate_full(registry["best"]["config"])
    assert (
        isinstance(registry["baseline"]["metric"], float)
        and registry["baseline"]["seed"] == family.default_seed
    )
    assert family.feasibility_field == ("strict_feasible" if name == "docking" else None)
    if name == "docking":
        assert family.target == 0.7
        assert {"safety"} <= set(family.axes) and registry["search_space"]["RUNTIME_CBF_FILTER"][
            "axis"
        ] == "safety"
    tree = ast.parse((path / "train.py").read_text())
    fixed = {
        n.targets[0].id: n.value
        for n in tree.body
        if isinstance(n, ast.Assign) and isinstance(n.targets[0], ast.Name)
    }
    assert ast.literal_eval(fixed["METRIC"]) == family.metric
    for program in ("program.md", "program_blind.md"):
        text = (path / program).read_text()
        assert all(parameter in text for parameter in defaults), f"{program} must name every parameter"
    blind = (path / "program_blind.md").read_text()
    assert "## Target" in (path / "program.md").read_text() and "## Target" not in blind
    assert "## Baseline" not in blind and f"{registry['baseline']['metric']:.3g}" not in blind
