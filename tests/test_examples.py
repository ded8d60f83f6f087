"""The examples end to end at their smallest budgets, as a reader would run them (a subprocess each).

The behaviour-cloned policies come from tmp copies of the family train.py with tiny editable
values (N_DEMOS, EPOCHS); the data pools and held-out starts are built once per test run into the
run's private cache (tests/conftest.py): about 10 s, what a cold run pays for, not the tiny budget.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
TINY_BC = {"N_DEMOS": 4, "EPOCHS": 2}
METRICS = {"rendezvous": "mean_terminal_distance", "docking": "score"}
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg"}


def run(script: str, *args: str, cwd: Path) -> str:
    result = subprocess.run(
        [sys.executable, str(EXAMPLES / script), *map(str, args)],
        cwd=cwd,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-4000:]
    return result.stdout


def table_rows(text: str) -> list[list[str]]:
    """The body rows of every markdown table in ``text``, as lists of stripped cells."""
    rows = [line.strip("|").split("|") for line in text.splitlines() if line.startswith("| ")]
    return [[cell.strip() for cell in row] for row in rows if not set(row[0]) <= {"-", ":"}][1:]


def assert_png(path: Path) -> None:
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 10_000, path


@pytest.fixture(scope="module")
def bc_policies(tmp_path_factory) -> dict[str, Path]:
    """{family: out dir} of a tiny behaviour-cloning run of each family's train.py (a patched copy)."""
    made = {}
    for family in ("rendezvous", "docking"):
        where = tmp_path_factory.mktemp(f"bc_{family}")
        source = (ROOT / "families" / family / "train.py").read_text()
        for name, value in TINY_BC.items():
            source, count = re.subn(rf"^{name} = \S+", f"{name} = {value}", source, count=1, flags=re.M)
            assert count == 1, name
        (where / "train.py").write_text(source)
        subprocess.run(
            [sys.executable, "train.py", "--out", "out", "--runs-log", "runs.jsonl"],
            cwd=where,
            env=ENV,
            check=True,
            capture_output=True,
            timeout=300,
        )
        made[family] = where / "out"
    return made


def test_quickstart(tmp_path):
    stdout = run("quickstart.py", "--out", tmp_path / "out", cwd=tmp_path)
    rows = {(row[0], row[1]): row for row in table_rows(stdout)}
    assert set(rows) == {
        (env, policy) for env in ("CWHRendezvous-v0", "CWHDockKOZ-v1") for policy in ("expert", "random")
    }
    for env in ("CWHRendezvous-v0", "CWHDockKOZ-v1"):
        assert float(rows[env, "expert"][2]) < 1e-6 and rows[env, "expert"][4] == "True"
        assert float(rows[env, "random"][2]) > 1.0 and rows[env, "random"][4] == "False"
        for policy in ("expert", "random"):
            assert_png(tmp_path / "out" / f"{env}_{policy}.png")
    assert rows["CWHDockKOZ-v1", "expert"][5] == "0.0%"


@pytest.mark.parametrize(
    ("args", "violations"),
    [
        (["--env", "docking", "--policy", "pd", "--cbf"], True),
        (["--env", "rendezvous", "--policy", "random"], False),
    ],
)
def test_vector_rollout(tmp_path, args, violations):
    stdout = run("vector_rollout.py", "--num-envs", 64, "--episodes", 1, *args, cwd=tmp_path)
    rate = float(re.search(r"([\d,]+) env-steps/s", stdout)[1].replace(",", ""))
    episodes = int(re.search(r"(\d+) episodes:", stdout)[1])
    success = float(re.search(r"success ([\d.]+)%", stdout)[1])
    assert rate > 1000 and episodes == 64 and 0 <= success <= 100
    assert ("keep-out: violation rate" in stdout) == violations


