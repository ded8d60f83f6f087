"""family.json is the paper's registry (the declaration and the current best); the audit's working data
(seed noise and its pins, per-split tables, distilled recipes, the promotions) is in ledger.json beside
it. A family in the old layout, both in family.json, reads the same and moves on the audit's first write,
and a proposer is shown what it was shown before the ledger."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from audit_support import AUDIT_FAMILY

from autoresearch import ledger
from autoresearch.family import Family, family_problems
from autoresearch.ledger import LEDGER_FILE, Ledger
from autoresearch.loop.context import shown_registry
from autoresearch.proposers.base import ProposerContext
from autoresearch.proposers.prompting import render_prompt

ROOT = Path(__file__).resolve().parents[1]
NOISE = {
    "mean": 1.8,
    "std": 0.01,
    "k": 4,
    "seeds": [1, 2, 3, 4],
    "values": [1.79, 1.81, 1.79, 1.81],
    "pinned": {"baseline": {}, "files": {}},
    "test": {"mean": 1001.8, "std": 0.01, "k": 4, "values": [1001.79, 1001.81, 1001.79, 1001.81]},
}


def old_layout(tmp_path: Path) -> Path:
    """A family as the audit left it before the ledger: the seed noise and a promoted best (with its
    per-split table, distilled recipe and re-measure note) in family.json."""
    family_dir = tmp_path / "old"
    shutil.copytree(AUDIT_FAMILY, family_dir, ignore=shutil.ignore_patterns("runs.jsonl*", "__pycache__"))
    registry = json.loads((family_dir / "family.json").read_text())
    config = {**registry["baseline"]["config"], "EPOCHS": 60}
    by_split = {"search": {"mu_r": 1.3, "sigma_r": 0.01, "n": 4, "n_feasible": 4}}
    best = {
        "config": config,
        "metric": 1.3,
        "std": 0.01,
        "n": 4,
        "source": {"campaign": "c", "run_id": "it0002", "step": "verify"},
        "split": "search",
        "by_split": by_split,
        "distilled": {"config": config, "metric": 1.31, "dropped": ["HITCH"]},
        "remeasured": "results/sealed/remeasure.py",
    }
    (family_dir / "family.json").write_text(
        json.dumps({**registry, "seed_noise": NOISE, "best": best}, indent=2)
    )
    return family_dir


def test_the_old_layout_reads_as_the_same_ledger(tmp_path):
    family = Family.load(old_layout(tmp_path))
    assert family.seed_noise == NOISE and family.sigma == 0.01
    entry = family.ledger.current(family.best)
    assert entry["by_split"]["search"]["mu_r"] == 1.3 and entry["distilled"]["dropped"] == ["HITCH"]
    assert family_problems(family.path) == []


def test_the_first_write_moves_the_old_layout_into_the_ledger(tmp_path):
    family_dir = old_layout(tmp_path)
    before = Family.load(family_dir)
    ledger.update(family_dir, lambda registry, old: (old, None))  # a write that changes nothing
    registry = json.loads((family_dir / "family.json").read_text())
    assert "seed_noise" not in registry and registry["best"] == {
        "config": before.best["config"],
        "metric": 1.3,
    }
    after = Family.load(family_dir)
    assert after.seed_noise == before.seed_noise and after.ledger == before.ledger
    assert after.ledger.current(after.best) == before.ledger.current(before.best)
    on_disk = json.loads((family_dir / LEDGER_FILE).read_text())
    assert on_disk == {"seed_noise": NOISE, "promotions": [before.ledger.current(before.best)]}


def test_a_proposer_is_shown_what_it_was_shown_before_the_ledger(tmp_path):
    family_dir = old_layout(tmp_path)
    before = Family.load(family_dir).search_registry()
    ledger.update(family_dir, lambda registry, old: (old, None))
    after = Family.load(family_dir).search_registry()
    assert json.dumps(after) == json.dumps(before)  # the same keys, in the same order
    assert after["seed_noise"]["mean"] == 1.8 and "test" not in after["seed_noise"] and "best" not in after

    def prompt(registry: dict) -> str:
        context = ProposerContext(1, (), "p", shown_registry(registry, blind=False), None, (), {}, False)
        return render_prompt(context).text

    assert prompt(after) == prompt(before)


def test_promotions_are_a_history_and_the_last_is_the_current_best():
    first, second = {"config": {"X": 1}, "metric": 2.0}, {"config": {"X": 2}, "metric": 1.0}
    book = Ledger().promoted(first).promoted(second)
    assert book.promotions == (first, second)
    assert book.current({"config": {"X": 2}, "metric": 1.0}) == second
    assert book.current({"config": {"X": 1}}) is None  # a best the audit did not promote last
    assert book.current({"config": {"X": 2, "NEW": 0}, "metric": 1.0}) == second  # the space grew since
    assert book.current({"config": {"X": 3}, "metric": 1.0}) is None
    assert book.restated({**second, "distilled": {}}).promotions == (first, {**second, "distilled": {}})


def test_the_committed_families_keep_the_registry_and_the_ledger_apart():
    for name in ("docking", "rendezvous", "docking-constrained"):
        family_dir = ROOT / "families" / name
        registry = json.loads((family_dir / "family.json").read_text())
        book = json.loads((family_dir / LEDGER_FILE).read_text())
        assert "seed_noise" not in registry
        assert set(registry.get("best") or {}) <= {"config", "metric", "time_budget", "limits"}
        assert book["seed_noise"]["k"] == 10 and "test" in book["seed_noise"]
        if registry.get("best"):
            promoted, best = book["promotions"][-1], registry["best"]
            # a parameter the space gained since the promotion sits beside it at the baseline's value
            grown = {k: v for k, v in best["config"].items() if k not in promoted["config"]}
            assert {k: best["config"][k] for k in promoted["config"]} == promoted["config"]
            assert grown == {k: registry["baseline"]["config"][k] for k in grown}
            assert promoted["metric"] == best["metric"]
            assert promoted.get("time_budget") == best.get("time_budget")  # the budget it was certified under


@pytest.mark.parametrize("budget", [0, -240.0, "240", True, None])
def test_a_best_certified_under_a_budget_names_it_in_positive_seconds(tmp_path, budget):
    family_dir = tmp_path / "fam"
    shutil.copytree(AUDIT_FAMILY, family_dir, ignore=shutil.ignore_patterns("runs.jsonl*", "__pycache__"))
    registry = json.loads((family_dir / "family.json").read_text())
    best = {"config": registry["baseline"]["config"], "metric": 1.0, "time_budget": budget}
    (family_dir / "family.json").write_text(json.dumps({**registry, "best": best}))
    problem = "'best.time_budget' must be a positive number of seconds"
    assert any(problem in p for p in family_problems(family_dir))
    (family_dir / "family.json").write_text(json.dumps({**registry, "best": {**best, "time_budget": 240.0}}))
    assert family_problems(family_dir) == []


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        ("not json", "ledger.json: not valid JSON"),
        ('{"promotions": {}}', "must hold an object with a 'promotions' list"),
        ('{"seed_noise": {"std": -1}, "promotions": []}', "'seed_noise' must be null or an object"),
    ],
)
def test_a_broken_ledger_is_a_problem_of_the_family(tmp_path, content, problem):
    family_dir = tmp_path / "fam"
    shutil.copytree(AUDIT_FAMILY, family_dir, ignore=shutil.ignore_patterns("runs.jsonl*", "__pycache__"))
    (family_dir / LEDGER_FILE).write_text(content)
    assert any(problem in p for p in family_problems(family_dir))
