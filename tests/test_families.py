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

import gymnasium as gym
import numpy as np
import pytest

import cwh_envs
from autoresearch.editable import read_region
from autoresearch.execution.protocol import parse_progress
from autoresearch.family import Family
from cwh_envs import prepare

ROOT = Path(__file__).resolve().parents[1]
FAMILIES = ("rendezvous", "docking")
METRICS = {"rendezvous": "mean_terminal_distance", "docking": "score"}
TINY_DATA = {"POOL_DEMOS": 8, "N_EVAL": 12, "N_TEST": 24, "POOL_RECOVERY": 4}
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


@pytest.mark.needs("families")
@pytest.mark.parametrize("name", FAMILIES)
def test_prepare_check_names_what_is_missing_then_passes_once_warm(name, tmp_path):
    family = family_copy(name, tmp_path)
    cache = tmp_path / "cache"
    cold = run(family / "prepare.py", "--check", cache=cache)
    assert cold.returncode != 0
    assert all(part in cold.stderr for part in ("training pool", "search split", "test split", "missing"))
    assert ("recovery pool" in cold.stderr) == (name == "docking")
    assert not cache.exists() or not any(cache.iterdir()), "--check must not build anything"
    built = run(family / "prepare.py", "--warm-cache", cache=cache, check=True)
    # what it will build and about how long, said before it starts (issue 39, item 15)
    sets = len(cold.stderr.splitlines()) - 2
    assert re.search(
        rf"^to build: {sets} of {sets} data sets, about \d+ (s|min) in all:$", built.stdout, re.M
    )
    assert built.stdout.index("to build:") < built.stdout.index("ready:")
    assert run(family / "prepare.py", "--check", cache=cache, check=True).returncode == 0
    again = run(family / "prepare.py", "--warm-cache", cache=cache, check=True)
    assert "to build" not in again.stdout


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
        # The Monte Carlo auxiliary: the same policy under the family's dispersion set, beside the score.
        dispersed = first["dispersed"]
        assert {"success_rate", "violation_rate", "violating_starts", "mean_terminal_distance"} < set(
            dispersed
        )
        assert dispersed["mean_terminal_distance"] != first["mean_terminal_distance"]
        # Beside it, the 3-sigma stress set and the share of starts breaking the keep-out at 1 sigma.
        assert first["dispersed_3sigma"]["dispersions"] != dispersed["dispersions"]
        assert set(first["dispersed_3sigma"]["breaking_starts"]) == set(dispersed["deepest"]) == {"keep_out"}
        assert first["dispersed_violating_share"] == dispersed["violating_starts"] / TINY_DATA["N_EVAL"]
    assert first["eval_split"] == "search" and "test_split" not in first["datasets"]
    assert {k: first[k] for k in first["splits"]["search"]} == first["splits"]["search"]  # on top too
    assert {"effort_ratio", "delta_v_ratio", "mean_delta_v"} <= set(first)

    # --eval-split test: the same training scored on the sealed split, the search split kept beside it
    result = run(
        family / "train.py", "--seed", "3", "--run-id", "t", "--runs-log", str(log),
        "--out", str(tmp_path / "out_t"), "--eval-split", "test", cache=cache, check=True,
    )  # fmt: skip
    sealed = final_metric(result.stdout)
    assert sealed["eval_split"] == "test" and sealed["best_train_loss"] == first["best_train_loss"]
    assert sealed["splits"]["search"] == first["splits"]["search"]  # bit for bit: one training, both splits
    assert {k: sealed[k] for k in sealed["splits"]["test"]} == sealed["splits"][
        "test"
    ]  # the test split on top
    assert set(first["splits"]) == {"search"} and set(sealed["splits"]) == {"search", "test"}
    assert sealed[METRICS[name]] != first[METRICS[name]]  # 24 other starts
    assert sealed["datasets"] == {**first["datasets"], "test_split": sealed["datasets"]["test_split"]}


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
    held_out = train.evaluation_set(train.TASK, train.N_EVAL, problem=train.PROBLEM)
    if name == "rendezvous":
        metrics = train.evaluate(policy, held_out)
    else:
        metrics = train.evaluate(policy, held_out, record["config"]["RUNTIME_CBF_FILTER"])
    assert metrics[METRICS[name]] == record[METRICS[name]]

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
def test_the_report_figure_names_each_split_with_its_own_count(name, warm, tmp_path):
    """Issue 39, item 1: an audit run is scored on both splits; its figure must not print the test
    split's number beside the search split's count."""
    family, cache = warm[name]
    out = tmp_path / "out"
    args = ("--runs-log", str(tmp_path / "log"), "--out", str(out), "--eval-split", "test")
    record = final_metric(run(family / "train.py", *args, cache=cache, check=True).stdout)
    shown = run(
        family / "report.py",
        "--policy",
        str(out),
        "--out",
        str(tmp_path / "r.png"),
        "--starts",
        "1",
        cache=cache,
        check=True,
    ).stdout
    search, test = (record["splits"][split][METRICS[name]] for split in ("search", "test"))
    words = {"rendezvous": "mean terminal distance {:.3g} m", "docking": "score {:.3g}"}[name]
    assert f"{words.format(search)}" in shown and f"{words.format(test)}" in shown
    search_part, test_part = shown.split(": ", 2)[2].split("; ")
    assert search_part.startswith(words.format(search)) and search_part.endswith(
        "on the 12 search-split starts"
    )
    assert test_part.startswith(words.format(test)) and test_part.endswith(
        "on the 24 sealed test-split starts\n"
    )
    assert record["run_id"] not in shown  # an internal name the reader cannot look up (issue 59)


