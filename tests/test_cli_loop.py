import io
import json
import subprocess
import sys

import pytest
from extras import missing_extras
from loop_helpers import copy_toy

from autoresearch.campaign import Record, Status
from autoresearch.cli import main
from autoresearch.journal import read_json, read_jsonl
from autoresearch.loop.live import PlainView, RichView
from autoresearch.proposers.base import Proposal


@pytest.fixture
def toy(tmp_path):
    return copy_toy(tmp_path)


def loop(*args):
    return main(["loop", *map(str, args)])


def test_no_key_and_no_proposer_is_a_clear_usage_error(toy, tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("ANTHROPIC_API_KEY", raising=False)
    assert loop("--family", toy, "--campaign", tmp_path / "c") == 2
    err = capsys.readouterr().err
    assert "ANTHROPIC_API_KEY is not set" in err and "--proposer random" in err and "--proposer tpe" in err
    assert not (tmp_path / "c").exists()
    assert loop("--family", toy, "--proposer", "anthropic", "--campaign", tmp_path / "c") == 2
    # Without the SDK, the one line names the extra first (tests/test_install.py).
    needed = "cwh-autoresearch[llm]" if missing_extras(["llm"]) else "needs ANTHROPIC_API_KEY"
    assert needed in capsys.readouterr().err


def test_random_campaign_end_to_end_as_a_subprocess(toy, tmp_path):
    campaign = tmp_path / "c"
    cmd = [sys.executable, "-m", "autoresearch", "loop", "--family", str(toy), "--proposer", "random"]
    proc = subprocess.run(
        [*cmd, "--max-iters", "8", "--seed", "3", "--campaign", str(campaign)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert f"campaign: {campaign}" in proc.stdout and "[it 8] random:" in proc.stdout
    records = read_jsonl(campaign / "proposals.jsonl")
    assert [r["iteration"] for r in records] == list(range(1, 10)) and records[-1]["trigger"] == "max_iters"
    assert [r["proposer"] for r in records[:2]] == ["baseline", "random"]
    meta = read_json(campaign / "campaign.json")
    assert (
        meta["proposer"] == "random"
        and meta["settings"]["seed"] == 3
        and meta["family"] == str(toy.resolve())
    )
    # Random search always proposes full configurations, all distinct.
    configs = {json.dumps(r["config"], sort_keys=True) for r in records if r["run_id"]}
    assert len(configs) == 8


def test_tpe_campaign_end_to_end(toy, tmp_path, capsys):
    args = ("--family", toy, "--proposer", "tpe", "--max-iters", 12, "--plateau-window", 20, "--seed", 5)
    assert loop(*args, "--campaign", tmp_path / "c") == 0
    records = read_jsonl(tmp_path / "c" / "proposals.jsonl")
    assert len(records) == 13 and all(r["status"] == "ran" for r in records[:12])
    assert records[1]["proposer"] == "tpe" and records[-1]["trigger"] == "max_iters"
    assert "ended: stopped (max_iters)" in capsys.readouterr().out


def test_enqueued_configurations_run_first_then_tpe_takes_over(toy, tmp_path, capsys):
    queue = tmp_path / "queue.json"
    queue.write_text(json.dumps([{"EPOCHS": 30, "ACTIVATION": "relu"}, {"LEARNING_RATE": 0.05}]))
    campaign = tmp_path / "c"
    args = ("--family", toy, "--proposer", "tpe", "--plateau-window", 20, "--campaign", campaign)
    assert loop(*args, "--enqueue", queue, "--max-iters", 2) == 0
    assert loop("--resume", "--campaign", campaign, "--max-iters", 6) == 0  # the queue is in campaign.json
    records = [r for r in read_jsonl(campaign / "proposals.jsonl") if r["status"] == "ran"]
    baseline = json.loads((toy / "family.json").read_text())["baseline"]["config"]
    assert [r["config"] for r in records[:3]] == [
        baseline,
        {**baseline, "EPOCHS": 30, "ACTIVATION": "relu"},
        {**baseline, "LEARNING_RATE": 0.05},
    ]
    hypotheses = [r["proposal"]["annotation"]["hypothesis"] for r in records[1:]]
    assert ["enqueued" in h for h in hypotheses] == [
        True,
        True,
        False,
        False,
        False,
    ]  # the second after the resume
    assert len(records) == 6 and all(h.startswith("TPE suggestion") for h in hypotheses[2:])
    assert len({json.dumps(r["config"], sort_keys=True) for r in records}) == 6  # each ran once

    queue.write_text(json.dumps({"EPOCHS": 999}))
    assert loop("--family", toy, "--proposer", "tpe", "--enqueue", queue, "--campaign", tmp_path / "d") == 2
    assert "--enqueue entry 1" in capsys.readouterr().err and not (tmp_path / "d").exists()
    queue.write_text("[")
    with pytest.raises(SystemExit):
        loop("--family", toy, "--proposer", "tpe", "--enqueue", queue)
    assert "--enqueue" in capsys.readouterr().err


def test_bad_input_is_refused_with_exit_code_2(toy, tmp_path, capsys):
    assert loop("--family", tmp_path / "nope", "--proposer", "random") == 2
    assert "no family" in capsys.readouterr().err
    (toy / "prepare.py").unlink()
    assert loop("--family", toy, "--proposer", "random") == 2
    assert "missing prepare.py" in capsys.readouterr().err
    assert loop("--resume", "--proposer", "random") == 2
    assert "--resume needs --campaign" in capsys.readouterr().err
    assert loop("--proposer", "random") == 2
    assert "--family is required" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:
        loop("--family", toy, "--proposer", "random", "--max-iters", 0)
    assert exit_.value.code == 2 and "expected a positive int" in capsys.readouterr().err


def test_family_by_name_default_campaign_dir_and_existing_campaign(toy, tmp_path, monkeypatch, capsys):
    families = tmp_path / "proj" / "families"
    families.mkdir(parents=True)
    toy.rename(families / "toy")
    work = tmp_path / "proj" / "sub"
    work.mkdir()
    monkeypatch.chdir(work)
    assert loop("--family", "toy", "--proposer", "random", "--max-iters", 2) == 0
    (campaign,) = (work / "runs").iterdir()
    assert campaign.name.startswith("toy-random-")
    capsys.readouterr()
    assert loop("--family", "toy", "--proposer", "random", "--campaign", campaign) == 2
    assert "already exists; continue it with --resume" in capsys.readouterr().err
    assert loop("--resume", "--campaign", campaign, "--proposer", "tpe") == 2
    assert "proposer is random" in capsys.readouterr().err


def test_prepare_failure_stops_then_resume_continues(toy, tmp_path, capsys):
    good = (toy / "prepare.py").read_text()
    (toy / "prepare.py").write_text(
        "import sys\nsys.exit('expert cache missing: run prepare.py --warm-cache')\n"
    )
    campaign = tmp_path / "c"
    assert loop("--family", toy, "--proposer", "random", "--max-iters", 3, "--campaign", campaign) == 1
    (record,) = read_jsonl(campaign / "proposals.jsonl")
    assert record["status"] == "stopped" and record["trigger"] == "prepare_check"
    assert "expert cache missing" in record["reason"] and "expert cache missing" in capsys.readouterr().out
    (toy / "prepare.py").write_text(good)
    assert loop("--resume", "--campaign", campaign) == 0
    records = read_jsonl(campaign / "proposals.jsonl")
    assert [r["status"] for r in records] == ["stopped", "ran", "ran", "ran", "stopped"]  # three, as asked
    assert records[1]["proposer"] == "baseline" and records[-1]["trigger"] == "max_iters"


def test_resume_of_a_finished_campaign(toy, tmp_path, capsys):
    campaign = tmp_path / "c"
    assert loop("--family", toy, "--proposer", "random", "--max-iters", 2, "--campaign", campaign) == 0
    assert loop("--resume", "--campaign", campaign) == 0
    assert (
        "already_finished" in capsys.readouterr().out and len(read_jsonl(campaign / "proposals.jsonl")) == 3
    )
    assert loop("--resume", "--campaign", campaign, "--max-iters", 5) == 0  # a raised cap continues it
    records = read_jsonl(campaign / "proposals.jsonl")
    assert [r["status"] for r in records] == ["ran", "ran", "stopped", "ran", "ran", "ran", "stopped"]
    assert read_json(campaign / "campaign.json")["settings"]["max_iters"] == 5


def test_views_render_every_kind_of_record():
    records = [
        Record(
            1,
            Status.RAN,
            proposer="baseline",
            run_id="it0001",
            wall_seconds=0.5,
            metric=1.5,
            verdict="baseline",
            best_so_far=1.5,
            cumulative_cost_usd=0.0,
        ),
        Record(
            2, Status.INVALID, proposer="tpe", best_so_far=1.5, cumulative_cost_usd=0.01, reason="EPOCHS: bad"
        ),
        Record(
            3,
            Status.STOPPED,
            proposer="tpe",
            best_so_far=1.5,
            cumulative_cost_usd=0.01,
            reason="cap",
            trigger="max_iters",
        ),
    ]
    out = io.StringIO()
    plain = PlainView("loss", out)
    for r in records:
        plain.record(r, "iterations 3/3")
    lines = out.getvalue().splitlines()
    assert (
        lines[0].startswith("[it 1] baseline: it0001 (0.5s) loss=1.5 (baseline)")
        and "EPOCHS: bad" in lines[1]
    )
    assert "stopped: max_iters" in lines[2] and len(lines) == 3

    from rich.console import Console

    console = Console(file=io.StringIO(), force_terminal=True, width=200)
    view = RichView("loss", console=console)
    view.iteration_started(1)
    view.proposal(1, "baseline", Proposal(kind="propose", annotation={"hypothesis": "baseline config"}))
    view.run_started("it0001")
    view.run_progress(1.2)
    for r in records:
        view.record(r, "iterations 3/3")
    view.close()
    text = console.file.getvalue()
    assert (
        "baseline config" in text and "closest stop: iterations 3/3" in text and "stopped: max_iters" in text
    )


def test_at_120_columns_a_key_free_table_keeps_its_headers_and_shows_no_spend():
    """Issue 59: at 120 columns the table cut 'verdict' to 'verdi…' and showed $0.0000 for a key-free
    proposer, which spends nothing; the plain line said spend=$0.0000 too."""
    import io

    from rich.console import Console

    record = Record(
        1,
        Status.RAN,
        proposer="gp",
        run_id="it0001",
        wall_seconds=3.0,
        metric=0.5,
        verdict="baseline",
        best_so_far=0.5,
        cumulative_cost_usd=0.0,
    )
    console = Console(file=io.StringIO(), force_terminal=True, width=120)
    view = RichView("mean_terminal_distance", console=console, spend=False, run_limit=300)
    view.iteration_started(1)
    view.proposal(1, "gp", Proposal(kind="propose", overrides={"LEARNING_RATE": 0.0019101141930370157}))
    view.run_started("it0001")
    view.run_progress(41.0)
    table_text = _render(view._table(), 120)
    assert "verdict" in table_text and "spend" not in table_text and "it0001 41/300 s" in table_text
    assert "LEARNING_RATE=0.00191" in table_text  # rounded, not 0.0019101141930370157
    view.record(record, "iterations 1/4")
    view.close()
    out = io.StringIO()
    PlainView("loss", out, spend=False).record(record, "iterations 1/4")
    assert "spend" not in out.getvalue() and "best=0.5 |" in out.getvalue()


def _render(table, width: int) -> str:
    import io

    from rich.console import Console

    console = Console(file=io.StringIO(), width=width, force_terminal=False)
    console.print(table)
    return console.file.getvalue()