@pytest.mark.slow
@pytest.mark.parametrize("family", ["rendezvous", "docking"])
def test_fly_policy(tmp_path, bc_policies, family):
    stdout = run(
        "fly_policy.py",
        "--family",
        family,
        "--policy",
        bc_policies[family],
        "--plot",
        2,
        "--out",
        tmp_path,
        cwd=tmp_path,
    )
    rows = table_rows(stdout)
    assert [row[0] for row in rows] == (["policy"] if family == "rendezvous" else ["policy", "policy + CBF"])
    for row in rows:
        assert math.isfinite(float(row[1])) and float(row[1]) >= 0
        assert 0 <= float(row[2].rstrip("%")) <= 100
    if family == "docking":  # the filter keeps the margin wherever the barrier is feasible
        assert float(rows[1][3].rstrip("%")) <= float(rows[0][3].rstrip("%"))
    assert_png(tmp_path / f"fly_{family}.png")


@pytest.mark.slow
def test_sb3_compare_smoke(tmp_path, bc_policies):
    out = tmp_path / "out"
    bc = [f"--bc-policy={family}={path}" for family, path in bc_policies.items()]
    tensorboard = ["--tensorboard", tmp_path / "tb"]  # logs if tensorboard is installed, else a note
    stdout = run(
        "sb3_compare.py", "--smoke", "--eval-points", 2, "--out", out, *bc, *tensorboard, cwd=tmp_path
    )
    methods = ["expert (open loop)", "PD law", "BC", "PPO", "SAC"]
    expected = [
        (problem, method) for problem in ("rendezvous", "docking", "docking+cbf") for method in methods
    ]
    markdown = (out / "results.md").read_text()
    assert markdown in stdout
    assert "[tensorboard] not installed" in stdout or any((tmp_path / "tb").iterdir())
    assert [(row[0], row[1]) for row in table_rows(markdown)] == expected
    assert_png(out / "metric_vs_wallclock.png")
    rows = {(row["problem"], row["method"]): row for row in json.loads((out / "results.json").read_text())}
    for (problem, method), row in rows.items():
        metrics = row["metrics"]
        assert math.isfinite(row["train_seconds"]) and row["train_seconds"] >= 0
        assert math.isfinite(metrics[row["metric"]]) and metrics[row["metric"]] >= 0
        assert 0 <= metrics["success_rate"] <= 1
        if problem != "rendezvous":
            assert 0 <= metrics["violation_rate"] <= 1
        if method in ("PPO", "SAC"):
            assert (
                row["curve"][-1]["timesteps"] >= 512
                and (out / "models" / f"{method.lower()}_{problem}.zip").exists()
            )
    # The expert flown open-loop through the family code lands on its targets; with the filter the
    # barrier may nudge it, but never into the keep-out.
    assert rows["rendezvous", "expert (open loop)"]["metrics"]["mean_terminal_distance"] < 1e-6
    assert rows["docking", "expert (open loop)"]["metrics"]["score"] < 1e-6
    assert rows["docking+cbf", "expert (open loop)"]["metrics"]["min_clearance"] >= 0
    # The PD law (in newtons, on the same observations) docks nearly every start through the filter.
    assert rows["docking+cbf", "PD law"]["metrics"]["success_rate"] > 0.9
    # The same code as the family: the BC rows reproduce each run's own FINAL_METRIC.
    for family in ("rendezvous", "docking"):
        record = json.loads((bc_policies[family].parent / "runs.jsonl").read_text())
        problem = "docking+cbf" if record["config"].get("RUNTIME_CBF_FILTER") else family
        assert rows[problem, "BC"]["metrics"][METRICS[family]] == pytest.approx(
            record[METRICS[family]], rel=1e-9
        )


@pytest.mark.slow
@pytest.mark.needs("sb3")
def test_a_smoke_run_never_overwrites_the_committed_results(tmp_path):
    """Issue 39, item 8: without --out a smoke run writes runs/sb3_compare_smoke, never results/."""
    smallest = ["--algos", "ppo", "--problems", "rendezvous", "--eval-points", 1]
    stdout = run("sb3_compare.py", "--smoke", *smallest, cwd=tmp_path)
    assert "wrote runs/sb3_compare_smoke/results.md" in stdout
    assert (tmp_path / "runs" / "sb3_compare_smoke" / "results.json").is_file()
    assert not (tmp_path / "results").exists()