def test_a_report_figures_title_is_whole_and_its_starts_have_a_legend():
    """Issue 59: trajectories.png's title ran off both edges, showed a run id, and the five starts
    had no legend. The title wraps to whole lines; the legend names each start and both line styles."""
    from matplotlib.figure import Figure

    from cwh_envs.prepare import TITLE_WIDTH, legend_starts, policy_title

    train = type("Train", (), {"N_EVAL": 512, "N_TEST": 1024})
    record = {"run_id": "prune-096f4c29-s16", "splits": {"search": {"d": 0.607}, "test": {"d": 0.661}}}
    title = policy_title("Rendezvous", record, train, "mean terminal distance {d:.3g} m")
    assert "prune-096f4c29" not in title and len(title.splitlines()) == 2
    assert all(len(line) <= TITLE_WIDTH for line in title.splitlines())
    assert title.replace("\n", " ").endswith("0.661 m on the 1024 sealed test-split starts")
    ax = Figure().subplots()
    starts = np.array([[100.0, 0, 0, 0, 0, 0], [0, 300.0, 400.0, 0, 0, 0]])
    legend_starts(ax, starts, np.array([0.012, 1.5]), ["C0", "C1"])
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == [
        "start 1: 100 m out, ended 0.012 m off",
        "start 2: 500 m out, ended 1.5 m off",
        "policy (solid)",
        "expert (dashed)",
    ]


def test_a_saved_runs_scores_are_worded_per_split():
    train = type("Train", (), {"N_EVAL": 128, "N_TEST": 1024})
    record = {
        "loss": 1.848,
        "eval_split": "test",
        "splits": {"search": {"loss": 1.717}, "test": {"loss": 1.848}},
    }
    assert prepare.scored_per_split(record, train, "{loss:.3g} m") == (
        "1.72 m on the 128 search-split starts; 1.85 m on the 1024 sealed test-split starts"
    )
    assert (
        prepare.scored_per_split({"loss": 2.0}, train, "{loss:.3g} m") == "2 m on the 128 search-split starts"
    )


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


@pytest.mark.slow
@pytest.mark.parametrize("name", FAMILIES)
def test_the_family_scores_exactly_what_gym_make_flies(name, warm, tmp_path, monkeypatch):
    """One source of truth for the metric: each evaluation start flown alone through gym.make (the
    CBFSafetyFilter wrapper where the configuration flies the filter) ends where the family's batched
    evaluation says, to the bit: terminal distance, violation rate, clearance and success."""
    family, cache = warm[name]
    run(family / "train.py", "--runs-log", str(tmp_path / "log"), "--out", str(tmp_path / "out"), cache=cache)
    monkeypatch.setenv("CWH_ENVS_CACHE", str(cache))
    train = import_train(family / "train.py")
    policy, saved = train.load_policy(tmp_path / "out")
    held_out = train.evaluation_set(train.TASK, train.N_EVAL, problem=train.PROBLEM)
    cbf = saved["config"].get("RUNTIME_CBF_FILTER", False)
    flight = train.fly(policy, held_out.starts, held_out.goals, cbf) if name == "docking" else None
    flight = flight or train.fly(policy, held_out.starts)
    env_id = {"rendezvous": "CWHRendezvous-v0", "docking": "CWHDockKOZ-v1"}[name]
    envs, observations = [], []
    for start, goal in zip(held_out.starts, held_out.goals, strict=True):
        env = gym.make(env_id)
        env = cwh_envs.CBFSafetyFilter(env, margin=train.PROBLEM.margin) if cbf else env
        options = {"initial_state": start, **({"goal": goal} if name == "docking" else {})}
        envs.append(env)
        observations.append(env.reset(options=options)[0])
    for _ in range(train.PROBLEM.horizon):
        # One batched forward pass for every env, as the family's evaluation does: the network's
        # rounding is not what is compared here, the physics and the metric are.
        steps = [
            env.step(action) for env, action in zip(envs, policy.act(np.stack(observations)), strict=True)
        ]
        observations = [step[0] for step in steps]
    infos = [step[4] for step in steps]
    assert all(step[2] for step in steps)
    np.testing.assert_array_equal([i["terminal_distance"] for i in infos], flight.terminal_distance)
    np.testing.assert_array_equal([i["is_success"] for i in infos], flight.is_success)
    if name == "docking":
        np.testing.assert_array_equal([i["violation_rate"] for i in infos], flight.violation_rate)
        np.testing.assert_array_equal([i["min_clearance"] for i in infos], flight.min_clearance)
    metrics = train.evaluate(policy, held_out, cbf) if name == "docking" else train.evaluate(policy, held_out)
    assert metrics[METRICS[name]] == saved["record"][METRICS[name]]


