"""loop --warm-start: earlier campaigns' finished runs, matched against the space searched now, told to
the key-free samplers (Optuna's add_trials) and summarised for an LLM proposer; kept in campaign.json."""

import json

import pytest
from loop_helpers import TOY_OPTIMUM, ScriptedProposer, copy_toy, run_loop

from autoresearch.campaign import Campaign, CampaignMeta
from autoresearch.cli import main
from autoresearch.family import Family
from autoresearch.journal import read_json, read_jsonl
from autoresearch.loop.warm_start import WarmStart
from autoresearch.proposers.prompting import WARM_START, render_prompt
from autoresearch.proposers.tpe import TPEProposer

NARROW = {"narrow": {"bounds": {"EPOCHS": {"high": 20}}}}  # a protocol: EPOCHS 30 lies outside it
EARLIER = [
    TOY_OPTIMUM,
    {"EPOCHS": 12},
    {"EPOCHS": 14, "DROPOUT": 0.2},
    {"LEARNING_RATE": 0.09, "MOMENTUM": 0.9},
]


@pytest.fixture
def toy(tmp_path):
    family = copy_toy(tmp_path)
    registry = json.loads((family / "family.json").read_text())
    (family / "family.json").write_text(json.dumps({**registry, "protocols": NARROW}))
    return family


@pytest.fixture
def earlier(toy, tmp_path):
    """An earlier campaign of the family: the baseline, four experiments (one of them failed), its
    second record written before DROPOUT existed and its third with a parameter since removed."""
    root = tmp_path / "earlier"
    root.mkdir()
    CampaignMeta.new(Family.load(toy), "scripted", {}).write(root)
    run_loop(toy, ScriptedProposer([*EARLIER, {"EPOCHS": 0}]), root, max_iters=6)
    lines = (root / "proposals.jsonl").read_text().splitlines()
    records = [json.loads(line) for line in lines]
    del records[1]["config"]["DROPOUT"]  # TOY_OPTIMUM, as a campaign before DROPOUT wrote it
    records[2]["config"]["OLD_KNOB"] = 1
    (root / "proposals.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    return root


def test_runs_are_matched_against_the_space_searched_now(toy, earlier):
    family = Family.load(toy)
    warm = WarmStart.load([str(earlier)], family, family.space)
    records = Campaign(earlier).records()
    finished = [r for r in records if r.ran]
    assert len(finished) == 5  # the baseline and four experiments; the failed one is no result
    (source,) = warm.sources
    assert source["finished"] == 5 and source["used"] == 4 and source["completed_from_baseline"] == 1
    assert source["dropped"] == {"sets a parameter the space no longer has": 1}
    optimum = next(run for run in warm.runs if run.iteration == 2).outcome
    assert optimum.config == {**TOY_OPTIMUM, "DROPOUT": 0.0}  # set to the baseline's value
    assert optimum.metric == records[1].metric and optimum.seconds == records[1].wall_seconds
    # Under a protocol that narrows EPOCHS to <= 20, the two EPOCHS 30 runs are outside too.
    narrow = family.under_protocol("narrow")
    warm = WarmStart.load([str(earlier)], narrow, narrow.space)
    assert [run.iteration for run in warm.runs] == [1, 4]
    assert warm.sources[0]["dropped"]["a value outside the space searched now"] == 2


def test_runs_are_judged_under_the_gate_searched_now(toy, earlier):
    """A protocol's limits re-judge the earlier runs: one that ran feasible but reports a limited field
    over its limit is told to the samplers as infeasible, with the excess among its constraints."""
    registry = json.loads((toy / "family.json").read_text())
    registry["protocols"]["capped"] = {"limits": {"loss": 0.5}}
    (toy / "family.json").write_text(json.dumps(registry))
    capped = Family.load(toy).under_protocol("capped")
    before = {
        run.iteration: run.outcome
        for run in WarmStart.load([str(earlier)], Family.load(toy), capped.space).runs
    }
    after = {run.iteration: run.outcome for run in WarmStart.load([str(earlier)], capped, capped.space).runs}
    assert before.keys() == after.keys()
    for iteration, outcome in after.items():
        over = outcome.metric > 0.5
        assert outcome.feasible == (before[iteration].feasible and not over)
        assert (outcome.constraints["loss_over_limit"] > 0) == over
    assert any(b.feasible and not after[i].feasible for i, b in before.items())  # one re-judged, at least


def test_tpe_starts_from_the_earlier_runs(toy, earlier, tmp_path, capsys):
    campaign = tmp_path / "c"
    args = ["loop", "--family", toy, "--proposer", "tpe", "--max-iters", "2", "--plain"]
    assert main([*map(str, args), "--warm-start", str(earlier), "--campaign", str(campaign)]) == 0
    records = read_jsonl(campaign / "proposals.jsonl")
    # Told before its first turn: four earlier runs and this campaign's baseline.
    assert records[1]["proposal"]["annotation"]["hypothesis"] == "TPE suggestion after 5 observations"
    meta = read_json(campaign / "campaign.json")
    assert meta["settings"]["warm_start"] == [str(earlier)]
    noted = meta["sessions"][-1]["warm_start"]
    assert noted["runs"] == 4 and noted["campaigns"][0]["dropped"] == {
        "sets a parameter the space no longer has": 1
    }
    # The same proposer, told the same runs, asks the same: the warm start is Optuna's add_trials.
    family = Family.load(toy)
    tpe = TPEProposer(
        family.search_registry(), prior=WarmStart.load([str(earlier)], family, family.space).outcomes
    )
    assert len(tpe.trials) == 4


def test_a_warm_start_that_cannot_be_used_is_one_line(toy, earlier, tmp_path, capsys):
    other = copy_toy(tmp_path, "other")
    registry = json.loads((other / "family.json").read_text())
    (other / "family.json").write_text(json.dumps({**registry, "name": "other"}))
    for proposer, source, said in (
        ("tpe", earlier, "a campaign of family 'toy', not 'other'"),
        ("tpe", tmp_path, "not a campaign directory"),
    ):
        args = ["loop", "--family", other, "--proposer", proposer, "--campaign", tmp_path / f"c-{proposer}"]
        assert main([*map(str, args), "--warm-start", str(source)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and said in err, err
    args = f"loop --family {toy} --proposer random --campaign {tmp_path / 'r'} --warm-start {earlier}"
    assert main(args.split()) == 2
    assert "the random proposer draws independently" in capsys.readouterr().err


def test_an_llm_proposer_is_shown_the_summary(toy, earlier, tmp_path):
    family = Family.load(toy)
    warm = WarmStart.load([str(earlier)], family, family.space)
    proposer = ScriptedProposer([{"EPOCHS": 11}])
    run_loop(toy, proposer, tmp_path / "c", max_iters=2, warm_start=warm)
    context = proposer.contexts[0]
    assert context.warm_start_summary == warm.summary(family)
    prompt = render_prompt(context)
    assert WARM_START in prompt.stable and "4 finished runs of earlier campaigns" in prompt.stable
    best = min((r.outcome for r in warm.runs), key=lambda o: o.metric)
    assert f"loss={best.metric:.6g}" in prompt.stable.split(WARM_START)[1].splitlines()[2]
