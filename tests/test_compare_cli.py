"""``autoresearch compare`` on campaigns with a known ordering, and end to end after ``loop --repeats``."""

import json
from pathlib import Path

import pytest
from loop_helpers import TOY_FAMILY, copy_toy

from autoresearch.campaign import Campaign, CampaignMeta, Record, Status
from autoresearch.cli import main
from autoresearch.compare.analysis import analyse
from autoresearch.compare.inputs import CompareError, load_arms
from autoresearch.compare.report import write_comparison
from autoresearch.journal import write_json_atomic

NOISE = {"mean": 0.86, "std": 0.01, "k": 5, "measured_at": "2025-01-01T00:00:00+00:00"}


def fake_campaign(root: Path, metrics: list, *, infeasible=(), step_s: float = 1.0, noise=NOISE) -> Path:
    """A campaign directory as the loop writes it (through the campaign store), for a family directory
    that is not there (a campaign recorded elsewhere). ``None`` is a failed run; an invalid turn after
    the first run costs no experiment."""
    registry = {**json.loads((TOY_FAMILY / "family.json").read_text()), "seed_noise": noise}
    root.mkdir(parents=True)
    CampaignMeta("/elsewhere/toy", registry["name"], "scripted", {}, "2025-01-01T00:00:00+00:00").write(root)
    store = Campaign(root)
    store.write_registry(registry)
    records, elapsed = [], 0.0
    for i, metric in enumerate(metrics):
        elapsed += step_s
        status = Status.FAILED if metric is None else Status.RAN
        fields = {"metric": metric, "feasible": None if metric is None else i not in infeasible}
        records.append((status, {**fields, "run_id": f"it{len(records) + 1:04d}", "elapsed_s": elapsed}))
        if i == 0:
            records.append((Status.INVALID, {"reason": "refused", "elapsed_s": elapsed}))
    records.append((Status.STOPPED, {"trigger": "max_iters", "elapsed_s": elapsed}))
    for i, (status, fields) in enumerate(records, 1):
        store.append(Record(i, status, **fields))
    return root


@pytest.fixture
def arms(tmp_path):
    """good: reaches the target 0.05 at experiments 3 and 4 in two of three started repeats; bad: never
    (its 0.01 is infeasible and must not count); none: no feasible run at all."""
    good = [[0.86, 0.5, 0.04, 0.03], [0.86, 0.2, 0.1, 0.045], [0.86, 0.3, 0.2, 0.1]]
    for i, metrics in enumerate(good):
        fake_campaign(tmp_path / "good" / f"repeat-{i:02d}", metrics, step_s=2.0)
    (tmp_path / "good" / "repeat-03").mkdir()  # an interrupted group had not started this one
    (tmp_path / "good" / "repeat-03" / "campaign.json").write_text("{}")
    fake_campaign(tmp_path / "bad1", [0.86, 0.9, 0.7, 0.6])
    fake_campaign(tmp_path / "bad2", [0.86, 0.01, 0.8, 0.7], infeasible={1})
    fake_campaign(tmp_path / "bad3", [0.86, None, 0.75, 0.65])
    fake_campaign(tmp_path / "none", [0.86, 0.5], infeasible={0, 1})
    return tmp_path


def test_known_ordering(arms, capsys):
    out = arms / "cmp"
    bad = ",".join(str(arms / f"bad{i}") for i in (1, 2, 3))
    assert (
        main(["compare", str(arms / "good"), str(arms / "none"), "--arm", f"bad={bad}", "--out", str(out)])
        == 0
    )
    printed = capsys.readouterr().out
    assert "## Final best after 4 experiments" in printed and f"written: {out / 'compare.md'}" in printed
    for figure in ("best_so_far.png", "best_so_far_wallclock.png", "performance_profile.png"):
        assert (out / figure).stat().st_size > 10_000
    md = (out / "compare.md").read_text()
    rows = {line.split(" | ")[0][2:]: line for line in md.splitlines() if line.startswith("| ")}
    # good: finals 0.03, 0.045, 0.1: median 0.045, IQM (n=3 trims nothing) 0.05833 = +80.2 sigma.
    good = md.split("## Final best")[1].splitlines()[4]
    assert good.startswith("| good | 3 | 0.045 [") and "| 0.05833 [" in good and "; +80.2σ [" in good
    assert "| 2/3 (67%, 95% CI 21%–94%) | 4 |" in good  # experiments to target: [3, 4, never]
    assert "| 0/3 (0%, 95% CI 0%–56%) | >4 |" in md
    assert "| none | 1 | none feasible | none feasible | 0/1" in md
    assert "- Note: good: not started yet, left out: repeat-03." in md
    assert rows["good"].endswith("| — | 1.00 [1.00, 1.00] | 1.00 [1.00, 1.00] |")  # P(good beats none, bad)
    assert rows["bad"].startswith("| bad | 0.00 [0.00, 0.00] | 1.00") and "Seed noise σ = 0.01" in md
    data = json.loads((out / "compare.json").read_text())
    assert data["arms"]["good"]["iqm"]["point"] == pytest.approx([0.86, 1 / 3, 0.34 / 3, 0.175 / 3])
    assert data["arms"]["bad"]["finals"] == [0.6, 0.7, 0.65] and data["arms"]["none"]["finals"] == [None]
    assert data["arms"]["bad"]["experiments"] == [4, 4, 4]  # the invalid turn is no experiment
    assert data["improvement"]["good > bad"]["p"] == 1.0


