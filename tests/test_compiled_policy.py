"""cwh_envs.compiled_policy (issue 58's compute target) and the docking families' ``export.py
--compiled``: the compiled policy is the torch policy's function in every form (the MLP alone, the
goal law's residual, the route's, with its correction switched off past the last waypoint), on
every step to go and on the docking axis itself; with no correction it is the closed-form law; it
survives a save and a load; bad input is refused by name.

The torch policies are the families' own ``Policy`` (their train.py), randomly initialised: the
conversion is tested, not a training run (tests/test_onnx_export.py flies a trained one)."""

from __future__ import annotations

import functools
import importlib.util
import itertools
import sys
from pathlib import Path

import numpy as np
import pytest
from extras import needs_module

from cwh_envs.controllers import CONE_ROUTE, MinEnergyFeedback, WaypointFeedback

pytestmark = pytest.mark.needs("fast")
torch = needs_module("torch", "families")

from cwh_envs.compiled_policy import CompiledPolicy, ResidualLaw  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# torch's MLP runs in float32, the compiled one in float64: the actions agree to float32 rounding,
# about 1e-7 of the pre-activations, which reach a few hundred on these draws (2e-6 seen)
TOLERANCE = 1e-5


def load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@functools.cache
def family(name: str):
    """The family's train.py and export.py (which imports it as ``train``)."""
    train = load(ROOT / "families" / name / "train.py", f"compiled_policy_train_{name}")
    before = sys.modules.get("train")
    sys.modules["train"] = train
    try:
        export = load(ROOT / "families" / name / "export.py", f"compiled_policy_export_{name}")
    finally:
        if before is None:
            del sys.modules["train"]
        else:
            sys.modules["train"] = before
    return train, export


def torch_policy(name: str, form: str, activation: str, seed: int = 0):
    """The family's Policy in ``form``, randomly initialised, with made-up standardisation."""
    train, _ = family(name)
    torch.manual_seed(seed)
    config = {
        "POLICY_FORM": form,
        "RESIDUAL_SCALE": 0.3,
        "N_LAYERS": 2,
        "HIDDEN_DIM": 32,
        "ACTIVATION": activation,
        "DROPOUT": 0.1,  # off in eval mode: the compiled policy has none
    }
    rng = np.random.default_rng(seed)
    mean = torch.tensor(rng.normal(size=10), dtype=torch.float32)
    std = torch.tensor(rng.uniform(0.5, 30.0, size=10), dtype=torch.float32)
    return train.build_policy(config, mean, std).eval(), config


def observations(seed: int, n: int = 1500) -> np.ndarray:
    """Docking observations [r, v, g, tau] on every step to go (tau = m / H, m = 0..H), ports on a
    sphere, chasers around them; every tenth chaser exactly on its docking axis."""
    rng = np.random.default_rng(seed)
    horizon = family("docking-constrained")[0].PROBLEM.horizon
    goal = rng.normal(size=(n, 3))
    goal *= rng.uniform(1.0, 3.0, (n, 1)) / np.linalg.norm(goal, axis=1, keepdims=True)
    r = goal + rng.normal(scale=40.0, size=(n, 3))
    r[::10] = goal[::10] * rng.uniform(2.0, 20.0, (len(goal[::10]), 1))
    v = rng.normal(scale=0.2, size=(n, 3))
    tau = np.arange(n) % (horizon + 1) / horizon
    return np.column_stack([r, v, goal, tau])


def compiled_from(name: str, policy, config: dict, path: Path) -> CompiledPolicy:
    """``policy`` through its family's export.py (``write_compiled``), read back."""
    _, export = family(name)
    summary = export.write_compiled(policy, path, {"task": "docking", "config": config})
    assert summary["max_action_difference"] <= TOLERANCE
    return CompiledPolicy.load(path)


CASES = [
    ("docking-constrained", "route", "gelu"),
    ("docking-constrained", "route", "tanh"),
    ("docking-constrained", "residual", "relu"),
    ("docking-constrained", "direct", "tanh"),
    ("docking", "residual", "gelu"),
    ("docking", "direct", "relu"),
]


