"""The audit steps end to end on real subprocesses of tests/audit_family (designed effects)."""

from __future__ import annotations

import json
import math

import pytest
from audit_support import AUDIT_FAMILY, P1, P1W, P2, ScriptedProposer, copy_family, family_best, run_campaign

from autoresearch.audit.inputs import AuditError, config_id, open_campaign
from autoresearch.audit.noise import measure_noise
from autoresearch.audit.prune import prune
from autoresearch.audit.random_arm import run_random_arm
from autoresearch.audit.report import write_report
from autoresearch.audit.verify import verify
from autoresearch.campaign.audit_log import read_audit
from autoresearch.execution.executors import LocalExecutor
from autoresearch.family import Family
from autoresearch.journal import read_json, read_jsonl
from autoresearch.loop.orchestrator import LoopSettings, Orchestrator
from autoresearch.loop.stopping import Budgets
from autoresearch.proposers.random_search import ARM_STREAM, RandomProposer

S = 0.01
SIGMA = S * math.sqrt(4 / 3)  # four alternating +-S noise values
SERIAL = LocalExecutor(1)


def full(family: Family, overrides: dict) -> dict:
    return {**family.baseline_config, **overrides}


def audited(tmp_path, script, top=3):
    """A family copy, a campaign of ``script``, then noise (K=4), verify (4 seeds) and prune."""
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer(script), iterations=len(script) + 1)
    measure_noise(family, SERIAL, k=4, campaign=open_campaign(root))
    verified = verify(open_campaign(root), LocalExecutor(2), top=top, n_seeds=4)
    pruned = prune(open_campaign(root), LocalExecutor(2))
    return family, root, verified, pruned


@pytest.fixture(scope="module")
def scenario_a(tmp_path_factory):
    """P1 (one edit per decision case) and P1W (P1, erratic: the single-seed best)."""
    return audited(tmp_path_factory.mktemp("a"), [P1, P1W])


def test_noise_is_written_into_the_family_and_the_audit(scenario_a):
    family, root, _, _ = scenario_a
    noise = read_json(family.path / "ledger.json")["seed_noise"]
    assert "seed_noise" not in read_json(family.path / "family.json")  # the registry holds no measurement
    assert noise["k"] == 4 and noise["seeds"] == [1, 2, 3, 4]  # fresh: the default seed 0 is taken
    assert noise["mean"] == pytest.approx(1.8) and noise["std"] == pytest.approx(SIGMA)
    assert noise["n_feasible"] == 0  # the baseline runs without its safety filter
    assert read_audit(root)["noise"]["std"] == noise["std"]


def test_verify_promotes_the_reproducible_candidate_not_the_single_seed_best(scenario_a):
    family, _, verified, _ = scenario_a
    p1, p1w = config_id(full(family, P1)), config_id(full(family, P1W))
    assert verified["single_seed_best"]["config_id"] == p1w  # lucky at seed 0
    candidates = {c["config_id"]: c for c in verified["candidates"]}
    assert set(candidates) == {p1, p1w}  # the baseline is the reference, never a candidate
    for c in candidates.values():  # equal means; P1W is ten times noisier
        assert c["passed"] and c["n"] == 4 and c["n_feasible"] == 4
        assert c["mu_r"] == pytest.approx(1.3 - 0.25 * SIGMA)
        assert c["margin"] == pytest.approx((1.8 - c["mu_r"]) / SIGMA)
        assert c["ci_low"] < c["diff"] < c["ci_high"]
    assert candidates[p1w]["sigma_r"] == pytest.approx(10 * SIGMA)
    assert verified["promoted"] == p1 and verified["family_best"]["updated"]
    (promotion,) = [e for e in Family.load(family.path).ledger.promotions if e["source"]["step"] == "verify"]
    assert promotion["config"] == full(family, P1) and promotion["n"] == 4
    assert promotion["metric"] == pytest.approx(candidates[p1]["mu_r"])
    # family.json: the configuration and its certified number (pruning's promotion since); the rest is the
    # ledger's
    best = family_best(family.path)
    assert read_json(family.path / "family.json")["best"] == {
        "config": best["config"],
        "metric": best["metric"],
    }


