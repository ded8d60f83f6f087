"""benchmarks/robust_safety.py on the first starts of the sealed split: the family's own constants,
every row at every dispersion level, and a table that says what it measured."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import robust_safety


@pytest.mark.needs("families")  # the task loads its family's train.py, which imports torch
def test_a_short_run_writes_every_row_at_every_level(tmp_path):
    robust_safety.main(["--starts", "3", "--out", str(tmp_path)])
    payload = json.loads((tmp_path / "docking-constrained.json").read_text())
    assert payload["split"].startswith("docking-constrained/test")
    names = [row["controller"] for row in payload["rows"]]
    assert names == [
        "routed law + CBF",
        "routed law + CBF fed the truth (comparison)",
        "routed law + robust CBF (1σ bounds, k=3)",
        "routed law + robust CBF + navigation filter (1σ bounds, k=3)",
        "tube MPC (1σ bounds, k=3)",
        "tube MPC + navigation filter (1σ bounds, k=3)",
        "tube MPC + robust CBF + navigation filter (1σ bounds, k=3)",
        "routed law + covariance-sized robust CBF + navigation filter (k=3)",
        "tube MPC + covariance-sized robust CBF + navigation filter (1σ bounds, k=3)",
        "routed law + covariance-sized robust CBF with stop line + navigation filter (k=3)",
        "tube MPC + covariance-sized robust CBF with stop line + navigation filter (1σ bounds, k=3)",
    ]
    for row in payload["rows"]:
        assert row["starts"] == 3 and row["us_per_step"] > 0
        for level in ("1σ", "3σ"):
            assert set(row[level]["breaking"]) == {"keep_out", "speed", "cone"}
            assert all(0 <= count <= 3 for count in row[level]["breaking"].values())
    # Without dispersions, the nominal and the truth-fed filter are one flight.
    assert payload["rows"][0]["nominal"] == payload["rows"][1]["nominal"]
    table = (tmp_path / "docking-constrained.md").read_text()
    assert "--starts 3" in table and table.count("| routed law") == 6
    # On the navigation filter a nominal flight has no innovation: the robust CBF flies as on the state.
    assert payload["rows"][3]["nominal"] == payload["rows"][2]["nominal"]
    for tube in [row for row in payload["rows"] if row["controller"].startswith("tube")]:
        for level in ("nominal", "1σ", "3σ"):  # one plan per start, at every level
            assert sum(tube[level]["plans"].values()) == 3
    assert "Tube MPC plans, one per episode" in table
    # Without dispersions the filter sees no innovation: the filtered tube MPC flies as the plain one.
    assert payload["rows"][5]["nominal"]["success"] == payload["rows"][4]["nominal"]["success"]

    # --rows flies the rows named and keeps the others as they were, each with its own command.
    robust_safety.main(["--starts", "3", "--out", str(tmp_path), "--rows", "routed law + CBF fed"])
    again = json.loads((tmp_path / "docking-constrained.json").read_text())
    assert [row["controller"] for row in again["rows"]] == names
    assert again["rows"][0] == payload["rows"][0]
    assert again["rows"][1]["command"].endswith("--rows routed law + CBF fed")
    assert again["rows"][1]["1σ"] == payload["rows"][1]["1σ"]  # the same flight, flown again

    # --retime measures only the named rows' µs column again; their flights stay, and the table says so.
    robust_safety.main(["--starts", "3", "--out", str(tmp_path), "--rows", "tube MPC (1σ", "--retime"])
    retimed = json.loads((tmp_path / "docking-constrained.json").read_text())
    tube = retimed["rows"][4]
    assert tube["retimed_by"].endswith("--retime") and tube["command"] == again["rows"][4]["command"]
    assert {k: v for k, v in tube.items() if k not in ("us_per_step", "retimed_by")} == {
        k: v for k, v in again["rows"][4].items() if k != "us_per_step"
    }
    assert [row for i, row in enumerate(retimed["rows"]) if i != 4] == [
        row for i, row in enumerate(again["rows"]) if i != 4
    ]
    assert (
        "µs/step of tube MPC (1σ bounds, k=3) measured again, alone"
        in (tmp_path / "docking-constrained.md").read_text()
    )
    with pytest.raises(SystemExit, match="--retime needs --rows"):
        robust_safety.main(["--starts", "3", "--out", str(tmp_path), "--retime"])
    with pytest.raises(SystemExit, match="no measured row"):
        robust_safety.main(["--starts", "3", "--out", str(tmp_path / "empty"), "--rows", "tube", "--retime"])


def test_retimed_note_names_the_rows_or_says_every_row():
    rows = [{"controller": "a", "retimed_by": "cmd"}, {"controller": "b"}]
    assert robust_safety.retimed_note(rows) == ["µs/step of a measured again, alone, by `cmd`."]
    rows[1]["retimed_by"] = "cmd"
    assert robust_safety.retimed_note(rows) == ["µs/step of every row measured again, alone, by `cmd`."]
    rows[1]["retimed_by"] = "other"
    assert len(robust_safety.retimed_note(rows)) == 2
