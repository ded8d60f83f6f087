"""Issue 25: what each install needs. The base install starts fast (nothing heavy imported for
``autoresearch --help`` or ``import cwh_envs``), and a missing extra is one line naming the extra.

A missing extra is made real in a subprocess: a sitecustomize on PYTHONPATH puts None in
sys.modules for the modules named in $BLOCK_MODULES, so that importing them fails as it does
where they are not installed, in that process and in every Python process it starts.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import pytest
from loop_helpers import copy_toy

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("numpy", "scipy", "matplotlib", "optuna", "torch", "proxsuite", "clarabel", "anthropic", "openai")


def python(code: str, *, block: tuple[str, ...] = (), tmp_path: Path | None = None, **kwargs):
    env = dict(os.environ)
    if block:
        site = tmp_path / "block"
        site.mkdir(exist_ok=True)
        (site / "sitecustomize.py").write_text(
            "import os, sys\nfor name in os.environ['BLOCK_MODULES'].split(','):\n    sys.modules[name] = None\n"
        )
        env["PYTHONPATH"] = os.pathsep.join([str(site), env.get("PYTHONPATH", "")])
        env["BLOCK_MODULES"] = ",".join(block)
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300, **kwargs
    )


def imported_by(code: str) -> list[str]:
    probe = f"{code}\nimport json, sys\nprint(json.dumps(sorted(m for m in {HEAVY!r} if m in sys.modules)))"
    result = python(probe)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])


def test_autoresearch_help_imports_nothing_heavy():
    code = "from autoresearch.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass"
    assert imported_by(code) == []
    result = python("from autoresearch.cli import main; main(['--help'])")
    assert "loop" in result.stdout and "export" in result.stdout  # every command listed


def test_import_cwh_envs_registers_the_ids_and_imports_only_numpy_beside_gymnasium():
    assert imported_by("import cwh_envs, gymnasium as gym\nassert 'CWHDockKOZ-v1' in gym.registry") == [
        "numpy"
    ]
    # The filter is still there, imported when first used.
    assert "proxsuite" in imported_by("import cwh_envs\ncwh_envs.CBFSafetyFilter")


def test_one_version_from_the_package_metadata():
    installed = metadata.version("cwh-autoresearch")
    result = subprocess.run(
        [sys.executable, "-m", "autoresearch", "--version"], capture_output=True, text=True, timeout=60
    )
    assert result.stdout.strip() == f"autoresearch {installed}"
    assert imported_by(f"import cwh_envs\nassert cwh_envs.__version__ == {installed!r}") == ["numpy"]
    for package in ("cwh_envs", "autoresearch"):
        assert (ROOT / package / "py.typed").is_file()


@pytest.mark.parametrize(
    ("args", "blocked", "extra"),
    [
        (["--proposer", "gp"], ("torch",), "gp"),
        (["--proposer", "anthropic"], ("anthropic",), "llm"),
        (["--proposer", "openai", "--dry-run"], ("openai",), "llm"),
        (["--proposer", "random", "--executor", "ray"], ("ray",), "ray"),
    ],
)
def test_a_missing_extra_is_one_line_naming_it(args, blocked, extra, tmp_path):
    toy = copy_toy(tmp_path)
    argv = [
        "loop",
        "--family",
        str(toy),
        "--campaign",
        str(tmp_path / "c"),
        "--max-iters",
        "2",
        "--plain",
        *args,
    ]
    code = f"import sys\nfrom autoresearch.cli import main\nsys.exit(main({argv!r}))"
    result = python(code, block=blocked, tmp_path=tmp_path)
    assert result.returncode == 2, result.stderr
    (line,) = result.stderr.strip().splitlines()
    assert f"pip install 'cwh-autoresearch[{extra}]'" in line and "Traceback" not in result.stderr
    assert not (tmp_path / "c" / "proposals.jsonl").exists()  # refused before anything ran


@pytest.mark.parametrize(
    ("name", "blocked", "message"),
    [
        (
            "docking",
            "torch",
            "this family trains with torch, which is not installed: pip install 'cwh-autoresearch[families]'",
        ),
        (  # torch is there, SB3 is not: the message names both and the two extras
            "docking-rl",
            "stable_baselines3",
            "this family trains with torch and stable-baselines3, which are not both installed: "
            "pip install 'cwh-autoresearch[families,sb3]'",
        ),
    ],
)
def test_a_family_without_its_extras_fails_its_prepare_check_naming_them(tmp_path, name, blocked, message):
    family = tmp_path / name
    shutil.copytree(ROOT / "families" / name, family, ignore=shutil.ignore_patterns("logs", "__pycache__"))
    result = python(
        "import runpy, sys\nsys.argv = ['prepare.py', '--check']\nrunpy.run_path('prepare.py', run_name='__main__')",
        block=(blocked,),
        tmp_path=tmp_path,
        cwd=family,
    )
    assert result.returncode == 1
    assert result.stderr.strip() == message