@pytest.mark.slow
def test_sb3_compare_learns_the_same_on_the_native_adapter_and_on_dummy_vec_env(tmp_path, bc_policies):
    """Same seeds, same start pool: the adapter and DummyVecEnv give SB3 identical transitions, so
    PPO and SAC end with identical policies, to the last bit of the family metric."""
    rows = {}
    for vec_env in ("native", "dummy"):
        out = tmp_path / vec_env
        run(
            "sb3_compare.py",
            "--smoke",
            "--eval-points",
            1,
            "--problems",
            "docking+cbf",
            "--vec-env",
            vec_env,
            f"--bc-policy=docking={bc_policies['docking']}",
            "--out",
            out,
            cwd=tmp_path,
        )
        results = json.loads((out / "results.json").read_text())
        rows[vec_env] = {row["method"]: row["metrics"] for row in results if row["method"] in ("PPO", "SAC")}
        assert (
            f"SB3 trained on {'cwh_envs.sb3.NativeVecEnv' if vec_env == 'native' else 'DummyVecEnv'}"
            in (out / "results.md").read_text()
        )
    assert set(rows["native"]) == {"PPO", "SAC"}
    assert rows["native"] == rows["dummy"]


@pytest.fixture
def one_torch_thread():
    """As sb3_compare runs torch: two threads on two busy cores make these tiny nets ~10x slower."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.mark.needs("sb3")
def test_sb3_policy_batch_matches_the_env(one_torch_thread):
    """An SB3 model scored by the family's batch evaluation (sb3_compare's path) flies exactly as it
    does through the env itself: the native vector env with the CBF, from the same starts."""
    spec = importlib.util.spec_from_file_location("sb3_compare", EXAMPLES / "sb3_compare.py")
    compare = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(compare)
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    family = compare.load_family("docking")
    train_envs = VecNormalize(make_vec_env("cwh_envs:CWHDockKOZ-v1", n_envs=2, seed=0))
    model = PPO("MlpPolicy", train_envs, n_steps=64, batch_size=64, n_epochs=1, seed=0)
    model.learn(128)  # a moved policy and moved normalisation statistics
    evaluate = compare.EvalSet(family, cbf=True)
    evaluate.held_out = evaluate.held_out.take(16)
    evaluate.starts, evaluate.goals = evaluate.held_out.starts, evaluate.held_out.goals
    metrics = evaluate(compare.SB3Policy(model))

    envs = gym.make_vec(
        "cwh_envs:CWHDockKOZ-v1", num_envs=16, vectorization_mode="vector_entry_point", cbf_margin=0.5
    )
    obs, _ = envs.reset(seed=0, options={"initial_state": evaluate.starts, "goal": evaluate.goals})
    for _ in range(family.PROBLEM.horizon):
        action, _ = model.predict(train_envs.normalize_obs(obs), deterministic=True)
        obs, _, terminated, _, info = envs.step(action)
    assert terminated.all()
    # The same core steps both (cwh_envs.rollout): equal, not merely close.
    assert metrics["mean_terminal_distance"] == float(info["terminal_distance"].mean())
    assert metrics["violation_rate"] == float(info["violation_rate"].mean())
    assert metrics["success_rate"] == float(np.mean(info["is_success"]))


def test_baselines_fly_every_controller_through_gym_make(tmp_path):
    """examples/baselines.py: MPC lands on both envs and keeps the keep-out; the closed-form law
    lands on rendezvous too, and on docking through the filter without entering the keep-out."""
    rows = {(row[0], row[1]): row for row in table_rows(run("baselines.py", "--seed", 3, cwd=tmp_path))}
    assert len(rows) == 6
    for env_id in ("CWHRendezvous-v0", "CWHDockKOZ-v1"):
        mpc = rows[(env_id, "MPC")]
        assert float(mpc[2]) < 1e-5 and mpc[3] == "True" and abs(float(mpc[5]) - 1) < 1e-3
    assert rows[("CWHDockKOZ-v1", "closed-form feedback + CBF")][4] == "0.0%"
    assert rows[("CWHDockKOZ-v1", "MPC")][4] == "0.0%"
