"""``autoresearch loop --repeats N``: N ordinary campaigns of one arm, resumable after a real kill."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from loop_helpers import copy_toy
from test_resume import check_trail, processes_under

from autoresearch.campaign.group import GroupError, is_group, plan_group, repeat_dirs
from autoresearch.cli import main
from autoresearch.family import Family
from autoresearch.journal import read_json, read_jsonl
from autoresearch.loop.repeats import CHILD

LOOP = [sys.executable, "-m", "autoresearch", "loop"]


def records_of(group: Path) -> dict[str, list[dict]]:
    return {d.name: read_jsonl(d / "proposals.jsonl") for d in repeat_dirs(group)}


def wait_for(predicate, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def repeat_processes(group: Path) -> list[int]:
    """Pids of the loop processes running the repeats of ``group``."""
    found = []
    for entry in Path("/proc").iterdir():
        try:
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if CHILD.encode() in cmdline and any(
            a.startswith(str(group).encode() + b"/repeat-") for a in cmdline
        ):
            found.append(int(entry.name))
    # A child caught between fork and exec still shows its parent's command line: count loops, not those.
    return [pid for pid in found if parent_of(pid) not in found]


def parent_of(pid: int) -> int | None:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return int(stat.rsplit(")", 1)[1].split()[1])


def test_repeats_survive_kill_9_and_sigterm_then_resume(tmp_path):
    toy, group = copy_toy(tmp_path), tmp_path / "g"
    cmd = [*LOOP, "--family", str(toy), "--proposer", "tpe", "--repeats", "3", "--max-iters", "6"]
    cmd += ["--plateau-window", "20", "--campaign", str(group), "--workers", "2"]
    slow = {**os.environ, "TOY_SLEEP_S": "0.2"}

    def in_flight() -> bool:
        done = sum(len(r) for r in records_of(group).values())
        return done >= 3 and any(p.name == "process.json" for p in group.glob("repeat-*/runs/*/process.json"))

    # Session 1: SIGKILL mid-way to the command's process group and to each repeat's loop process (its own
    # session); the training runs survive as orphans.
    proc = subprocess.Popen(
        cmd, env=slow, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    wait_for(lambda: group.exists() and in_flight())
    loops = repeat_processes(group)
    os.killpg(proc.pid, signal.SIGKILL)
    for pid in loops:
        os.kill(pid, signal.SIGKILL)
    proc.wait()
    assert len(loops) == 2  # --workers 2
    before = records_of(group)
    assert 3 <= sum(map(len, before.values())) < 3 * 7

    # Session 2: the same command resumes; SIGTERM cancels every repeat in flight promptly (exit 130).
    proc = subprocess.Popen(cmd, env=slow, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wait_for(lambda: len(read_json(group / "repeats.json")["sessions"]) == 2)
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    started = time.monotonic()
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 130 and time.monotonic() - started < 10
    assert "resume with: autoresearch loop --resume --campaign" in err

    # Session 3: resumed to the end.
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("(max_iters), 6 iterations") == 3, done.stdout[-800:]
    meta = read_json(group / "repeats.json")
    assert (meta["proposer"], meta["repeats"], meta["seeds"], len(meta["sessions"])) == (
        "tpe",
        3,
        [0, 1, 2],
        3,
    )
    baselines = []
    for i, campaign in enumerate(repeat_dirs(group)):
        records = check_trail(campaign)  # contiguous iterations, no duplicated run id, runs.jsonl agrees
        assert len(records) == 7 and records[-1]["trigger"] == "max_iters"
        assert read_json(campaign / "campaign.json")["settings"]["seed"] == i
        baselines.append((records[0]["proposer"], records[0]["config"], records[0]["metric"]))
    assert len({repr(b) for b in baselines}) == 1 and baselines[0][0] == "baseline"  # shared first experiment
    assert processes_under(group) == []


def test_a_repeat_is_the_plain_campaign_with_its_seed_and_the_group_can_grow(tmp_path, capsys):
    toy, group = copy_toy(tmp_path), tmp_path / "g"
    common = ["--family", str(toy), "--proposer", "tpe", "--max-iters", "5", "--plateau-window", "20"]
    assert main(["loop", *common, "--seed", "4", "--campaign", str(tmp_path / "single")]) == 0
    assert main(["loop", *common, "--seed", "3", "--repeats", "2", "--campaign", str(group)]) == 0
    out = capsys.readouterr().out
    assert "[repeat-01] [it 5] tpe:" in out and "seeds [3, 4]" in out
    single = read_jsonl(tmp_path / "single" / "proposals.jsonl")
    second = read_jsonl(group / "repeat-01" / "proposals.jsonl")
    assert [r["config"] for r in second] == [r["config"] for r in single]  # repeat i = seed + i
    assert [r["metric"] for r in second] == [r["metric"] for r in single]

    # A larger --repeats adds repeats with the next seeds; the finished ones end at once, writing nothing.
    finished = (group / "repeat-00" / "proposals.jsonl").read_bytes()
    assert main(["loop", "--resume", "--campaign", str(group), "--repeats", "3", "--workers", "3"]) == 0
    out = capsys.readouterr().out
    assert "repeat-00 (seed 3): already_finished (max_iters)" in out
    assert "repeat-02 (seed 5): stopped (max_iters)" in out
    assert (group / "repeat-00" / "proposals.jsonl").read_bytes() == finished
    assert len(read_json(group / "repeat-00" / "campaign.json")["sessions"]) == 2  # one per session run
    assert read_json(group / "repeats.json")["seeds"] == [3, 4, 5]
    assert read_json(group / "repeat-02" / "campaign.json")["group"]["repeat"] == 2


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--repeats", "1"], "holds 2 repeats; --repeats 1 cannot shrink it"),
        (["--proposer", "random"], "is a group of proposer 'tpe', not 'random'"),
        (["--seed", "7"], "this group's seeds start at 0; --seed cannot change"),
    ],
)
def test_a_group_is_one_arm(tmp_path, capsys, flags, message):
    toy, group = copy_toy(tmp_path), tmp_path / "g"
    session = {"started": "now", "argv": []}
    plan_group(
        group, family=Family.load(toy), proposer="tpe", settings={"seed": 0}, repeats=2, session=session
    ).write()
    assert is_group(group) and [d.name for d in repeat_dirs(group)] == ["repeat-00", "repeat-01"]
    assert main(["loop", "--campaign", str(group), *flags]) == 2
    assert message in capsys.readouterr().err


def test_bad_group_directories_are_refused(tmp_path, capsys):
    toy = copy_toy(tmp_path)
    family = Family.load(toy)
    (tmp_path / "single").mkdir()
    (tmp_path / "single" / "campaign.json").write_text("{}")
    with pytest.raises(GroupError, match="is a single campaign, not a group"):
        plan_group(tmp_path / "single", family=family, proposer="tpe", settings={}, repeats=2, session={})
    assert main(["loop", "--resume", "--campaign", str(tmp_path / "nothing"), "--repeats", "2"]) == 2
    assert "--family is required" in capsys.readouterr().err
    assert main(["loop", "--family", str(toy), "--proposer", "tpe", "--workers", "0"]) == 2
    assert "--workers must be >= 1 (got 0)" in capsys.readouterr().err


def test_a_broken_repeat_is_reported_and_the_others_run(tmp_path, capsys):
    toy, group = copy_toy(tmp_path), tmp_path / "g"
    args = ["loop", "--family", str(toy), "--proposer", "random", "--repeats", "2", "--max-iters", "3"]
    assert main([*args, "--campaign", str(group)]) == 0
    (group / "repeat-00" / "proposals.jsonl").write_text("not json\n")
    assert main([*args, "--campaign", str(group), "--max-iters", "6"]) == 2
    out = capsys.readouterr().out
    assert "repeat-00: error (exit 2): autoresearch loop: error:" in out and "not a JSON line" in out
    # six iterations: the first session's stop record is not one of them
    assert "repeat-01 (seed 1): stopped (max_iters), 6 iterations" in out


@pytest.mark.slow
def test_repeats_on_ray_match_the_local_pool(ray_instance, tmp_path):
    toy = copy_toy(tmp_path)
    args = ["loop", "--family", str(toy), "--proposer", "random", "--repeats", "2", "--max-iters", "3"]
    assert main([*args, "--campaign", str(tmp_path / "pool"), "--workers", "2"]) == 0
    assert main([*args, "--campaign", str(tmp_path / "ray"), "--workers", "2", "--executor", "ray"]) == 0
    pool, ray = records_of(tmp_path / "pool"), records_of(tmp_path / "ray")
    ran_on_ray = [d / "remote.json" for d in (tmp_path / "ray").glob("repeat-*/runs/*")]
    assert len(ran_on_ray) == 6 and all(p.is_file() for p in ran_on_ray)  # each repeat's runs: Ray tasks
    assert "RAY_ADDRESS" not in os.environ  # given to the repeats' loops only while the group ran
    assert {k: [(r["config"], r["metric"]) for r in v] for k, v in ray.items()} == {
        k: [(r["config"], r["metric"]) for r in v] for k, v in pool.items()
    }
