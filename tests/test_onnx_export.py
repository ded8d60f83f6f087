"""The audited policy as an ONNX artifact: families/<name>/export.py, cwh_envs.onnx_policy and
examples/fly_onnx.py, with real torch, onnx and onnxruntime.

A tiny policy is trained by a copy of each family's train.py (tiny data pools and budget, the real
search starts), exported by the copy's export.py and flown by fly_onnx.py. How close the two
flights can be: the graph is the same float32 function, but onnxruntime's matrix products and tanh
round differently from torch's (about 94 % of action components differ, by at most ~2e-7), and the
closed loop amplifies that over the horizon. Measured on the default recipes (seed 0; 128 search
and 1024 test starts): per start, terminal distances agree to 2e-6 relative on rendezvous (80
steps) but only to 1.5e-4 on docking (240 steps, CBF on), while the family metric, a mean over the
starts, agrees to 3e-7. So the tests hold the metric to 1e-5 relative for both families, the
per-start terminal distance to 1e-5 on rendezvous and 1e-3 on docking, and, the sharp check of the
export itself, the actions on the torch flight's own observations to 1e-6.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from extras import needs_module

from cwh_envs.datasets import evaluation_set
from cwh_envs.observations import docking_observation, rendezvous_observation
from cwh_envs.rollout import fly

onnx = needs_module("onnx", "onnx")
torch = needs_module("torch", "families")

from cwh_envs.onnx_policy import OnnxPolicy, action_difference, export_checked, export_policy  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
METRICS = {"rendezvous": "mean_terminal_distance", "docking": "score"}
PER_START_RTOL = {"rendezvous": 1e-5, "docking": 1e-3}  # see the module docstring
# Tiny data and budget; rendezvous also checks GELU (exported through Erf) and dropout (dropped in
# eval mode), docking the default tanh net with the run-time CBF on.
TINY = {
    "rendezvous": {"POOL_DEMOS": 8, "N_DEMOS": 4, "EPOCHS": 2, "ACTIVATION": '"gelu"', "DROPOUT": 0.2},
    "docking": {"POOL_DEMOS": 8, "POOL_RECOVERY": 4, "N_DEMOS": 4, "EPOCHS": 2},
}


def run(*args, cwd: Path) -> str:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    result = subprocess.run(
        [sys.executable, *map(str, args)], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr[-4000:]
    return result.stdout


def import_train(path: Path):
    spec = importlib.util.spec_from_file_location(f"onnx_test_train_{path.parent.name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> dict[str, tuple[Path, Path]]:
    """{family: (family copy, exported file)}: a tiny train.py run, then the copy's export.py."""
    made = {}
    for name, values in TINY.items():
        family = tmp_path_factory.mktemp(name) / name
        shutil.copytree(ROOT / "families" / name, family, ignore=shutil.ignore_patterns("runs.jsonl*", "out"))
        source = (family / "train.py").read_text()
        for key, value in values.items():
            source, count = re.subn(
                rf"^{key} = .*?(\s+#.*)?$", rf"{key} = {value}\1", source, count=1, flags=re.M
            )
            assert count == 1, key
        (family / "train.py").write_text(source)
        run(family / "train.py", "--out", "out", "--runs-log", "runs.jsonl", cwd=family)
        stdout = run(family / "export.py", "--policy", "out", "--onnx", "policy.onnx", cwd=family)
        summary = json.loads(stdout.split("EXPORTED: ", 1)[1])
        assert summary["task"] == name and summary["max_action_difference"] <= 1e-5
        made[name] = (family, family / "policy.onnx")
    return made


def observations(task: str, flight, horizon: int) -> np.ndarray:
    """Every observation the env showed along a flight, (H * N, d) float32."""
    n = len(flight.states)
    if task == "rendezvous":
        rows = [rendezvous_observation(flight.states[:, k], np.full(n, k), horizon) for k in range(horizon)]
    else:
        rows = [
            docking_observation(flight.states[:, k], flight.goals, np.full(n, k), horizon)
            for k in range(horizon)
        ]
    return np.concatenate(rows).astype(np.float32)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(TINY))
