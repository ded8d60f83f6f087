import json
import subprocess
import sys

import pytest

from autoresearch.journal import Journal, JournalError, append_jsonl, read_json, read_jsonl, write_json_atomic


def test_append_and_read_back(tmp_path):
    path = tmp_path / "log.jsonl"
    records = [{"i": 1, "text": "two\nlines"}, {"i": 2, "x": float("nan")}, [1, 2]]
    for r in records:
        append_jsonl(path, r)
    assert path.read_text().count("\n") == 3
    got = read_jsonl(path)
    assert got[0] == records[0] and got[2] == [1, 2] and got[1]["x"] != got[1]["x"]  # NaN survives
    assert read_jsonl(tmp_path / "missing.jsonl") == []


def test_torn_last_line_is_moved_aside_not_glued(tmp_path):
    path = tmp_path / "log.jsonl"
    append_jsonl(path, {"i": 1})
    with open(path, "ab") as f:
        f.write(b'{"i": 2, "half')  # a crash in the middle of a write
    assert read_jsonl(path) == [{"i": 1}]  # readers skip the unterminated line
    journal = Journal(path)
    assert journal.read() == [{"i": 1}] and path.read_bytes().endswith(b"half")  # opening writes nothing
    assert journal.repair()  # what a writer does first
    journal.append({"i": 3})
    assert read_jsonl(path) == [{"i": 1}, {"i": 3}]
    assert (tmp_path / "log.jsonl.torn").read_bytes() == b'{"i": 2, "half\n'
    assert not Journal(path).repair()  # a clean file is left alone


def test_torn_first_and_only_line(tmp_path):
    path = tmp_path / "log.jsonl"
    path.write_bytes(b'{"x"')
    journal = Journal(path)
    journal.repair()
    journal.append({"ok": True})
    assert read_jsonl(path) == [{"ok": True}]


def test_corrupt_complete_line_is_an_error(tmp_path):
    path = tmp_path / "log.jsonl"
    path.write_text('{"i": 1}\nnot json\n')
    with pytest.raises(JournalError, match=r"log.jsonl:2"):
        read_jsonl(path)


WRITER = """
import sys
from autoresearch.journal import append_jsonl
path, who = sys.argv[1], int(sys.argv[2])
for i in range(100):
    append_jsonl(path, {"who": who, "i": i, "pad": "x" * (20000 + 997 * who)})
"""


def test_concurrent_appends_from_processes_never_interleave(tmp_path):
    path = tmp_path / "log.jsonl"
    procs = [subprocess.Popen([sys.executable, "-c", WRITER, str(path), str(w)]) for w in range(4)]
    assert [p.wait(timeout=60) for p in procs] == [0, 0, 0, 0]
    records = read_jsonl(path)  # raises if any line were interleaved
    assert len(records) == 400
    for w in range(4):
        mine = [r for r in records if r["who"] == w]
        assert [r["i"] for r in mine] == list(range(100))
        assert all(len(r["pad"]) == 20000 + 997 * w for r in mine)


def test_write_json_atomic(tmp_path):
    path = tmp_path / "state.json"
    write_json_atomic(path, {"a": 1})
    write_json_atomic(path, {"a": 2, "b": [1, 2]})
    assert read_json(path) == {"a": 2, "b": [1, 2]}
    assert json.loads(path.read_text()) == {"a": 2, "b": [1, 2]}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["state.json"]  # no temp file left behind
    with pytest.raises(TypeError):
        write_json_atomic(path, {"bad": object()})
    assert read_json(path) == {"a": 2, "b": [1, 2]}  # a failed write leaves the old content
    assert sorted(p.name for p in tmp_path.iterdir()) == ["state.json"]