def test_a_promotion_keeps_the_training_budget_it_was_certified_under(tmp_path):
    """A campaign that granted its runs a time budget promotes a recipe defined with it: the ledger's
    entry and family.json's best both carry it (scenario_a's best, certified without one, has none)."""
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2, time_budget=30.0)
    measure_noise(family, SERIAL, k=4, campaign=open_campaign(root))
    verified = verify(open_campaign(root), LocalExecutor(2), top=1, n_seeds=4)
    assert verified["family_best"]["updated"]
    assert family_best(family.path)["time_budget"] == 30.0
    best = read_json(family.path / "family.json")["best"]
    assert best == {
        "config": full(family, P1),
        "metric": verified["candidates"][0]["mu_r"],
        "time_budget": 30.0,
    }
    assert Family.load(family.path).best["time_budget"] == 30.0  # a valid registry


def test_a_best_certified_under_limits_is_replaced_only_under_limits_as_tight(tmp_path):
    """A protocol's limits hold every split a reseed is scored on (the sealed split's loss is the
    search loss + 1000 here), and promotion keeps the tightest gate met: a best certified under
    limits replaces one certified without, and is not replaced by a campaign held to none."""
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    registry = read_json(family.path / "family.json")
    registry["test_split"] = True
    registry["protocols"] = {"capped": {"limits": {"loss": 5000.0}}, "tight": {"limits": {"loss": 100.0}}}
    (family.path / "family.json").write_text(json.dumps(registry))
    family = Family.load(family.path)
    measure_noise(family, SERIAL, k=4, out_dir=tmp_path / "noise")  # not runs/ of the working directory

    def certify(name, protocol=None):
        root = run_campaign(family, tmp_path / name, ScriptedProposer([P1]), iterations=2, protocol=protocol)
        return verify(open_campaign(root), LocalExecutor(2), top=1, n_seeds=4)

    assert certify("plain")["family_best"]["updated"]
    tight = certify("tight", "tight")  # feasible on the search split, over the limit on the sealed one
    (candidate,) = tight["candidates"]
    assert candidate["n_feasible"] == 0 and not candidate["passed"] and tight.get("promoted") is None
    capped = certify("capped", "capped")
    assert capped["family_best"]["updated"] and "tighter limits" in capped["family_best"]["why"]
    assert read_json(family.path / "family.json")["best"]["limits"] == {"loss": 5000.0}
    assert family_best(family.path)["limits"] == {"loss": 5000.0}
    text = write_report(tmp_path / "capped").read_text()
    assert "is true and it reports `loss` <= 5000 (the protocol's limits)" in text
    again = certify("plain-again")  # as reproducible, held to no limit
    assert not again["family_best"]["updated"] and "limits" in again["family_best"]["why"]
    # In words (issue 59): where the best came from and its limits, never a dict.
    why = again["family_best"]["why"]
    assert "{" not in why and "(run it0002 of capped, verified)" in why and "(loss <= 5000)" in why


def test_prune_decides_every_case_of_eq_loodecision(scenario_a):
    _, _, _, pruned = scenario_a
    d = {x["param"]: x for x in pruned["decisions"]}
    assert {k: v["decision"] for k, v in d.items()} == {
        "EPOCHS": "keep",  # one seed suffices
        "SAFE": "keep",  # reverting breaks feasibility
        "HITCH": "drop",  # hitchhiker
        "BORDER": "keep-borderline",
        "DAGGER": "drop-dagger",
        "GAP": "keep",  # the gap: load-bearing, visible at two seeds only
    }
    assert "infeasible" in d["SAFE"]["note"]
    assert d["EPOCHS"]["delta1_sigma"] <= -1 and "delta2" not in d["EPOCHS"]
    assert d["HITCH"]["delta2_sigma"] == pytest.approx(0, abs=1e-9)
    assert d["BORDER"]["delta2_sigma"] == pytest.approx(-0.75)
    assert d["DAGGER"]["delta2_sigma"] == pytest.approx(2.0)
    assert d["GAP"]["delta1_sigma"] > -1 and d["GAP"]["delta2_sigma"] == pytest.approx(-1.5)
    assert pruned["dropped"] == ["HITCH", "DAGGER"] and pruned["flagged"] == ["DAGGER"]


