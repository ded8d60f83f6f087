"""Smaller reliability fixes (issue 29, item 6): atomic writes keep a file's mode, env constructors
bound the horizon, and complex inputs are refused instead of cast to real."""

from __future__ import annotations

import os
import stat
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

import cwh_envs  # noqa: F401  (registers the envs)
from autoresearch.journal import write_json_atomic
from cwh_envs.problems import MAX_HORIZON, DockingProblem, RendezvousProblem
from cwh_envs.vector import CWHRendezvousVectorEnv


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o600])
def test_an_atomic_write_keeps_the_files_mode(tmp_path, mode):
    path = tmp_path / "family.json"
    path.write_text("{}")
    path.chmod(mode)
    write_json_atomic(path, {"best": None})
    assert stat.S_IMODE(path.stat().st_mode) == mode
    assert [p.name for p in tmp_path.iterdir()] == ["family.json"]  # no temporary left


def test_an_atomic_write_gives_a_new_file_the_mode_open_would(tmp_path):
    previous = os.umask(0o027)
    try:
        write_json_atomic(tmp_path / "new.json", {})
        (tmp_path / "plain.json").write_text("{}")
    finally:
        os.umask(previous)
    modes = {p.name: stat.S_IMODE(p.stat().st_mode) for p in tmp_path.iterdir()}
    assert modes == {"new.json": 0o640, "plain.json": 0o640}


def test_a_horizon_too_long_to_build_is_refused_at_once():
    # In a subprocess: before the bound, the constructor walked 10**9 steps (hours).
    code = (
        "import gymnasium as gym, cwh_envs\n"
        "try:\n"
        "    gym.make('CWHRendezvous-v0', horizon=10**9)\n"
        "except ValueError as err:\n"
        "    print(err)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and f"horizon must be an integer in [2, {MAX_HORIZON}]" in out.stdout
    for problem in (RendezvousProblem, DockingProblem):
        with pytest.raises(ValueError, match="horizon"):
            problem(horizon=MAX_HORIZON + 1)
        assert problem(horizon=MAX_HORIZON).horizon == MAX_HORIZON


@pytest.mark.parametrize("env_id", ["CWHRendezvous-v0", "CWHDockKOZ-v1"])
def test_complex_actions_and_states_are_refused_not_cast(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    for action in (np.array([0.5 + 0.5j, 0.0, 0.0]), [0.5j, 0, 0], np.zeros(3, dtype=np.complex64)):
        with pytest.raises(ValueError, match="action must be real"):
            env.step(action)
    state = np.zeros(6, dtype=complex)
    state[0] = 50 + 1j
    with pytest.raises(ValueError, match="initial_state must be real"):
        env.reset(options={"initial_state": state})
    env.step(np.array([0.1, 0.0, -0.1]))  # a real action still steps
    env.close()


def test_a_complex_batch_of_actions_is_refused():
    envs = CWHRendezvousVectorEnv(num_envs=2)
    envs.reset(seed=0)
    with pytest.raises(ValueError, match="action must be real"):
        envs.step(np.zeros((2, 3)) + 0.1j)
    envs.close()
