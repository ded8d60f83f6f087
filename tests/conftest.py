"""Shared by every test: a private data cache for the run, one Ray instance for the tests that use
Ray, and the optional extras.

A test that needs an extra says so with ``@pytest.mark.needs("families", ...)``; a module that
cannot even be imported without one, with ``pytestmark = pytest.mark.needs(...)`` on a line of its
own (read here before the module is imported). Without the extra the test or the module is
skipped, naming it, so that the base install runs the rest (.ci/run's lowest-floors and
Python-matrix jobs); with ``CWH_REQUIRE_EXTRAS=1`` (the README's test command, which installs them
all) a missing extra fails instead.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from pathlib import Path

import pytest
from extras import EXTRAS, missing_extras, needs_module, required, skip_or_fail

from autoresearch.execution.executors import keeping_signal_handlers

_CACHE_ENV = "CWH_ENVS_CACHE"
_MODULE_NEEDS = re.compile(r"^pytestmark = .*pytest\.mark\.needs\(([^)]*)\)", re.MULTILINE)


class _NotImportable(pytest.Module):
    """A test module that needs a missing extra: reported as skipped, never imported."""

    missing: list[str]

    def collect(self):
        skip_or_fail(self.missing, module_level=True)
        return []


def pytest_pycollect_makemodule(module_path, parent):
    found = _MODULE_NEEDS.search(module_path.read_text(encoding="utf-8"))
    missing = missing_extras([e.strip().strip("\"'") for e in found.group(1).split(",")]) if found else []
    if missing and not required():
        module = _NotImportable.from_parent(parent, path=module_path)
        module.missing = missing
        return module
    return None


def pytest_runtest_setup(item):
    for marker in item.iter_markers("needs"):
        unknown = set(marker.args) - set(EXTRAS)
        if unknown:
            pytest.fail(f"unknown extra(s) {sorted(unknown)} in @pytest.mark.needs (known: {sorted(EXTRAS)})")
        missing = missing_extras(marker.args)
        if missing:
            skip_or_fail(missing)


def pytest_collection_modifyitems(config, items):
    # Under pytest-xdist (scripts/test.sh runs -n 2 --dist loadgroup) every test that starts Ray runs
    # on one worker, one after another: two Ray instances on two cores starve each other.
    if not config.pluginmanager.hasplugin("xdist"):
        return
    for item in items:
        if "ray_instance" in item.fixturenames or any("ray" in m.args for m in item.iter_markers("needs")):
            item.add_marker(pytest.mark.xdist_group("ray"))


_CHECKOUT_RUNS = Path(__file__).resolve().parents[1] / "runs"


def _checkout_runs() -> set[str]:
    return set(os.listdir(_CHECKOUT_RUNS)) if _CHECKOUT_RUNS.is_dir() else set()


def pytest_sessionstart(session):
    if not hasattr(session.config, "workerinput"):  # the controller (or a run without xdist)
        session.config._runs_before = _checkout_runs()


def pytest_sessionfinish(session, exitstatus):
    # A test writes under its tmp_path, never into the checkout: a run directory the suite leaves in
    # runs/ (as `measure_noise` without out_dir once left runs/noise-audit-toy) fails the session.
    before = getattr(session.config, "_runs_before", None)
    left = sorted(_checkout_runs() - before) if before is not None else []
    if left:
        reporter = session.config.pluginmanager.get_plugin("terminalreporter")
        if reporter is not None:
            reporter.ensure_newline()
            reporter.write_line(
                f"the tests left {left} in {_CHECKOUT_RUNS}: write under tmp_path instead", red=True
            )
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_configure(config):
    # Before collection (test modules copy os.environ for their subprocesses at import): every set the
    # tests build, in-process or in a subprocess, goes to a directory of this run, never the user's
    # ~/.cache/cwh_envs. A cold build of everything the families read takes about 10 s.
    config._cwh_cache = tempfile.mkdtemp(prefix="cwh_envs_cache-")
    config._cwh_cache_before = os.environ.get(_CACHE_ENV)
    os.environ[_CACHE_ENV] = config._cwh_cache


def pytest_unconfigure(config):
    if getattr(config, "_cwh_cache", None):
        shutil.rmtree(config._cwh_cache, ignore_errors=True)
        if config._cwh_cache_before is None:
            os.environ.pop(_CACHE_ENV, None)
        else:
            os.environ[_CACHE_ENV] = config._cwh_cache_before


@pytest.fixture(scope="session")
def ray_instance():
    """One local Ray instance for the whole run (RayExecutor reuses a running one), with our signal
    handlers kept: ray.init would leave its own SIGTERM handler behind."""
    ray = needs_module("ray", "ray")
    with keeping_signal_handlers():
        ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    with keeping_signal_handlers():
        ray.shutdown()
