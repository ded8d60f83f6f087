"""Issue 39: what a newcomer hit in the first hour. The audit's random arm draws its own stream, a
run's verdict names the noise it was judged against, a group resumes from any directory, the setup
shows its progress, the stop line is not numbered as an experiment, and search.png spans the
experiments with its legend beside the data."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

from loop_helpers import copy_toy
from matplotlib.backends.backend_agg import FigureCanvasAgg

from autoresearch.audit.figures import PlottedArm, recipe_figure, search_figure
from autoresearch.campaign import Campaign, Status
from autoresearch.family import Family
from autoresearch.journal import read_json, read_jsonl

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "autoresearch"]


def _cli(*args, cwd=None) -> subprocess.CompletedProcess:
    done = subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=300, cwd=cwd)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    return done


def _random_loop(toy: Path, campaign: Path, iterations: int, *extra) -> subprocess.CompletedProcess:
    random = ["--proposer", "random", "--space", "random-range", "--seed", 0, "--max-iters", iterations]
    return _cli("loop", "--family", toy, *random, "--campaign", campaign, "--plain", *extra)


def _drawn(root: Path) -> list[dict]:
    return [
        r["config"] for r in read_jsonl(root / "proposals.jsonl") if r["proposer"] == "random" and r["config"]
    ]


def test_the_random_arm_never_repeats_a_random_campaigns_draws(tmp_path):
    """Item 4: a --proposer random campaign and the audit's random arm at the same seed drew the same
    configurations ("tie, -0.00 sigma")."""
    toy, campaign = copy_toy(tmp_path), tmp_path / "c"
    _random_loop(toy, campaign, 5)
    _cli("random", "--budget-from", campaign, "--seed", 0, "--out", tmp_path / "arm")
    ours, arms = _drawn(campaign), _drawn(tmp_path / "arm")
    assert len(ours) == len(arms) == 4
    assert not [config for config in arms if config in ours]


def test_a_verdict_names_the_noise_it_was_judged_against_and_the_report_says_which_predate_it(tmp_path):
    """Item 5: a run judged 'within noise' against 5 % of the best before the seed noise was measured
    can be 'regressed' against the measured noise: each record says which, and so does the report."""
    toy, campaign = copy_toy(tmp_path), tmp_path / "c"
    shown = _random_loop(toy, campaign, 3).stdout
    assert "against 5% of the best" in shown and "no seed noise measured yet" in shown
    early = [r for r in read_jsonl(campaign / "proposals.jsonl") if r["verdict_noise"]]
    assert len(early) == 2 and {r["verdict"] for r in early} <= {"confirmed", "regressed", "within noise"}
    assert all(r["verdict_noise"]["measured_at"] is None for r in early)
    for record in early:  # 5 % of the best before it
        best = max(
            (r for r in read_jsonl(campaign / "proposals.jsonl") if r["iteration"] < record["iteration"]),
            key=lambda r: r["iteration"],
        )["best_so_far"]
        assert record["verdict_noise"]["sigma"] == 0.05 * abs(best)
    _cli("noise", "--campaign", campaign, "--family", toy, "--seeds", 3)
    noise = read_json(toy / "ledger.json")["seed_noise"]
    shown = _random_loop(toy, campaign, 5, "--resume").stdout
    later = [r for r in read_jsonl(campaign / "proposals.jsonl") if r["iteration"] > 4 and r["verdict_noise"]]
    assert later and all(
        r["verdict_noise"] == {"sigma": noise["std"], "k": 3, "measured_at": noise["measured_at"]}
        for r in later
    )
    assert f"against seed noise σ {noise['std']:.3g}" in shown
    _cli("audit", "--campaign", campaign, "--seeds", 2, "--top", 1, "--count", 2)
    text = (campaign / "report.md").read_text()
    assert (
        f"Run verdicts judged before the seed noise this audit used was measured ({noise['measured_at']})"
        in text
    )
    assert f"{len(early)} of {len(early) + len(later)} in agent (random)" in text


def test_a_group_resumes_from_inside_its_familys_directory(tmp_path):
    """Item 9: `loop --resume --campaign ../runs/d` from inside the family found no family 'dock'."""
    _cli("init", tmp_path / "dock")
    loop = ["loop", "--family", "dock", "--proposer", "random", "--max-iters", 2, "--plain"]
    _cli(*loop, "--repeats", 2, "--campaign", "runs/d", cwd=tmp_path)
    done = _cli("loop", "--resume", "--campaign", "../runs/d", "--max-iters", 3, cwd=tmp_path / "dock")
    assert "repeat-01 (seed 1): stopped (max_iters), 3 iterations" in done.stdout
    done = _cli(
        "loop", "--resume", "--campaign", "../runs/d/repeat-00", "--max-iters", 4, cwd=tmp_path / "dock"
    )
    assert "iterations: 4" in done.stdout


def test_the_setup_says_what_it_installs_and_lets_pip_show_its_progress(tmp_path):
    """Item 12: `bash scripts/main.sh` showed nothing for three minutes while pip installed quietly. A
    stand-in interpreter: torch is missing, and pip prints how it was asked."""
    python = tmp_path / "venv" / "bin" / "python"
    python.parent.mkdir(parents=True)
    python.write_text('#!/bin/sh\n[ "$1" = "-c" ] && exit 1\necho "pip asked: $*"\n')
    python.chmod(0o755)
    env = {**os.environ, "VENV": str(tmp_path / "venv")}
    done = subprocess.run(
        ["bash", ROOT / "scripts" / "bootstrap.sh"], env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("[setup] installing torch==2.13.0 first: a download of hundreds of MB")
    assert lines[1] == "pip asked: -m pip install torch==2.13.0"  # not -q: its own progress shows
    assert lines[2].startswith("[setup] installing cwh-autoresearch and its dependencies (about a minute)")
    assert lines[3] == f"pip asked: -m pip install -e {ROOT}[all,dev]" and lines[4].startswith(
        "[setup] ready"
    )


def test_the_stop_line_is_not_numbered_as_an_experiment(tmp_path):
    """Item 13: `[it 5] ... reached the cap of 4`."""
    lines = _random_loop(copy_toy(tmp_path), tmp_path / "c", 4).stdout.splitlines()
    events = [line.split("]")[0] + "]" for line in lines if line.startswith("[")]
    assert events == ["[it 1]", "[it 2]", "[it 3]", "[it 4]", "[stop]"]
    (stop,) = [line for line in lines if line.startswith("[stop]")]
    assert stop.startswith("[stop] random: stopped: max_iters 4 iterations reached the cap of 4")
    assert lines[0].startswith("loop: family toy, proposer random")  # the banner comes first


def test_the_search_figure_spans_the_experiments_and_keeps_its_legend_off_the_data(tmp_path):
    """Item 14: the x-axis ran one past the experiments (the stop record) and the legend covered the
    points; the title names the split it shows."""
    toy, campaign = copy_toy(tmp_path), tmp_path / "c"
    _random_loop(toy, campaign, 6)
    records = Campaign(campaign).records()
    assert records[-1].status is Status.STOPPED and records[-1].iteration == 7
    arm = PlottedArm("agent (random)", "#2ca02c", records)
    fig = search_figure([arm], Family.load(toy), None, tmp_path / "search.png")
    (ax,) = fig.axes
    assert ax.get_xlim() == (0.5, 6.5) and "on the search split" in ax.get_title()
    renderer = FigureCanvasAgg(fig).get_renderer()
    legend, plot = ax.get_legend().get_window_extent(renderer), ax.get_window_extent(renderer)
    assert legend.x0 > plot.x1  # beside the plot, not over it
    line = next(line for line in ax.get_lines() if line.get_label().endswith("best so far"))
    assert max(line.get_xdata()) == 6


def test_the_figures_show_only_what_was_searched_with_units_and_every_run(tmp_path):
    """Issue 59: recipe.png drew the parameters a protocol held as flat lines, without axis labels;
    search.png's y-axis was a raw key, and a run that timed out was not drawn."""
    toy = copy_toy(tmp_path)
    registry = json.loads((toy / "family.json").read_text())
    registry["protocols"] = {"narrow": {"exclude_axes": ["regularization"]}}
    registry["metric_label"] = "toy loss (nats)"
    (toy / "family.json").write_text(json.dumps(registry))
    campaign = tmp_path / "c"
    _random_loop(toy, campaign, 3, "--protocol", "narrow")
    family = Family.load(toy).under_protocol("narrow")
    records = Campaign(campaign).records()
    fig = recipe_figure(records, family, tmp_path / "recipe.png", Campaign(campaign).registry())
    titles = [ax.get_title() for ax in fig.axes]
    assert titles and not any(t.startswith(("USE_NORM", "DROPOUT")) for t in titles), titles
    assert any(t.startswith("LEARNING_RATE") for t in titles)
    assert all(ax.get_ylabel() for ax in fig.axes) and any(ax.get_xlabel() == "experiment" for ax in fig.axes)
    assert "on the search split" in fig._suptitle.get_text()
    # A run that came back without a metric is drawn on the top edge, labelled.
    timed_out = replace(records[1], status=Status.FAILED, metric=None, run_status="timeout")
    arm = PlottedArm("random arm", "#1f77b4", [records[0], timed_out, *records[2:]])
    (ax,) = search_figure([arm], family, None, tmp_path / "search.png").axes
    assert ax.get_ylabel() == "toy loss (nats) (lower is better)"
    labels = ax.get_legend_handles_labels()[1]
    assert "random arm: did not finish (failed or timed out)" in labels
