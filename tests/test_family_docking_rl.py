"""Issue 60, item 3: families/docking-rl, SB3 PPO (optionally residual) on the docking problem,
follows the family contract and is scored as its behaviour-cloning sibling families/docking is.

The runs work on a copy of the family with tiny splits and start pool (plain text replacement in the
fixed part, the loop's own patcher in the editable region) against the session's private cache, so
that a real PPO run trains and is scored in seconds.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from autoresearch.editable import patch, read_region
from autoresearch.execution.protocol import parse_progress
from autoresearch.family import Family, family_problems
from autoresearch.space import ValidationError

ROOT = Path(__file__).resolve().parents[1]
FAMILY = ROOT / "families" / "docking-rl"
SIBLING = ROOT / "families" / "docking"
TINY_DATA = {"N_EVAL": 12, "N_TEST": 24, "START_POOL": 256}
TINY_RUN = {"N_ENVS": 2, "N_STEPS": 64, "BATCH_SIZE": 64, "N_EPOCHS": 2, "HIDDEN_DIM": 16}
BUDGET_VARIABLE = "AUTORESEARCH_TIME_BUDGET"


def load_train(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def family_copy(where: Path, **values) -> Path:
    """A copy of the family with tiny data in the fixed part and ``values`` in the editable region."""
    target = where / "docking-rl"
    shutil.copytree(FAMILY, target, ignore=shutil.ignore_patterns("runs.jsonl*", "out", "__pycache__"))
    source = (target / "train.py").read_text()
    for name, value in TINY_DATA.items():
        source, count = re.subn(rf"^{name} = \d+", f"{name} = {value}", source, count=1, flags=re.M)
        assert count == 1, name
    (target / "train.py").write_text(patch(source, values))
    return target


def run(script: Path, *args: str, budget: float | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONDONTWRITEBYTECODE": "1"}
    env.pop(BUDGET_VARIABLE, None)
    if budget is not None:
        env[BUDGET_VARIABLE] = str(budget)
    return subprocess.run(
        [sys.executable, str(script), *args],
        cwd=script.parent,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def final_metric(stdout: str) -> dict:
    lines = [line for line in stdout.splitlines() if line.startswith("FINAL_METRIC: ")]
    assert len(lines) == 1, stdout
    return json.loads(lines[0].removeprefix("FINAL_METRIC: "))


@pytest.fixture(scope="module")
def rl():
    return load_train(FAMILY / "train.py", "docking_rl_train_under_test")


@pytest.fixture(scope="module")
def sibling():
    return load_train(SIBLING / "train.py", "docking_bc_train_beside_rl")


def test_the_family_passes_the_contract_check_and_poses_the_siblings_problem():
    assert family_problems(FAMILY) == []
    family, docking = Family.load(FAMILY), Family.load(SIBLING)
    assert family.name == "docking-rl" and family.has_test_split
    for field in ("metric", "metric_label", "direction", "target", "feasibility_field", "constraints_field"):
        assert getattr(family, field) == getattr(docking, field), field
    for field in ("split_ids", "tails", "time_budget"):  # the same sealed starts, tails and budget
        assert family.registry[field] == docking.registry[field], field
    for name in ("fuel", "robust"):
        assert family.registry["protocols"][name] == docking.registry["protocols"][name]
    assert family.registry["baseline"]["metric"] is None  # measured by a campaign, not assumed
    # its best is only what an audit promoted: the TPE arm's reseeded recipe (results/rl-family)
    verify = json.loads((ROOT / "results/rl-family/docking-rl-tpe/audit.json").read_text())["verify"]
    promoted = next(c for c in verify["candidates"] if c["config_id"] == verify["promoted"])
    assert family.best["config"] == promoted["config"] and family.best["time_budget"] == 300
    source = (FAMILY / "train.py").read_text()  # it stands alone: no other family's code, no path tricks
    imported = re.findall(r"^(?:from|import) (\S+)", source, re.M)
    assert imported and not {m.split(".")[0] for m in imported} & {"families", "train", "tests"}
    assert "sys.path" not in source and "import_module" not in source


def test_the_loop_refuses_values_outside_the_search_space_by_name():
    family = Family.load(FAMILY)
    for name, value in {"GAMMA": 1.5, "POLICY_FORM": "hybrid", "N_ENVS": 5, "RESIDUAL_SCALE": 3.0}.items():
        with pytest.raises(ValidationError, match=name):
            family.space.validate_full({**family.baseline_config, name: value})


@pytest.mark.needs("families", "sb3")
def test_the_baseline_is_the_zoo_default_row_of_sb3_compare(rl):
    compare = load_train(ROOT / "examples" / "sb3_compare.py", "sb3_compare_beside_rl")
    zoo = compare.HYPERPARAMS["ppo"]["docking"]
    config = Family.load(FAMILY).baseline_config
    names = {
        "N_ENVS": "n_envs",
        "N_STEPS": "n_steps",
        "BATCH_SIZE": "batch_size",
        "GAMMA": "gamma",
        "GAE_LAMBDA": "gae_lambda",
        "N_EPOCHS": "n_epochs",
        "ENT_COEF": "ent_coef",
        "LEARNING_RATE": "learning_rate",
        "CLIP_RANGE": "clip_range",
        "MAX_GRAD_NORM": "max_grad_norm",
        "USE_SDE": "use_sde",
        "SDE_SAMPLE_FREQ": "sde_sample_freq",
    }
    assert {name: config[name] for name in names} == {name: zoo[key] for name, key in names.items()}
    policy = zoo["policy_kwargs"]
    assert config["LOG_STD_INIT"] == policy["log_std_init"] and rl.ORTHO_INIT == policy["ortho_init"]
    assert rl.ACTIVATIONS[config["ACTIVATION"]] is policy["activation_fn"]
    assert [config["HIDDEN_DIM"]] * config["N_LAYERS"] == policy["net_arch"]
    assert config["NORMALIZE_REWARD"] == zoo["normalize"]["norm_reward"] and zoo["normalize"]["norm_obs"]
    assert not config["LR_ANNEAL"] and config["POLICY_FORM"] == "direct" and config["RUNTIME_CBF_FILTER"]


@pytest.mark.needs("families", "sb3")
def test_it_is_scored_on_the_docking_familys_splits_with_its_metric(rl, sibling):
    from cwh_envs import splits
    from cwh_envs.datasets import evaluation_set

    pinned = Family.load(FAMILY).registry["split_ids"]
    for split, n in (("search", rl.N_EVAL), ("test", rl.N_TEST)):
        shipped = splits.shipped_split(rl.TASK, rl.PROBLEM, split)
        assert splits.split_identity(*shipped.first(n)) == pinned[split]
    for name in ("TASK", "METRIC", "PROBLEM", "N_EVAL", "N_TEST", "VIOLATION_WEIGHT", "SUCCESS_GATE"):
        assert getattr(rl, name) == getattr(sibling, name), name
    for name in ("RUNAWAY_DISTANCE", "DISPERSIONS", "DISPERSION_SEED", "STRESS_SCALE", "N_PROGRESS"):
        assert getattr(rl, name) == getattr(sibling, name), name
    # The same flights scored by both families' code: every field, the Monte Carlo auxiliary included.
    held_out = evaluation_set(rl.TASK, 4, problem=rl.PROBLEM, split="search")
    law = rl.base_law()

    class Flown:
        act = staticmethod(law)

    for cbf in (True, False):
        safety = rl.safety_filter({"RUNTIME_CBF_FILTER": cbf})
        assert safety == sibling.safety_filter({"RUNTIME_CBF_FILTER": cbf, "ROBUST_FILTER_K": 0.0})
        mine = rl.evaluate(law, held_out, safety)
        assert mine == sibling.evaluate(Flown(), held_out, safety)
        assert mine[rl.METRIC] == pytest.approx(mine["mean_terminal_distance"] + 10 * mine["violation_rate"])


@pytest.mark.needs("families", "sb3")
@pytest.mark.parametrize("form", ["residual", "direct"])
def test_the_residual_form_starts_flying_the_law_and_the_direct_one_does_not(rl, form, monkeypatch):
    from cwh_envs.datasets import start_pool

    monkeypatch.setattr(rl, "START_POOL", TINY_DATA["START_POOL"])
    config = {name: getattr(rl, name) for name in rl.CONFIG_NAMES} | {"POLICY_FORM": form, **TINY_RUN}
    envs = rl.training_envs(config, seed=0)
    model = rl.build_model(config, envs, 0, rl.LearningRate(config, rl.Budget(None)))
    pool = start_pool(rl.TASK, 8, rl.PROBLEM)
    safety = rl.safety_filter(config)
    flown = rl.fly(rl.flown_policy(config, model, envs), pool.starts, pool.goals, safety)
    law = rl.fly(rl.base_law(), pool.starts, pool.goals, safety)
    mean_layer = model.policy.action_net
    if form == "residual":
        assert not mean_layer.weight.any() and not mean_layer.bias.any()
        np.testing.assert_array_equal(flown.thrust, law.thrust)
        np.testing.assert_array_equal(flown.terminal_distance, law.terminal_distance)
    else:
        assert mean_layer.weight.any()
        assert not np.array_equal(flown.thrust, law.thrust)
    envs.close()


@pytest.mark.needs("families", "sb3")
def test_the_budget_cuts_inside_a_long_update(rl, monkeypatch):
    monkeypatch.setattr(rl, "START_POOL", TINY_DATA["START_POOL"])
    # One rollout of 128 steps, then an update of 100,000 epochs x 2 minibatches: minutes, uncut.
    config = {name: getattr(rl, name) for name in rl.CONFIG_NAMES} | {**TINY_RUN, "TOTAL_TIMESTEPS": 128}
    config["N_EPOCHS"] = 100_000
    budget = rl.Budget(3.0)
    envs = rl.training_envs(config, seed=0)
    model = rl.build_model(config, envs, 0, rl.LearningRate(config, budget))
    before = [p.detach().clone() for p in model.policy.parameters()]
    supervisor = rl.learn(model, config, budget, report=lambda step: None)
    seconds = time.perf_counter() - budget.started
    assert budget.exhausted and 3.0 <= seconds < 30.0
    assert model.num_timesteps == 128 and supervisor.rollouts == 1  # cut in the update, not the rollout
    import torch

    after = list(model.policy.parameters())
    assert any(not torch.equal(a, b) for a, b in zip(before, after, strict=True))  # it kept its steps
    envs.close()


@pytest.mark.needs("families", "sb3")
def test_the_annealed_rate_reaches_zero_at_whichever_end_of_the_run_comes_first(rl):
    budget = rl.Budget(100.0)
    rate = rl.LearningRate({"LEARNING_RATE": 1e-3, "LR_ANNEAL": True}, budget)
    assert rate(1.0) == 1e-3  # SB3 builds its optimiser before the clock starts
    assert rate(0.25) == pytest.approx(2.5e-4)  # the steps are the nearer end
    budget.start()
    budget.started -= 60.0  # 60 % of the budget spent: the clock is the nearer end
    assert rate(0.9) == pytest.approx(4e-4, rel=1e-3) and rate(0.25) == pytest.approx(2.5e-4)
    budget.started -= 100.0
    assert rate(0.9) == 0.0
    assert rl.LearningRate({"LEARNING_RATE": 1e-3, "LR_ANNEAL": False}, budget)(0.1) == 1e-3


@pytest.mark.needs("families", "sb3")
def test_bad_editable_values_are_refused_by_name_before_anything_runs(tmp_path, rl, monkeypatch):
    bad = {"GAMMA": 1.5, "POLICY_FORM": "hybrid", "BATCH_SIZE": 1, "RESIDUAL_SCALE": 3.0, "USE_SDE": 1}
    family = family_copy(tmp_path, **bad)
    log = tmp_path / "runs.jsonl"
    result = run(family / "train.py", "--runs-log", str(log), "--out", str(tmp_path / "out"))
    assert result.returncode != 0 and "FINAL_METRIC" not in result.stdout
    assert "invalid configuration" in result.stderr
    assert all(name in result.stderr for name in bad), result.stderr
    assert not log.exists() and not (tmp_path / "out").exists()
    for text in ("-5", "soon"):
        monkeypatch.setenv(BUDGET_VARIABLE, text)
        with pytest.raises(SystemExit, match=BUDGET_VARIABLE):
            rl.Budget.from_environment()


@pytest.mark.needs("families", "sb3")
def test_prepare_check_names_the_missing_sets_builds_nothing_and_passes_once_warm(tmp_path):
    family = family_copy(tmp_path)
    cache = tmp_path / "cache"
    env = {**os.environ, "CWH_ENVS_CACHE": str(cache), "PYTHONDONTWRITEBYTECODE": "1"}

    def prepare(mode: str) -> subprocess.CompletedProcess:
        command = [sys.executable, "prepare.py", mode]
        return subprocess.run(command, cwd=family, env=env, capture_output=True, text=True, timeout=300)

    cold = prepare("--check")
    assert cold.returncode == 1
    assert all(part in cold.stderr for part in ("search split", "test split", "start pool", "missing"))
    assert not cache.exists() or not any(cache.iterdir()), "--check must not build anything"
    warm = prepare("--warm-cache")
    assert warm.returncode == 0, warm.stderr
    assert warm.stdout.index("to build: 3 of 3 data sets") < warm.stdout.index("ready:")
    assert prepare("--check").returncode == 0


@pytest.mark.slow
@pytest.mark.needs("families", "sb3")
def test_a_budgeted_run_is_cut_by_the_clock_and_writes_the_docking_record_on_both_splits(tmp_path):
    family = family_copy(tmp_path, TOTAL_TIMESTEPS=5_000_000, **TINY_RUN)
    log, out = tmp_path / "runs.jsonl", tmp_path / "out"
    result = run(
        family / "train.py",
        *("--run-id", "cut", "--seed", "3", "--runs-log", str(log), "--out", str(out)),
        *("--eval-split", "test"),
        budget=3,
    )
    assert result.returncode == 0, result.stderr
    record = final_metric(result.stdout)
    assert [json.loads(line) for line in log.read_text().splitlines()] == [record]
    assert record["run_id"] == "cut" and record["seed"] == 3 and record["eval_split"] == "test"
    assert record["config"] == read_region((family / "train.py").read_text()).values()
    assert record["time_budget"] == 3.0 and record["budget_exhausted"] is True
    assert 3.0 <= record["train_seconds"] and 0 < record["env_steps"] < 5_000_000
    assert record["rollouts"] >= 1 and record["n_params"] > 0
    assert set(record["splits"]) == {"search", "test"} == set(record["split_ids"])
    assert {key: record[key] for key in record["splits"]["test"]} == record["splits"]["test"]
    for split, n in (("search", TINY_DATA["N_EVAL"]), ("test", TINY_DATA["N_TEST"])):
        metrics = record["splits"][split]
        assert metrics["score"] == pytest.approx(
            metrics["mean_terminal_distance"] + 10 * metrics["violation_rate"]
        )
        assert isinstance(metrics["strict_feasible"], bool)
        assert set(metrics["constraints"]) == {"success_shortfall", "violation_rate", "clearance_deficit"}
        for field in ("success_rate", "runaway_share", "max_terminal_distance", "effort_ratio"):
            assert np.isfinite(metrics[field]), field
        assert metrics["dispersed"]["dispersions"] and metrics["dispersed_3sigma"]["dispersions"]
        violating = metrics["dispersed"]["violating_starts"]
        assert metrics["dispersed_violating_share"] == pytest.approx(violating / n)
    points = [parse_progress(line, "score") for line in result.stdout.splitlines()]
    steps = [point["step"] for point in points if point is not None]
    assert steps[-1] == 100 and steps == sorted(set(steps)) and set(steps) <= {25, 50, 75, 100}
    assert {path.name for path in out.iterdir()} == {"model.zip", "vecnormalize.pkl", "run.json"}
    assert json.loads((out / "run.json").read_text())["record"] == record
    # Loaded as the leaderboard loads it, the saved agent flies the sealed starts to the record's score.
    trained = load_train(family / "train.py", "docking_rl_copy_reloaded")
    agent, saved = trained.load_policy(out)
    assert saved["record"] == record and saved["config"] == record["config"]
    test = trained.evaluation_set(trained.TASK, trained.N_TEST, problem=trained.PROBLEM, split="test")
    reflown = trained.evaluate(agent.act, test, trained.safety_filter(saved["config"]), dispersed=False)
    assert reflown["score"] == pytest.approx(record["splits"]["test"]["score"], rel=1e-12, abs=1e-15)


@pytest.mark.slow
@pytest.mark.needs("families", "sb3")
def test_without_a_budget_a_run_trains_its_steps_and_the_same_seed_gives_the_same_record(tmp_path):
    family = family_copy(tmp_path, TOTAL_TIMESTEPS=128, **TINY_RUN)  # one rollout of 2 envs x 64 steps
    log = tmp_path / "runs.jsonl"
    records = []
    for i in range(2):
        out = str(tmp_path / f"out{i}")
        result = run(family / "train.py", "--run-id", f"r{i}", "--runs-log", str(log), "--out", out)
        assert result.returncode == 0, result.stderr
        records.append(final_metric(result.stdout))
    first, second = records
    assert first["env_steps"] == 128 and first["rollouts"] == 1 and first["eval_split"] == "search"
    assert "time_budget" not in first and "budget_exhausted" not in first
    assert set(first["splits"]) == {"search"} == set(first["split_ids"])
    assert first["score"] == second["score"] and first["splits"] == second["splits"]
    assert [json.loads(line)["run_id"] for line in log.read_text().splitlines()] == ["r0", "r1"]