def test_onnx_flight_matches_the_torch_flight(name, exported):
    family, path = exported[name]
    train = import_train(family / "train.py")
    policy, saved = train.load_policy(family / "out")
    artifact = OnnxPolicy(path)
    meta = artifact.metadata
    assert meta["task"] == name and meta["problem"] == json.loads(json.dumps(train.PROBLEM.as_dict()))
    assert meta["config"] == saved["config"] and meta["record"]["run_id"] == saved["record"]["run_id"]
    cbf = name == "docking"  # the docking default recipe flies with the filter
    assert meta["runtime_cbf_filter"] is cbf and meta["cbf_margin"] == (train.PROBLEM.margin if cbf else None)
    assert artifact.obs_dim == train.OBS_DIM and not any(
        n.op_type == "Dropout" for n in onnx.load(path).graph.node
    )

    held_out = evaluation_set(train.TASK, train.N_EVAL, problem=train.PROBLEM)
    goals = held_out.goals if cbf else None
    margin = train.PROBLEM.margin if cbf else None
    torch_flight = fly(train.PROBLEM, policy.act, held_out.starts, goals, cbf_margin=margin)
    onnx_flight = fly(train.PROBLEM, artifact, held_out.starts, goals, cbf_margin=margin)
    # The export is the same function: on the torch flight's own observations, the same actions.
    seen = observations(train.TASK, torch_flight, train.PROBLEM.horizon)
    assert np.abs(artifact(seen) - policy.act(seen)).max() <= 1e-6
    np.testing.assert_allclose(
        onnx_flight.terminal_distance, torch_flight.terminal_distance, rtol=PER_START_RTOL[name], atol=0
    )
    # The family's own metric, as its train.py scores the torch policy and fly_onnx.py the file.
    reference = train.evaluate(policy, held_out, cbf) if cbf else train.evaluate(policy, held_out)
    assert reference[METRICS[name]] == saved["record"][METRICS[name]]
    flown = json.loads(run(ROOT / "examples" / "fly_onnx.py", "--family", name, path, cwd=family))
    assert (
        flown["n_starts"] == train.N_EVAL
        and flown["split"] == "search"
        and flown["runtime_cbf_filter"] is cbf
    )
    assert flown[METRICS[name]] == pytest.approx(reference[METRICS[name]], rel=1e-5)
    assert flown["success_rate"] == reference["success_rate"]
    if cbf:
        assert flown["violation_rate"] == pytest.approx(reference["violation_rate"], rel=1e-5, abs=1e-9)
        assert flown["cbf_active_rate"] == pytest.approx(
            reference["cbf_active_rate"], abs=1 / (train.N_EVAL * train.PROBLEM.horizon) + 1e-12
        )