def test_a_published_pruned_recipe_more_reproducible_than_the_full_one_is_promoted(scenario_a):
    """Dropping DAGGER (an edit that costs 2 sigma) makes the pruned recipe the better and the more
    reproducible one: it is promoted in the full configuration's place (issue 39, item 2)."""
    family, _, verified, pruned = scenario_a
    assert pruned["published"] and pruned["pruned"]["passed"] and pruned["promotes_pruned"]
    recipe = full(family, {**P1, "HITCH": "a", "DAGGER": 0})
    best = family_best(family.path)
    assert best["config"] == recipe and best["metric"] == pruned["pruned"]["mu_r"]
    assert best["source"]["step"] == "prune" and best["pruned_from"] == verified["promoted"]
    assert best["dropped"] == ["HITCH", "DAGGER"] and "distilled" not in best


def test_a_published_pruned_recipe_no_more_reproducible_is_recorded_beside_the_full_one(tmp_path):
    """Dropping only a hitchhiker gives the same reseeded mean and spread: the full configuration
    stays the family best (the paper's docking case) and the recipe is its distilled one."""
    hitch = {**P1, "DAGGER": 0}  # DAGGER's harm reverted by hand: HITCH alone is left to drop
    family, _, _, pruned = audited(tmp_path, [hitch], top=1)
    assert pruned["dropped"] == ["HITCH"] and pruned["published"] and not pruned["promotes_pruned"]
    best = family_best(family.path)
    assert best["config"] == full(family, hitch) and best["source"]["step"] == "verify"
    assert best["distilled"]["config"] == full(family, {**hitch, "HITCH": "a"})
    assert best["distilled"]["dropped"] == ["HITCH"]


def test_every_step_uses_fresh_disjoint_seeds(scenario_a):
    _, root, verified, pruned = scenario_a
    groups = {
        "campaign": {r["seed"] for r in read_jsonl(root / "proposals.jsonl") if r["seed"] is not None},
        "noise": set(read_audit(root)["noise"]["seeds"]),
        "verify": set(verified["seeds"]),
        "probes": set(pruned["probe_seeds"]),
        "reverify": set(pruned["reverify_seeds"]),
    }
    assert groups["campaign"] == {0}
    seen: set[int] = set()
    for name, seeds in groups.items():
        assert not seen & seeds, f"{name} reuses {seen & seeds}"
        seen |= seeds


def test_rerunning_the_steps_runs_nothing_again(scenario_a):
    _, root, verified, pruned = scenario_a
    logs = [root / "audit" / "verify" / "verify.jsonl", root / "audit" / "prune" / "prune.jsonl"]
    before = [len(read_jsonl(log)) for log in logs]
    again = verify(open_campaign(root), SERIAL, top=3, n_seeds=4)
    assert again["seeds"] == verified["seeds"] and again["promoted"] == verified["promoted"]
    assert prune(open_campaign(root), SERIAL)["decisions"] == pruned["decisions"]
    assert [len(read_jsonl(log)) for log in logs] == before


def test_joint_group_forces_the_full_recipe(tmp_path):
    family, _, _, pruned = audited(tmp_path, [P2], top=1)
    d = {x["param"]: x["decision"] for x in pruned["decisions"]}
    assert d["JOINT_A"] == d["JOINT_B"] == "drop"  # each inert alone
    assert pruned["dropped"] == ["HITCH", "DAGGER", "JOINT_A", "JOINT_B"]
    # Together they regress past the target the full recipe reached: not published.
    assert pruned["pruned"]["passed"] and pruned["target_retained"] is False and not pruned["published"]
    assert "matters jointly" in pruned["reason"] and "JOINT_A, JOINT_B" in pruned["reason"]
    best = family_best(family.path)
    assert best["config"] == full(family, P2) and "distilled" not in best


def test_parity_guard_drops_a_throttled_reseed(tmp_path, monkeypatch):
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2)
    measure_noise(family, SERIAL, k=4, campaign=open_campaign(root))
    monkeypatch.setenv("AUDIT_THROTTLE_SEED", "6")  # a verification seed (5..8)
    (candidate,) = verify(open_campaign(root), SERIAL, top=3, n_seeds=4)["candidates"]
    assert candidate["n"] == 3 and candidate["n_parity_excluded"] == 1
    (excluded,) = [r for r in candidate["reseeds"] if r["excluded"]]
    assert excluded["seed"] == 6 and excluded["excluded"].startswith("parity guard")


