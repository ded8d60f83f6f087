"""Running N independent campaigns of one arm (``autoresearch loop --repeats N``).

A single campaign is one draw of a high-variance search; scoring an arm needs several. A *group*
directory (autoresearch.campaign.group) holds the N campaigns of one arm as ordinary campaign
directories: repeat i seeds its proposer with ``seed + i``; every repeat starts with the same first
experiment (the family baseline at the family's default seed) and trains every experiment at that seed,
so repeats differ only in what the proposer chooses.

The repeats are tasks of an :class:`~autoresearch.execution.executors.Executor` (the local pool or Ray),
and each task runs its repeat as a process of its own: a session of its campaign resumed
(:func:`autoresearch.loop.session.resume`, what ``autoresearch loop --resume --campaign
<group>/repeat-NN`` runs). So a repeat runs, records and resumes exactly like any campaign, and repeats
share nothing, not even an interpreter (the loop is not written to share one). Running the same command
again (or ``--resume``) continues the unfinished repeats; finished ones end at once with nothing
written. A larger ``--repeats`` adds repeats with the next seeds.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from typing import Any

from autoresearch.campaign import Campaign, CampaignError, Record, count_iterations
from autoresearch.campaign.group import Group, RepeatTask
from autoresearch.execution.executors import Executor
from autoresearch.journal import JournalError

# A repeat's process: a loop session alone (not the whole CLI, whose other commands import scipy and
# matplotlib: seconds per repeat), given its parent's pid first, then the arguments of the loop command it
# stands for (campaign.json records them as its session's). It asks the kernel for SIGTERM (which the
# loop turns into a clean interrupt) when its parent dies, even by kill -9, so that no orphaned loop runs
# on beside a resumed one (Linux PR_SET_PDEATHSIG; elsewhere an orphan runs to its end).
CHILD = """
import ctypes, os, signal, sys
try:
    ctypes.CDLL(None).prctl(1, signal.SIGTERM)
except (AttributeError, OSError):
    pass
if os.getppid() != int(sys.argv.pop(1)):
    sys.exit(130)
from autoresearch.loop import session
sys.exit(session.resume(sys.argv[sys.argv.index("--campaign") + 1]))
"""
_CHILDREN: set[subprocess.Popen] = set()  # repeats in flight in this process: where a cancel goes


def _records(task: RepeatTask) -> list[Record]:
    """The repeat's records; [] when unreadable (its own process then says why)."""
    try:
        return Campaign(task.root).records()
    except (CampaignError, JournalError):
        return []


def _outcome(task: RepeatTask, returncode: int, before: int, last_line: str) -> dict[str, Any]:
    """What one repeat's process did, from its exit code and its campaign directory."""
    records = _records(task)
    last = records[-1] if records else None
    best = Campaign(task.root).running_best()
    status = {0: last and last.status.value, 1: "prepare_failed", 130: "interrupted"}.get(returncode, "error")
    if returncode == 0 and len(records) == before:
        status = "already_finished"
    return {
        "repeat": task.name,
        "dir": task.root,
        "seed": task.meta.settings["seed"],
        "returncode": returncode,
        "status": status,
        "trigger": last and last.trigger,
        "reason": last_line if status == "error" else last and last.reason,
        "iterations": count_iterations(records),
        "best": best and {"metric": best["metric"], "run_id": best["run_id"]},
    }


def run_repeat(task: RepeatTask) -> dict[str, Any]:
    """Run (or resume) one repeat in its own process, forwarding its output line by line under the repeat's
    name; its outcome as a plain dict (it may travel back from a Ray worker)."""
    before = len(_records(task))
    cmd = [sys.executable, "-c", CHILD, str(os.getpid()), "--resume", "--campaign", task.root, "--plain"]
    last_line = ""
    with subprocess.Popen(
        cmd,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,  # a terminal's Ctrl-C reaches it once, forwarded by run_group
    ) as proc:
        _CHILDREN.add(proc)
        try:
            for line in proc.stdout:
                last_line = line.strip() or last_line
                print(f"[{task.name}] {line}", end="", flush=True)  # one write per line: never split
        finally:
            returncode = proc.wait()  # after a cancel too: the repeat is still stopping its training run
            _CHILDREN.discard(proc)
    return _outcome(task, returncode, before, last_line)


def describe(outcome: dict[str, Any], metric: str) -> str:
    """One line for a repeat's outcome."""
    if outcome["status"] == "error":
        return f"{outcome['repeat']}: error (exit {outcome['returncode']}): {outcome['reason']}"
    best = outcome["best"]
    best_text = f"{best['metric']:.6g} ({best['run_id']})" if best else "none feasible"
    ended = outcome["status"] + (f" ({outcome['trigger']})" if outcome["trigger"] else "")
    return (
        f"{outcome['repeat']} (seed {outcome['seed']}): {ended}, {outcome['iterations']} iterations, "
        f"best {metric}: {best_text}"
    )


def _cancel(signum, frame):
    for proc in list(_CHILDREN):  # list(): one step under the GIL while threads add and discard
        try:
            proc.send_signal(signal.SIGTERM)  # the loop's clean interrupt
        except ProcessLookupError:
            pass
    raise KeyboardInterrupt


def run_group(group: Group, executor: Executor) -> list[dict[str, Any]]:
    """Run every repeat of ``group`` through ``executor``; their outcomes in repeat order.

    Ctrl-C or SIGTERM cancels the whole group: each repeat in flight gets SIGTERM, stops its training run
    and exits (on Ray, when the executor closes), and every repeat can be resumed.
    """
    main = threading.current_thread() is threading.main_thread()
    previous = {s: signal.signal(s, _cancel) for s in (signal.SIGINT, signal.SIGTERM)} if main else {}
    try:
        return executor.map(run_repeat, group.tasks)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
