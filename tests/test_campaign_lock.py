"""One process at a time writes a campaign; ``autoresearch check`` finds what two writers leave."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from loop_helpers import copy_toy

from autoresearch.campaign import CampaignError
from autoresearch.campaign.lock import LOCK_FILE, CampaignBusy, CampaignLock, holder
from autoresearch.cli import main
from autoresearch.journal import read_jsonl


def loop_cmd(campaign: Path, *args: str) -> list[str]:
    return [sys.executable, "-m", "autoresearch", "loop", "--campaign", str(campaign), "--plain", *args]


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    """A finished three-iteration campaign of the toy family (random proposer)."""
    tmp = tmp_path_factory.mktemp("lock")
    toy, root = copy_toy(tmp), tmp / "c"
    args = ["--family", str(toy), "--proposer", "random", "--max-iters", "3", "--seed", "1"]
    assert main(["loop", "--campaign", str(root), "--plain", *args]) == 0
    return root


def wait_for(condition, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def test_a_second_lock_on_a_campaign_is_refused_naming_the_holder(tmp_path):
    with CampaignLock(tmp_path, "verify"):
        assert holder(tmp_path) == f"pid {os.getpid()} (autoresearch verify)"
        with pytest.raises(CampaignBusy, match=f"in use by pid {os.getpid()} \\(autoresearch verify\\)"):
            CampaignLock(tmp_path, "loop").acquire()
    assert holder(tmp_path) is None
    with CampaignLock(tmp_path, "loop"):  # released: free again
        pass


def test_lock_path_mistakes_are_one_line_errors(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(CampaignError, match="is not a directory"):
        CampaignLock(tmp_path / "file", "verify").acquire()
    with pytest.raises(CampaignError, match="does not exist"):
        CampaignLock(tmp_path / "missing", "verify").acquire()
    with pytest.raises(CampaignError, match="cannot create the directory"):
        CampaignLock(tmp_path / "file" / "sub", "loop", create=True).acquire()


def test_two_concurrent_resumes_the_second_is_refused(campaign, tmp_path):
    # 5 runs of 1.5 s: the first still holds the campaign when the second has started up, even on a
    # loaded machine (where a Python start-up alone can take seconds)
    env = {**os.environ, "TOY_SLEEP_S": "1.5"}
    first = subprocess.Popen(
        loop_cmd(campaign, "--resume", "--max-iters", "8"),
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        wait_for(lambda: holder(campaign) == f"pid {first.pid} (autoresearch loop)")
        second = subprocess.run(
            loop_cmd(campaign, "--resume", "--max-iters", "8"), capture_output=True, text=True, timeout=60
        )
        assert second.returncode == 2
        assert second.stderr.strip().splitlines() == [
            f"autoresearch loop: error: {campaign} is in use by pid {first.pid} (autoresearch loop); "
            "one process at a time writes a campaign: wait for it to end or stop it"
        ]
        assert first.wait(timeout=60) == 0
    finally:
        first.kill()
    records = read_jsonl(campaign / "proposals.jsonl")
    # 3 iterations and their stop record, then 5 more (8 in all) and the final stop record
    assert [r["iteration"] for r in records] == list(range(1, 11))
    assert main(["check", "--campaign", str(campaign)]) == 0


def test_a_lock_left_by_a_killed_loop_does_not_block(tmp_path):
    toy, root = copy_toy(tmp_path), tmp_path / "c"
    start = [*loop_cmd(root, "--family", str(toy), "--proposer", "random", "--max-iters", "20")]
    proc = subprocess.Popen(
        start, env={**os.environ, "TOY_SLEEP_S": "0.3"}, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    # killed once the campaign exists: the lock is taken a moment before campaign.json is written
    wait_for(lambda: holder(root) is not None and (root / "campaign.json").exists())
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert f"pid {proc.pid}" in (root / LOCK_FILE).read_text()  # the file stays; the lock does not
    # A run the loop was forking at the kill holds a copy of the lock's descriptor until it execs
    # (the descriptor is close-on-exec): the lock goes with it, a moment later on a loaded machine.
    wait_for(lambda: holder(root) is None, timeout=10.0)
    done = subprocess.run(loop_cmd(root, "--resume", "--max-iters", "2"), capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


@pytest.mark.parametrize(
    "argv",
    [
        ["verify", "--campaign", "{c}"],
        ["prune", "--campaign", "{c}"],
        ["audit", "--campaign", "{c}"],
        ["noise", "--family", "{toy}", "--campaign", "{c}"],
        ["random", "--budget-from", "{c}"],
        ["loop", "--resume", "--campaign", "{c}"],
    ],
    ids=lambda argv: argv[0],
)
def test_every_writing_command_is_refused_while_another_holds_the_campaign(campaign, argv, capsys):
    toy = json.loads((campaign / "campaign.json").read_text())["family"]
    with CampaignLock(campaign, "audit"):
        assert main([a.format(c=campaign, toy=toy) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert f"is in use by pid {os.getpid()} (autoresearch audit)" in err


def test_a_loop_killed_before_writing_campaign_json_leaves_a_directory_a_new_start_takes(tmp_path, capsys):
    toy, root = copy_toy(tmp_path), tmp_path / "c"
    root.mkdir()
    (root / LOCK_FILE).write_text("pid 1 loop\n")  # what the killed loop left
    (root / ".campaign.json.x1y2.tmp").write_text("{")
    start = ["loop", "--campaign", str(root), "--plain", "--family", str(toy), "--proposer", "random"]
    assert main([*start, "--max-iters", "2"]) == 0
    assert json.loads((root / "campaign.json").read_text())["proposer"] == "random"
    other = tmp_path / "d"
    other.mkdir()
    (other / LOCK_FILE).write_text("")
    (other / "notes.txt").write_text("mine")  # anything else there is someone's: refused
    capsys.readouterr()
    assert (
        main(["loop", "--campaign", str(other), "--plain", "--family", str(toy), "--proposer", "random"]) == 2
    )
    assert "already exists" in capsys.readouterr().err
