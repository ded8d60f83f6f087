"""The sealed test split end to end on real subprocesses: the audit scores every reseed on both
splits from one training, chooses on the search split and gates on the test split; no proposer ever
sees a test-split value.

tests/audit_family scores its test split as the search loss plus 1000 (its TEST_OFFSET): every
designed effect holds on it unchanged, and any number of 1000 or more in what a proposer is shown
is a leaked test-split value.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
from dataclasses import asdict
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest
from audit_support import AUDIT_FAMILY, P1, P1W, ScriptedProposer, copy_family, family_best, run_campaign
from llm_support import chat_reply, messages_reply, tool_use

from autoresearch.audit.inputs import AuditError, config_id, open_campaign
from autoresearch.audit.noise import measure_noise
from autoresearch.audit.prune import prune
from autoresearch.audit.random_arm import run_random_arm
from autoresearch.audit.report import write_report
from autoresearch.audit.verify import pick_key, verify
from autoresearch.campaign import CampaignMeta
from autoresearch.campaign.audit_log import StepLog, read_audit
from autoresearch.campaign.meta import EVAL_ALLOWANCE
from autoresearch.commands.random_arm import print_random
from autoresearch.execution.executors import LocalExecutor
from autoresearch.family import Family
from autoresearch.journal import read_json, read_jsonl
from autoresearch.loop.context import shown_registry, summarize_random_arm
from autoresearch.loop.orchestrator import LoopSettings, Orchestrator
from autoresearch.loop.session import DEFAULTS, build_loop
from autoresearch.loop.stopping import Budgets
from autoresearch.proposers.base import Proposer
from autoresearch.proposers.tools import PROPOSE
from autoresearch.splits import Split

OFFSET = 1000.0
LEAK = re.compile(r"(?<![\d.])1\d{3}\.\d")  # a number in [1000, 2000) written with decimals
SERIAL = LocalExecutor(1)


def sealed_family(dest: Path) -> Family:
    copy_family(AUDIT_FAMILY, dest)
    registry = read_json(dest / "family.json")
    (dest / "family.json").write_text(json.dumps({**registry, "test_split": True}, indent=2))
    return Family.load(dest)


def leaks(text: str) -> list[str]:
    return LEAK.findall(text)


@pytest.fixture(scope="module")
def sealed(tmp_path_factory):
    """A sealed family copy, a campaign of [P1, P1W], then noise (K=4), verify, prune, random arm."""
    tmp = tmp_path_factory.mktemp("sealed")
    family = sealed_family(tmp / "family")
    root = run_campaign(family, tmp / "campaign", ScriptedProposer([P1, P1W]), iterations=3)
    measure_noise(family, SERIAL, k=4, campaign=open_campaign(root))
    verified = verify(open_campaign(root), LocalExecutor(2), top=3, n_seeds=4)
    pruned = prune(open_campaign(root), LocalExecutor(2))
    arm = run_random_arm(open_campaign(root), LocalExecutor(2), count=3)
    return family, root, verified, pruned, arm


def test_the_noise_is_measured_on_both_splits_from_the_same_runs(sealed):
    family, root, *_ = sealed
    noise = Family.load(family.path).seed_noise
    assert noise["test"]["k"] == noise["k"] == 4
    assert noise["test"]["mean"] == pytest.approx(noise["mean"] + OFFSET)
    assert noise["test"]["std"] == pytest.approx(noise["std"])
    assert [v - OFFSET for v in noise["test"]["values"]] == pytest.approx(noise["values"])
    rows = StepLog(root / "audit" / "noise" / "noise.jsonl").read()
    assert len(rows) == 4 and all(r.split is Split.TEST for r in rows)  # one run, both splits
    assert [r.on(Split.TEST).metric - OFFSET for r in rows] == pytest.approx(
        [r.on(Split.SEARCH).metric for r in rows]
    )


def test_verify_gates_on_the_test_split_and_picks_on_the_search_split(sealed):
    family, root, verified, *_ = sealed
    assert verified["split"] == "test" and verified["sealed_split"] is True
    assert verified["picked_on"] == "search"
    assert verified["noise"]["mean"] > OFFSET  # the gate's reference is the test-split noise
    for candidate in verified["candidates"]:
        search, test = candidate["by_split"]["search"], candidate["by_split"]["test"]
        assert candidate["mu_r"] == test["mu_r"] == pytest.approx(search["mu_r"] + OFFSET)
        assert all(r["metric"] > OFFSET and r["search_metric"] < OFFSET for r in candidate["reseeds"])
    assert verified["promoted"] == config_id({**family.baseline_config, **P1})  # as on search: the tight one
    best = family_best(family.path)
    assert best["split"] == "test" and best["metric"] > OFFSET and best["by_split"]["search"]["mu_r"] < OFFSET
    assert read_audit(root)["verify"]["split"] == "test"


def test_prune_decides_on_the_search_split_exactly_as_designed_and_gates_on_the_test_split(sealed):
    family, _, _, pruned, _ = sealed
    assert pruned["split"] == "test" and pruned["decided_on"] == "search"
    noise = Family.load(family.path).seed_noise  # the search split's
    assert pruned["unit"] == {"at": "baseline", "split": "search", "sigma": noise["std"], "n": 4}
    assert pruned["mu_r"] < OFFSET  # the probes' reference: the candidate's reseeded search-split mean
    decisions = {d["param"]: d["decision"] for d in pruned["decisions"]}
    assert decisions == {
        "EPOCHS": "keep",
        "SAFE": "keep",
        "HITCH": "drop",
        "BORDER": "keep-borderline",
        "DAGGER": "drop-dagger",
        "GAP": "keep",
    }
    probes = [p for d in pruned["decisions"] for p in d["probes"]]
    assert all(p["metric"] < OFFSET for p in probes)
    assert [p["test_metric"] - OFFSET for p in probes] == pytest.approx([p["metric"] for p in probes])
    assert pruned["pruned"]["split"] == "test" and pruned["pruned"]["mu_r"] > OFFSET


def test_the_random_arm_is_a_search_and_both_bests_are_judged_on_the_test_split(sealed):
    _, root, _, _, arm = sealed
    assert arm["split"] == "test" and arm["search_verdict"]["verdict"] is not None
    for side in ("agent", "random"):
        judged = arm["judged"][side]
        assert judged["reproduced"] is True  # the re-run's search value is the recorded one
        assert judged["test_metric"] == pytest.approx(judged["search_metric"] + OFFSET)
    arm_dir = root.parent / f"{root.name}-random"
    for name in ("proposals.jsonl", "runs.jsonl", "campaign.json"):
        assert leaks((arm_dir / name).read_text()) == [], name  # the arm's directory stays sealed


def test_the_random_arms_console_lines_print_numbers_at_their_precision(sealed, capsys):
    """Issue 39, item 3: a raw 1.857285765346452 in the console."""
    print_random(sealed[4])
    shown = capsys.readouterr().out
    judged = sealed[4]["judged"]["agent"]
    assert f"test split {judged['test_metric']:.6g}, search split {judged['search_metric']:.6g}" in shown
    assert not re.search(r"\d\.\d{7,}", shown)


def test_the_report_shows_both_splits_and_says_which_decided(sealed):
    _, root, verified, *_ = sealed
    text = write_report(root).read_text()
    assert "The search split chose, the sealed test split gated" in text
    assert "Selection gap of the promoted recipe" in text and "on the search split, in units of" in text
    promoted = next(c for c in verified["candidates"] if c["config_id"] == verified["promoted"])
    assert f"{promoted['by_split']['search']['mu_r']:.4g}" in text and f"{promoted['mu_r']:.4g}" in text


def test_gate_split_search_keeps_the_papers_protocol(tmp_path):
    family = sealed_family(tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2)
    measure_noise(family, SERIAL, k=4, campaign=open_campaign(root))
    verified = verify(open_campaign(root), SERIAL, top=1, n_seeds=2, split="search")
    candidate = verified["candidates"][0]
    assert verified["split"] == "search" and candidate["mu_r"] < OFFSET
    assert candidate["by_split"]["test"]["mu_r"] == pytest.approx(candidate["mu_r"] + OFFSET)
    assert "The search split decided" in write_report(root).read_text()


def test_a_test_split_that_ranks_otherwise_picks_nothing(tmp_path, monkeypatch):
    """On the sealed split the erratic P1W looks far better than P1 (AUDIT_TEST_SHIFT); both pass
    the gate there. Verification still promotes P1, the better on the search split, and pruning
    still decides every edit as designed though one reverted edit looks like a gain on test."""
    family = sealed_family(tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1, P1W]), iterations=3)
    measure_noise(family, SERIAL, k=4, campaign=open_campaign(root))
    monkeypatch.setenv("AUDIT_TEST_SHIFT", "WIDE=true:-0.5")
    verified = verify(open_campaign(root), LocalExecutor(2), top=2, n_seeds=4)
    tight, wide = (config_id({**family.baseline_config, **p}) for p in (P1, P1W))
    by_id = {c["config_id"]: c for c in verified["candidates"]}
    assert by_id[tight]["passed"] and by_id[wide]["passed"]
    assert by_id[wide]["bound"] > by_id[tight]["bound"]  # picked on the test split, P1W would win
    assert by_id[wide]["by_split"]["search"]["mu_r"] == pytest.approx(
        by_id[tight]["by_split"]["search"]["mu_r"]
    )
    assert verified["promoted"] == tight and family_best(family.path)["config"] == by_id[tight]["config"]
    assert verified["reason"].endswith("of those, the best bound on the search split is promoted")
    monkeypatch.setenv("AUDIT_TEST_SHIFT", 'HITCH="a":-0.5')  # reverting HITCH gains 0.5 on test only
    pruned = prune(open_campaign(root), LocalExecutor(2))
    decisions = {d["param"]: d for d in pruned["decisions"]}
    assert decisions["HITCH"]["decision"] == "drop" and decisions["DAGGER"]["decision"] == "drop-dagger"
    probes = decisions["HITCH"]["probes"]
    assert [p["test_metric"] - OFFSET for p in probes] == pytest.approx([p["metric"] - 0.5 for p in probes])


def test_the_test_split_refuses_the_search_pick_and_the_next_passing_one_is_promoted(tmp_path, monkeypatch):
    family = sealed_family(tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1, P1W]), iterations=3)
    measure_noise(family, SERIAL, k=4, campaign=open_campaign(root))
    monkeypatch.setenv("AUDIT_TEST_SHIFT", "GAP=1.0,WIDE=false:0.6")  # P1 no better than the baseline on test
    verified = verify(open_campaign(root), LocalExecutor(2), top=2, n_seeds=4)
    tight, wide = (config_id({**family.baseline_config, **p}) for p in (P1, P1W))
    by_id = {c["config_id"]: c for c in verified["candidates"]}
    assert pick_key(by_id[tight], family.direction) > pick_key(by_id[wide], family.direction)
    assert not by_id[tight]["passed"] and "m =" in by_id[tight]["reason"] and by_id[wide]["passed"]
    assert verified["promoted"] == wide


def test_a_family_without_a_sealed_split_gates_as_before_and_says_so(tmp_path):
    family = copy_family(AUDIT_FAMILY, tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2)
    measure_noise(family, SERIAL, k=4, campaign=open_campaign(root))
    with pytest.raises(AuditError, match="declares no sealed test split"):
        verify(open_campaign(root), SERIAL, top=1, n_seeds=2, split="test")
    verified = verify(open_campaign(root), SERIAL, top=1, n_seeds=2)
    assert verified["split"] == "search" and verified["sealed_split"] is False
    assert "test" not in Family.load(family.path).seed_noise
    assert "No sealed split" in write_report(root).read_text()


def test_audit_runs_are_granted_the_evaluation_allowance_for_the_sealed_split(tmp_path, monkeypatch):
    """A reseed also scores the sealed split, which no search run did: it gets the campaign's limit
    plus its evaluation allowance, so a recipe the search ran near its limit is not refused for the
    audit's own evaluation; without a sealed split the limit stays the campaign's."""
    family = sealed_family(tmp_path / "family")
    root = run_campaign(family, tmp_path / "campaign", ScriptedProposer([P1]), iterations=2, timeout=5.0)
    measure_noise(family, SERIAL, k=4, campaign=open_campaign(root))
    campaign = open_campaign(root)
    assert campaign.timeout == 5.0 and campaign.audit_timeout == 5.0 + EVAL_ALLOWANCE
    monkeypatch.setenv("AUDIT_SLEEP_S", "6")  # every reseed now outlasts the search's limit
    verified = verify(campaign, SERIAL, top=1, n_seeds=2)
    assert [r["status"] for r in verified["candidates"][0]["reseeds"]] == ["ok", "ok"]
    monkeypatch.delenv("AUDIT_SLEEP_S")
    plain = copy_family(AUDIT_FAMILY, tmp_path / "plain")
    root = run_campaign(plain, tmp_path / "plain-campaign", ScriptedProposer([P1]), iterations=1, timeout=5.0)
    assert open_campaign(root).audit_timeout == 5.0


# ----- no test-split value reaches a proposer ----------------------------------------------


class Spy(Proposer):
    """The real proposer, with everything it is handed written down."""

    def __init__(self, inner: Proposer):
        self.inner, self.name, self.seen = inner, inner.name, []

    def propose(self, context):
        self.seen.append(json.dumps(asdict(context), default=str))
        return self.inner.propose(context)

    def tell(self, outcome):
        self.seen.append(json.dumps(outcome._asdict(), default=str))
        self.inner.tell(outcome)


@pytest.mark.parametrize("name", ["random", "tpe", pytest.param("gp", marks=pytest.mark.needs("gp"))])
def test_no_key_free_proposer_sees_a_test_split_value(name, sealed, tmp_path):
    family, root, *_ = sealed
    arm = root.parent / f"{root.name}-random"
    assert leaks(json.dumps(Family.load(family.path).registry))  # the family itself holds test values
    settings = {"seed": 0, "timeout_per_run": 60.0, "max_iters": 4, "space": None, "random_arm": str(arm)}
    meta = CampaignMeta.new(Family.load(family.path), name, {**DEFAULTS, **settings})
    fam, proposer, _ = build_loop(meta)
    assert (
        leaks(json.dumps(shown_registry(fam.search_registry(), blind=False))) == []
    )  # what build_loop hands it
    spy = Spy(proposer)
    campaign = tmp_path / "c"
    campaign.mkdir()
    meta.write(campaign)
    budgets = Budgets(max_iters=4, plateau_window=10**6)
    Orchestrator(fam, spy, campaign, LoopSettings(name, budgets, timeout_per_run=60.0, random_arm=arm)).run()
    assert spy.seen and all(leaks(text) == [] for text in spy.seen)
    assert leaks(summarize_random_arm(arm, fam)) == []
    for file in ("family.json", "proposals.jsonl", "runs.jsonl"):
        assert leaks((campaign / file).read_text()) == [], file


class _LLMServer(ThreadingHTTPServer):
    """A local server speaking the Messages API and Chat Completions JSON; records each request body."""

    def __init__(self):
        super().__init__(("127.0.0.1", 0), _Handler)
        self.bodies: list[str] = []
        self.turn = 0


class _Handler(BaseHTTPRequestHandler):
    def do_POST(self):  # http.server's name
        server = self.server
        body = self.rfile.read(int(self.headers["Content-Length"])).decode()
        server.bodies.append(body)
        server.turn += 1
        proposal = {
            "hypothesis": "A longer budget lowers the loss.",
            "overrides": {"EPOCHS": 50 + server.turn},
            "axes": ["training_budget"],
            "expected_mechanism": "More optimisation.",
            "comparison_to_best": "Longer than the best run.",
            "failure_prediction": {"metric": 2.0, "direction": "above"},
        }
        if self.path.endswith("/messages"):
            reply = messages_reply(tool_use(PROPOSE, proposal), model="claude-sonnet-4-6")
        else:
            reply = chat_reply(tool_calls=[(PROPOSE, json.dumps(proposal))], model="gpt-5.4")
        content = reply.content
        self.send_response(200)
        self.send_header("content-type", "application/json")
        self.send_header("content-length", str(len(content)))
        self.end_headers()
        self.wfile.write(content)

    def log_message(self, *args):
        pass


@pytest.mark.needs("llm")
@pytest.mark.parametrize("name", ["anthropic", "openai"])
def test_no_llm_request_carries_a_test_split_value(name, sealed, tmp_path):
    """The real CLI and the real SDK against a local server: every request body, and the dry run."""
    family, root, *_ = sealed
    arm = root.parent / f"{root.name}-random"
    server = _LLMServer()
    threading.Thread(target=server.serve_forever, daemon=True).start()
    url = f"http://127.0.0.1:{server.server_address[1]}"
    env = {**os.environ, "ANTHROPIC_API_KEY": "test", "OPENAI_API_KEY": "test", "ANTHROPIC_BASE_URL": url}
    base = [sys.executable, "-m", "autoresearch", "loop", "--family", str(family.path), "--proposer", name]
    base += ["--random-arm", str(arm), "--max-iters", "3", "--timeout-per-run", "60", "--plain"]
    base += ["--base-url", f"{url}/v1"] if name == "openai" else []
    try:
        dry = subprocess.run([*base, "--dry-run"], capture_output=True, text=True, env=env, timeout=120)
        assert dry.returncode == 0, dry.stderr
        done = subprocess.run(
            [*base, "--campaign", str(tmp_path / "c")], capture_output=True, text=True, env=env, timeout=300
        )
        assert done.returncode == 0, done.stderr
    finally:
        server.shutdown()
    assert len(server.bodies) >= 2
    assert all(leaks(body) == [] for body in server.bodies)
    assert leaks(dry.stdout) == []
    records = read_jsonl(tmp_path / "c" / "proposals.jsonl")
    assert [r["status"] for r in records[:3]] == ["ran", "ran", "ran"]  # the proposals were real and ran