def test_directories_inside_the_working_directory_are_written_relative(arms, monkeypatch):
    monkeypatch.chdir(arms)  # as from a repository's root: committed comparisons name no machine
    assert main(["compare", str(arms / "good"), str(arms / "bad1"), "--out", "cmp"]) == 0
    data = json.loads((arms / "cmp" / "compare.json").read_text())
    assert data["arms"]["good"]["dirs"][:2] == ["good/repeat-00", "good/repeat-01"]
    md = (arms / "cmp" / "compare.md").read_text().splitlines()
    assert any(line.startswith("| good | scripted |") and line.endswith("| good |") for line in md)


def test_budget_and_noise_units(arms):
    found = load_arms([("good", [arms / "good"]), ("bad", [arms / f"bad{i}" for i in (1, 2, 3)])])
    a = analyse(found, budget=2, n_resamples=200)
    assert a.budget == 2 and a.summaries["good"]["finals"].tolist() == [0.5, 0.2, 0.3]
    assert a.summaries["bad"]["finals"].tolist() == [0.86, 0.86, 0.86]  # the infeasible 0.01 does not count
    assert a.noise == {
        "sigma": 0.01,
        "reference": 0.86,
        "note": "measured by `autoresearch noise`, K = 5 seeds",
    }
    assert analyse(found, sigma=0.5, n_resamples=200).noise["sigma"] == 0.5
    assert analyse(found, budget=99, n_resamples=200).budget == 4  # capped at the longest campaign


def test_arms_that_cannot_be_compared(arms, tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["compare", str(tmp_path / "empty")]) == 2
    assert "no campaign here (no campaign.json) and no repeat-*/ sub-campaigns" in capsys.readouterr().err
    other = fake_campaign(tmp_path / "other", [1.0])
    registry = json.loads((other / "family.json").read_text())
    write_json_atomic(other / "family.json", {**registry, "direction": "maximize"})
    assert main(["compare", str(arms / "good"), str(other)]) == 2
    assert "direction 'minimize' vs 'maximize'" in capsys.readouterr().err
    with pytest.raises(CompareError, match="two arms are named 'good'"):
        load_arms([("good", [arms / "good"]), ("good", [arms / "bad1"])])
    with pytest.raises(SystemExit):
        main(["compare", "--arm", "nodirs="])
    assert "expected NAME=DIR[,DIR...]" in capsys.readouterr().err
    (arms / "bad1" / "proposals.jsonl").unlink()
    assert main(["compare", str(arms / "bad1")]) == 2
    assert "not a campaign directory: proposals.jsonl is missing" in capsys.readouterr().err


def test_end_to_end_after_loop_repeats(tmp_path, capsys):
    toy, runs = copy_toy(tmp_path), tmp_path / "runs"
    common = ["--family", str(toy), "--max-iters", "5", "--plateau-window", "20", "--repeats", "2"]
    for proposer in ("tpe", "random"):
        args = ["loop", *common, "--proposer", proposer, "--campaign", str(runs / f"toy-{proposer}")]
        assert main([*args, "--workers", "2"]) == 0
    capsys.readouterr()
    single = str(runs / "toy-tpe" / "repeat-00")
    assert main(["compare", str(runs / "toy-tpe"), str(runs / "toy-random"), "--arm", f"one={single}"]) == 0
    (out,) = runs.glob("compare-*")  # default: beside the first arm
    md = (out / "compare.md").read_text()
    assert "| toy-tpe | tpe | 2 | 5 | 2 of 2 |" in md and "| one | tpe | 1 | 5 |" in md
    assert "No measured seed noise" in md and "| toy-random | 0." in md
    # The baseline is every arm's first experiment: at a budget of 1 all arms agree exactly.
    first = next(line for line in md.splitlines() if line.startswith("| 1 | "))
    baseline = json.loads((toy / "family.json").read_text())["baseline"]["metric"]
    assert first.count(f"{baseline:.4g}") == 3 + 2 * 2  # a point everywhere, a degenerate interval for n=2
    data = json.loads((out / "compare.json").read_text())
    assert data["arms"]["one"]["iqm"]["low"][-1] is None  # one repeat: no interval


def test_a_campaign_that_never_ran_an_experiment(arms, tmp_path):
    fake_campaign(tmp_path / "empty", [])  # e.g. stopped at once by prepare.py --check
    found = load_arms([("good", [arms / "good"]), ("empty", [tmp_path / "empty"])])
    md = write_comparison(found, tmp_path / "out", n_resamples=200).read_text()
    assert "| empty | 1 | none feasible | none feasible | 0/1" in md
    assert (tmp_path / "out" / "best_so_far_wallclock.png").exists()
