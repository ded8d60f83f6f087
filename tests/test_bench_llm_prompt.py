"""benchmarks/bench_llm_prompt.py's fake campaign: the cache serves most input after the first turns."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_llm_prompt import campaign  # noqa: E402

pytestmark = pytest.mark.needs("llm")


@pytest.mark.parametrize("kind", ["anthropic", "openai"])
def test_most_input_is_cached_after_the_first_turns_and_caching_saves_money(kind):
    result = campaign(kind, str(ROOT / "families" / "docking"), 25)
    later = result["log"][2:]
    assert sum(read for _, _, read in later) / sum(total for _, total, _ in later) >= 0.8
    assert result["cached_cost"] < result["uncached_cost"]
    sizes = [size for size, _, _ in result["log"]]
    assert sizes == sorted(sizes)  # one run more each turn, nothing else grows