def _flight(train, terminal_distance, *, violation=0.0, clearance=3.0, speed=0.0):
    """A docking Flight with the env's per-start outcomes given (ten starts unless arrays say)."""
    distance = np.asarray(terminal_distance, dtype=float)
    n, problem = len(distance), train.PROBLEM
    violation = np.broadcast_to(np.asarray(violation, dtype=float), n)
    clearance = np.broadcast_to(np.asarray(clearance, dtype=float), n)
    speed = np.broadcast_to(np.asarray(speed, dtype=float), n)
    success = (distance < problem.success_distance) & (speed < problem.success_speed) & (violation == 0)
    thrust = np.full((n, problem.horizon, 3), 0.1)
    return train.Flight(
        states=np.zeros((n, problem.horizon + 1, 6)),
        thrust=thrust,
        goals=np.zeros((n, 3)),
        terminal_distance=distance,
        terminal_speed=speed,
        is_success=success,
        violation_rate=violation,
        min_clearance=clearance,
    )


@pytest.mark.needs("families")
def test_docking_score_and_strict_gate():
    train = import_train(ROOT / "families" / "docking" / "train.py")
    horizon, n = train.PROBLEM.horizon, 10
    expert = np.full((n, horizon, 3), 0.2)

    def metrics(flight):
        return train.docking_metrics(flight, expert)

    perfect = _flight(train, np.zeros(n))
    assert metrics(perfect)["score"] == 0.0 and metrics(perfect)["success_rate"] == 1.0
    assert metrics(perfect)["strict_feasible"] is True
    assert (
        metrics(perfect)["effort_ratio"] == pytest.approx(0.25) and metrics(perfect)["delta_v_ratio"] == 0.5
    )

    grazing = _flight(train, np.zeros(n), clearance=[0.0] + [3.0] * (n - 1))  # on the sphere: no violation
    assert metrics(grazing)["strict_feasible"] is True

    two_steps = np.array([2 / horizon] + [0.0] * (n - 1))
    inside = _flight(train, np.zeros(n), violation=two_steps, clearance=[-1.0] + [3.0] * (n - 1))
    m = metrics(inside)
    assert m["violation_rate"] == pytest.approx(2 / horizon / n)
    assert m["score"] == pytest.approx(10.0 * 2 / horizon / n)
    assert m["min_clearance"] == -1.0 and m["violating_starts"] == 1
    assert m["success_rate"] == 0.9  # a violating start is never a success
    assert m["strict_feasible"] is False

    missed = _flight(train, [2.0] * 3 + [0.0] * (n - 3))  # three of ten 2 m off: success 0.7 < 0.8
    m = metrics(missed)
    assert m["violation_rate"] == 0.0 and m["min_clearance"] >= 0.0
    assert m["success_rate"] == pytest.approx(0.7) and m["strict_feasible"] is False
    assert m["score"] == pytest.approx(0.6)

    slow = _flight(train, np.zeros(n), speed=0.06)  # at the dock but too fast: not a success
    assert metrics(slow)["success_rate"] == 0.0

    # The graded constraints are the same gate: all <= 0 exactly when strict_feasible, and they say
    # by how much each case misses (family.json's constraints_field, read by the key-free arms).
    family = Family.load(ROOT / "families" / "docking")
    for case in (perfect, grazing, inside, missed, slow):
        graded = family.constraints(metrics(case))
        assert (
            (max(graded.values()) <= 0.0)
            is metrics(case)["strict_feasible"]
            is family.is_feasible(metrics(case))
        )
    assert family.constraints(metrics(missed))["success_shortfall"] == pytest.approx(0.1)
    assert family.constraints(metrics(inside))["clearance_deficit"] == pytest.approx(1.0)


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
    noise = family.seed_noise
    if noise is not None:
        assert noise["k"] >= 2 and len(noise["values"]) == noise["k"] and noise["std"] > 0
    if family.best is not None:
        family.space.validate_full(family.best["config"])
        promoted = family.ledger.current(family.best)["config"]  # where it came from (keys it predates aside)
        assert promoted == {k: family.best["config"][k] for k in promoted}
    # family.json is the registry: the declaration and the current best (with the training budget it
    # was certified under, if any), no measurement of the audit's
    assert "seed_noise" not in registry
    assert set(registry.get("best") or {}) <= {"config", "metric", "time_budget", "limits"}
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
