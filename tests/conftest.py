"""Shared by every test: a private data cache for the run, and one Ray instance for the tests that use Ray."""

from __future__ import annotations

import os
import shutil
import tempfile

import pytest

from autoresearch.executors import keeping_signal_handlers

_CACHE_ENV = "CWH_ENVS_CACHE"


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
    ray = pytest.importorskip("ray", reason="the optional extra 'ray' is not installed")
    with keeping_signal_handlers():
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    with keeping_signal_handlers():
        ray.shutdown()