@pytest.mark.parametrize(("name", "form", "activation"), CASES)
def test_the_compiled_policy_is_the_torch_policy(tmp_path, name, form, activation):
    policy, config = torch_policy(name, form, activation)
    compiled = compiled_from(name, policy, config, tmp_path / "policy.npz")
    obs = observations(len(form) + len(activation))
    expected = policy.act(obs)
    got = compiled(obs)
    assert got.shape == (len(obs), 3) and np.abs(got - expected).max() <= TOLERANCE
    # not a trivial function: the actions vary and the correction moves them off the law
    assert expected.std(axis=0).min() > 0.01
    # one chaser at a time, as a flight calls it, is the same answer
    for row in (0, 10, 241, 999):
        np.testing.assert_array_equal(compiled(obs[row]), got[row])
    assert compiled.metadata == {"task": "docking", "config": config}


def test_with_no_correction_the_route_policy_flies_the_route_law_and_past_the_last_waypoint_it_is_off(
    tmp_path,
):
    train, _ = family("docking-constrained")
    policy, config = torch_policy("docking-constrained", "route", "tanh")
    compiled = compiled_from("docking-constrained", policy, config, tmp_path / "route.npz")
    obs = observations(7)
    horizon, last = train.PROBLEM.horizon, CONE_ROUTE[-1].step
    law = WaypointFeedback(train.PROBLEM, CONE_ROUTE)
    steps = np.rint(obs[:, -1] * horizon).astype(int)
    flown = (steps >= 1) & (steps <= horizon)  # the law's own range of steps to go
    late = flown & (steps <= horizon - last)
    np.testing.assert_allclose(compiled(obs[late]), law(obs[late]), rtol=0, atol=1e-12)
    assert np.abs(compiled(obs[flown & ~late]) - law(obs[flown & ~late])).max() > 0.05
    # the net's last layer zeroed: tanh(0) = 0, the law alone at every step
    for parameter in (policy.net[-1].weight, policy.net[-1].bias):
        parameter.data.zero_()
    silent = compiled_from("docking-constrained", policy, config, tmp_path / "silent.npz")
    np.testing.assert_allclose(silent(obs[flown]), law(obs[flown]), rtol=0, atol=1e-12)


def test_with_no_correction_the_residual_policy_flies_the_minimum_energy_law(tmp_path):
    train, _ = family("docking")
    policy, config = torch_policy("docking", "residual", "tanh")
    for parameter in (policy.net[-1].weight, policy.net[-1].bias):
        parameter.data.zero_()
    compiled = compiled_from("docking", policy, config, tmp_path / "silent.npz")
    obs = observations(8)
    steps = np.rint(obs[:, -1] * train.PROBLEM.horizon)
    obs = obs[steps >= 1]
    np.testing.assert_allclose(compiled(obs), MinEnergyFeedback(train.PROBLEM)(obs), rtol=0, atol=1e-12)


def test_export_refuses_a_compiled_policy_that_misses_the_tolerance_and_writes_nothing(tmp_path, monkeypatch):
    _, export = family("docking-constrained")
    policy, config = torch_policy("docking-constrained", "route", "gelu")
    monkeypatch.setattr(export, "CHECK_TOLERANCE", 0.0)  # float32 torch against float64: never exact
    with pytest.raises(SystemExit, match=r"differ from the torch policy's by .*nothing written"):
        export.write_compiled(policy, tmp_path / "policy.npz", {"task": "docking", "config": config})
    assert not (tmp_path / "policy.npz").exists()


def layers(widths=(10, 8, 3), seed=0):
    rng = np.random.default_rng(seed)
    weights = [rng.normal(size=(out, into)) for into, out in itertools.pairwise(widths)]
    return weights, [rng.normal(size=len(w)) for w in weights]