@pytest.mark.slow
def test_docking_export_records_a_recipe_without_the_filter_and_fly_onnx_follows_it(exported, tmp_path):
    family, _ = exported["docking"]
    saved = torch.load(family / "out" / "policy.pt", weights_only=True)
    saved["config"] = {**saved["config"], "RUNTIME_CBF_FILTER": False}
    torch.save(saved, tmp_path / "policy.pt")
    run(family / "export.py", "--policy", tmp_path / "policy.pt", "--onnx", tmp_path / "off.onnx", cwd=family)
    meta = OnnxPolicy(tmp_path / "off.onnx").metadata
    assert meta["runtime_cbf_filter"] is False and meta["cbf_margin"] is None
    train = import_train(family / "train.py")
    policy, _ = train.load_policy(tmp_path / "policy.pt")
    reference = train.evaluate(policy, evaluation_set("docking", train.N_EVAL), False)
    flown = json.loads(
        run(ROOT / "examples" / "fly_onnx.py", "--family", "docking", tmp_path / "off.onnx", cwd=tmp_path)
    )
    assert flown["runtime_cbf_filter"] is False and "cbf_active_rate" not in flown
    assert flown["score"] == pytest.approx(reference["score"], rel=1e-5)
    # A file of the other task is refused, naming the mismatch.
    result = subprocess.run(
        [sys.executable, ROOT / "examples" / "fly_onnx.py", "--family", "rendezvous", tmp_path / "off.onnx"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode != 0 and "holds a 'docking' policy, not 'rendezvous'" in result.stderr


@pytest.mark.slow
def test_a_robust_filter_recipe_is_flown_through_the_robust_filter_by_fly_onnx(exported, tmp_path):
    """A recipe with ROBUST_FILTER_K > 0 records it, and fly_onnx.py flies the robust filter sized for
    the family's DISPERSIONS at that k: the family's own score of that recipe, not the nominal one's."""
    family, _ = exported["docking"]
    saved = torch.load(family / "out" / "policy.pt", weights_only=True)
    saved["config"] = {**saved["config"], "RUNTIME_CBF_FILTER": True, "ROBUST_FILTER_K": 3.0}
    torch.save(saved, tmp_path / "policy.pt")
    run(
        family / "export.py",
        "--policy",
        tmp_path / "policy.pt",
        "--onnx",
        tmp_path / "robust.onnx",
        cwd=family,
    )
    assert OnnxPolicy(tmp_path / "robust.onnx").metadata["robust_filter_k"] == 3.0
    train = import_train(family / "train.py")
    policy, _ = train.load_policy(tmp_path / "policy.pt")
    held_out = evaluation_set("docking", train.N_EVAL)
    robust = train.evaluate(policy, held_out, train.safety_filter(saved["config"]), dispersed=False)
    nominal = train.evaluate(policy, held_out, True, dispersed=False)
    assert robust["score"] != nominal["score"]
    flown = json.loads(
        run(ROOT / "examples" / "fly_onnx.py", "--family", "docking", tmp_path / "robust.onnx", cwd=tmp_path)
    )
    assert flown["robust_filter_k"] == 3.0
    assert flown["score"] == pytest.approx(robust["score"], rel=1e-5)


@pytest.mark.slow
@pytest.mark.needs("fast")
def test_docking_export_writes_a_compiled_policy_that_flies_as_the_torch_one(exported, tmp_path):
    """``export.py --compiled`` (cwh_envs.compiled_policy, numba): on the torch flight's own
    observations, the torch policy's actions to float32 rounding, and the family's metric."""
    from cwh_envs.compiled_policy import CompiledPolicy

    family, _ = exported["docking"]
    stdout = run(family / "export.py", "--policy", "out", "--compiled", tmp_path / "p.npz", cwd=family)
    summary = json.loads(stdout.split("COMPILED: ", 1)[1])
    assert "EXPORTED" not in stdout and summary["max_action_difference"] <= 1e-5
    train = import_train(family / "train.py")
    policy, saved = train.load_policy(family / "out")
    compiled = CompiledPolicy.load(tmp_path / "p.npz")
    assert compiled.metadata["config"] == saved["config"] and compiled.metadata["runtime_cbf_filter"] is True
    assert (
        compiled.metadata["policy_sha256"]
        == hashlib.sha256((family / "out" / "policy.pt").read_bytes()).hexdigest()
    )
    held_out = evaluation_set(train.TASK, train.N_EVAL, problem=train.PROBLEM)
    flight = fly(train.PROBLEM, policy.act, held_out.starts, held_out.goals, cbf_margin=train.PROBLEM.margin)
    seen = observations(train.TASK, flight, train.PROBLEM.horizon)
    assert np.abs(compiled(seen) - policy.act(seen)).max() <= 1e-5
    assert train.evaluate(compiled, held_out, True, dispersed=False)["score"] == pytest.approx(
        saved["record"]["score"], rel=1e-5
    )
    result = subprocess.run(
        [sys.executable, family / "export.py", "--policy", "out"], cwd=family, capture_output=True, text=True
    )
    assert result.returncode != 0 and "give --onnx, --compiled or both" in result.stderr


def test_export_policy_standardises_clips_and_keeps_metadata(tmp_path):
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.Tanh(), torch.nn.Linear(8, 3))
    with torch.no_grad():
        net[2].weight.mul_(10.0)  # large outputs, so the clip binds
    mean, std = torch.tensor([1.0, -2.0, 0.5, 0.0]), torch.tensor([2.0, 0.5, 1.0, 4.0])
    path = export_policy(net, mean, std, tmp_path / "p.onnx", {"task": "toy", "margin": 0.5, "on": True})
    policy = OnnxPolicy(path)
    assert policy.metadata == {"task": "toy", "margin": 0.5, "on": True} and policy.obs_dim == 4

    def act(obs):
        with torch.no_grad():
            return np.clip(net((torch.as_tensor(obs) - mean) / std).double().numpy(), -1.0, 1.0)

    obs = np.random.default_rng(0).normal(size=(257, 4)).astype(np.float32)  # any batch size
    actions = policy(obs)
    assert actions.shape == (257, 3) and actions.dtype == np.float64
    assert np.abs(actions).max() == 1.0 and (np.abs(actions) == 1.0).mean() > 0.2
    # float32 rounding of outputs up to ~10 before the clip
    assert np.abs(actions - act(obs)).max() <= 1e-5
    assert action_difference(act, policy, mean, std) <= 1e-5
    assert action_difference(lambda o: act(o) * 0.5, policy, mean, std) > 0.1  # the check can fail


def test_export_checked_stamps_the_source_and_deletes_a_file_that_flies_differently(tmp_path):
    torch.manual_seed(0)

    class Policy(torch.nn.Sequential):  # a family Policy's interface: statistics and act
        obs_mean, obs_std = np.zeros(4), np.ones(4)

        def act(self, obs):
            with torch.no_grad():
                return np.clip(self(torch.as_tensor(obs, dtype=torch.float32)).double().numpy(), -1, 1)

    policy = Policy(torch.nn.Linear(4, 3))
    source = tmp_path / "policy.pt"
    torch.save(policy.state_dict(), source)
    summary = export_checked(
        policy, tmp_path / "p.onnx", {"task": "toy", "runtime_cbf_filter": False}, source
    )
    assert summary["task"] == "toy" and summary["max_action_difference"] <= 1e-5
    stamped = OnnxPolicy(tmp_path / "p.onnx").metadata
    assert stamped["policy_sha256"] == hashlib.sha256(source.read_bytes()).hexdigest()
    assert stamped["torch"] == torch.__version__

    drifting = Policy(torch.nn.Linear(4, 3))
    drifting.act = lambda obs: Policy.act(drifting, obs) + 0.1  # flies differently from its graph
    with pytest.raises(ValueError, match=r"differs from the torch policy by 0\.1 "):
        export_checked(drifting, tmp_path / "q.onnx", {"task": "toy"}, source)
    assert not (tmp_path / "q.onnx").exists()


def test_onnx_policy_refuses_a_graph_that_is_not_an_exported_policy(tmp_path):
    from onnx import TensorProto, helper

    graph = helper.make_graph(
        [helper.make_node("Relu", ["x"], ["y"])],
        "other",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [None, 3])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [None, 3])],
    )
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), tmp_path / "other.onnx")
    with pytest.raises(ValueError, match="not an exported policy"):
        OnnxPolicy(tmp_path / "other.onnx")


def test_importing_the_onnx_helper_imports_neither_torch_nor_onnx():
    code = "import sys, cwh_envs.onnx_policy; print(sorted(m for m in ('torch', 'onnx', 'onnxruntime') if m in sys.modules))"
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert result.stdout.strip() == "[]"
