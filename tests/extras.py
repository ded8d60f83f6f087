"""The optional extras in the tests: which modules each installs, and a test module's top-level
import of one (``torch = needs_module("torch", "families")``), skipped without it unless
``CWH_REQUIRE_EXTRAS=1``. Tests mark themselves with ``@pytest.mark.needs(...)`` (tests/conftest.py)."""

from __future__ import annotations

import importlib
import importlib.util
import os

import pytest

# extra -> the modules it installs that the tests import
EXTRAS = {
    "families": ("torch",),
    "gp": ("torch",),
    "llm": ("anthropic", "openai"),
    "ray": ("ray",),
    "sb3": ("stable_baselines3",),
    "rl": ("stable_baselines3", "rliable"),
    "onnx": ("onnx", "onnxruntime"),
    "dashboard": ("optuna_dashboard",),
    "fast": ("numba",),
}


def required() -> bool:
    return os.environ.get("CWH_REQUIRE_EXTRAS") == "1"


def missing_extras(extras) -> list[str]:
    return [e for e in extras if any(importlib.util.find_spec(m) is None for m in EXTRAS[e])]


def skip_or_fail(missing: list[str], *, module_level: bool = False):
    message = "needs the extra(s) " + ", ".join(f"[{e}]" for e in missing)
    if required():
        pytest.fail(message + ", which CWH_REQUIRE_EXTRAS=1 requires", pytrace=False)
    pytest.skip(message, allow_module_level=module_level)


def needs_module(module: str, extra: str):
    """``module`` imported, for a test module's top level; the whole module skipped without it."""
    if missing_extras([extra]):
        skip_or_fail([extra], module_level=True)
    return importlib.import_module(module)