def test_bad_input_is_refused_by_name(tmp_path):
    weights, biases = layers()
    mean, std = np.zeros(10), np.ones(10)
    with pytest.raises(ValueError, match="activation must be one of"):
        CompiledPolicy(weights, biases, "swish", mean, std)
    with pytest.raises(ValueError, match="layer 1: weights"):
        CompiledPolicy([weights[0], np.zeros((3, 7))], biases, "tanh", mean, std)
    with pytest.raises(ValueError, match="last layer must output the 3 thrust axes"):
        CompiledPolicy(*layers((10, 8, 4)), "tanh", mean, std)
    with pytest.raises(ValueError, match="one bias per weight matrix"):
        CompiledPolicy(weights, biases[:1], "tanh", mean, std)
    with pytest.raises(ValueError, match="weights\\[0\\] must be finite"):
        CompiledPolicy([np.full((8, 10), np.nan), weights[1]], biases, "tanh", mean, std)
    with pytest.raises(ValueError, match="obs_std must be > 0"):
        CompiledPolicy(weights, biases, "tanh", mean, np.zeros(10))
    with pytest.raises(ValueError, match="target_gain has 3 columns; 2 waypoints need 12"):
        ResidualLaw(0.3, np.zeros((5, 3, 3)), np.zeros((5, 3, 6)), 1.0, np.ones(2), np.ones(2))
    with pytest.raises(ValueError, match="correction_above must be an int in"):
        ResidualLaw(0.3, np.zeros((5, 3, 3)), np.zeros((5, 3, 6)), 1.0, correction_above=5)
    policy = CompiledPolicy(weights, biases, "tanh", mean, std)
    with pytest.raises(ValueError, match="obs must be finite"):
        policy(np.full(10, np.nan))
    with pytest.raises(ValueError, match="obs must be finite"):
        policy(np.vstack([np.zeros(10), np.full(10, np.inf)]))
    with pytest.raises(ValueError, match=r"obs must be \(10,\) or \(N, 10\), got shape \(7,\)"):
        policy(np.zeros(7))
    np.savez(tmp_path / "other.npz", weights_0=weights[0])
    with pytest.raises(ValueError, match="is not a compiled policy"):
        CompiledPolicy.load(tmp_path / "other.npz")


def test_an_mlp_alone_is_computed_as_written(tmp_path):
    """The direct form against numpy's own arithmetic: clip(W2 tanh(W1 z + b1) + b2, -1, 1)."""
    weights, biases = layers(seed=3)
    rng = np.random.default_rng(4)
    mean, std = rng.normal(size=10), rng.uniform(0.5, 2.0, 10)
    policy = CompiledPolicy(weights, biases, "tanh", mean, std)
    obs = rng.normal(size=(200, 10))
    hidden = np.tanh(((obs - mean) / std) @ weights[0].T + biases[0])
    expected = np.clip(hidden @ weights[1].T + biases[1], -1.0, 1.0)
    np.testing.assert_allclose(policy(obs), expected, rtol=0, atol=1e-12)
    assert 0 < np.mean(np.abs(expected) == 1.0) < 1  # some actions clipped, some not
    again = CompiledPolicy.load(policy.save(tmp_path / "mlp.npz"))
    np.testing.assert_array_equal(again(obs), policy(obs))


def test_compile_checked_refuses_a_net_it_does_not_compute(tmp_path):
    from cwh_envs.compiled_policy import compile_checked

    policy, config = torch_policy("docking", "direct", "tanh")
    nn = torch.nn
    for net, problem in (
        (nn.Sequential(nn.Linear(10, 8), nn.Sigmoid(), nn.Linear(8, 3)), "holds a Sigmoid"),
        (nn.Sequential(nn.Linear(10, 8), nn.Tanh(), nn.Linear(8, 8), nn.ReLU(), nn.Linear(8, 3)), "mixes"),
        (nn.Sequential(nn.Linear(10, 8), nn.GELU(approximate="tanh"), nn.Linear(8, 3)), "holds a GELU"),
    ):
        policy.net = net
        with pytest.raises(ValueError, match=problem):
            compile_checked(policy, tmp_path / "p.npz", {"config": config})
        assert not (tmp_path / "p.npz").exists()