def test_noise_resumes_and_extends_its_seed_list(tmp_path):
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    out = tmp_path / "noise"
    measure_noise(family, SERIAL, k=3, out_dir=out)
    assert len(read_jsonl(out / "noise.jsonl")) == 3
    noise = measure_noise(Family.load(family.path), SERIAL, k=5, out_dir=out)
    assert len(read_jsonl(out / "noise.jsonl")) == 5  # only seeds 4 and 5 ran
    assert noise["seeds"] == [1, 2, 3, 4, 5] and noise["k"] == 5
    with pytest.raises(AuditError, match="K >= 2"):
        measure_noise(family, SERIAL, k=1, out_dir=out)


def test_verify_needs_the_seed_noise_first(tmp_path):
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2)
    with pytest.raises(AuditError, match="autoresearch noise"):
        verify(open_campaign(root), SERIAL)


def test_random_arm_matches_the_loop_and_resumes(tmp_path):
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1, P1W]), iterations=3)
    measure_noise(family, SERIAL, k=4, campaign=open_campaign(root))
    part = run_random_arm(open_campaign(root), LocalExecutor(2), count=6)
    # An ordinary loop campaign: two draws in flight, records in completion order, the stop record last.
    records = read_jsonl(tmp_path / "campaign-random" / "proposals.jsonl")
    assert [r["status"] for r in records] == ["ran"] * 6 + ["stopped"]
    records = sorted(records[:6], key=lambda r: r["iteration"])
    assert records[0]["proposer"] == "baseline" and records[0]["config"] == family.baseline_config
    # The same draws the loop makes with the random proposer on the arm's own stream (the shared first
    # iteration included), never a random campaign's at the same seed (tests/test_first_hour.py).
    loop_dir = tmp_path / "loop-random"
    proposer = RandomProposer(Family.load(family.path).registry, seed=0, stream=ARM_STREAM)
    budgets = Budgets(max_iters=6, plateau_window=10**6)
    Orchestrator(Family.load(family.path), proposer, loop_dir, LoopSettings("random", budgets)).run()
    loop = [r for r in read_jsonl(loop_dir / "proposals.jsonl") if r["status"] == "ran"]
    assert [r["config"] for r in loop] == [r["config"] for r in records[:6]]
    assert [r["metric"] for r in loop] == [r["metric"] for r in records[:6]]
    # The verdict of Eq. verdict, in noise units against the campaign's single-seed best.
    agent = open_campaign(root).single_seed_best().metric
    assert part["count"] == 6 and part["agent_best"] == agent
    if part["best"]:
        assert part["units"] == pytest.approx(-(agent - part["best"]["metric"]) / SIGMA)
    assert part["n_feasible"] == sum(bool(r["feasible"]) for r in records[:6])
    assert read_audit(root)["random"]["verdict"] == part["verdict"]
    lines = (tmp_path / "campaign-random" / "proposals.jsonl").read_bytes()
    assert run_random_arm(open_campaign(root), SERIAL, count=6) == part  # resumed: nothing runs again
    assert (tmp_path / "campaign-random" / "proposals.jsonl").read_bytes() == lines


def test_matched_range_narrows_the_training_budget(tmp_path):
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2)
    part = run_random_arm(open_campaign(root), LocalExecutor(2), count=8, matched_range=True)
    assert part["matched_range"] == {"EPOCHS": {"low": 10, "high": 60}}  # the campaign ran 10 and 60
    records = read_jsonl(tmp_path / "campaign-random-matched" / "proposals.jsonl")
    assert all(10 <= r["config"]["EPOCHS"] <= 60 for r in records if r["config"])
    assert part["verdict"] is None and "noise" in part["verdict_note"]  # no noise measured yet
    assert "random_matched" in read_audit(root)
    with pytest.raises(AuditError, match="other settings"):  # same directory, another arm
        run_random_arm(open_campaign(root), SERIAL, count=9, out=tmp_path / "campaign-random-matched")
