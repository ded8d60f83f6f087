"""N independent campaigns of one arm (``autoresearch loop --repeats N``).

A single campaign is one draw of a high-variance search; scoring an arm needs several. A *group*
directory holds the N campaigns of one arm as ordinary campaign directories, ``repeat-00/``,
``repeat-01/``, ...: repeat i seeds its proposer with ``seed + i``; every repeat starts with the same
first experiment (the family baseline at the family's default seed) and trains every experiment at that
seed, so repeats differ only in what the proposer chooses. ``repeats.json`` at the top records the arm
(family, proposer, number of repeats, their seeds, the shared settings, one entry per session).

The repeats are tasks of an :class:`~autoresearch.executors.Executor` (the local pool or Ray), and each
task runs its repeat as a process of its own: ``autoresearch loop --resume --campaign <group>/repeat-NN``,
the single-campaign command itself. So a repeat runs, records and resumes exactly like any campaign, and
repeats share nothing, not even an interpreter (the loop is not written to share one). Running the same
command again (or ``--resume``) continues the unfinished repeats; finished ones end at once with nothing
written. A larger ``--repeats`` adds repeats with the next seeds.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from autoresearch.campaign import (
    Campaign,
    CampaignError,
    CampaignMeta,
    CampaignPaths,
    Record,
    count_iterations,
    portable_path,
)
from autoresearch.execution.executors import Executor
from autoresearch.family import Family
from autoresearch.journal import JournalError, read_json, write_json_atomic

GROUP_FILE = "repeats.json"
REPEAT_PREFIX = "repeat-"
# A repeat's process: the loop command alone (not the whole CLI, whose other commands import scipy and
# matplotlib: seconds per repeat), given its parent's pid first. It asks the kernel for SIGTERM (which the
# loop turns into a clean interrupt) when its parent dies, even by kill -9, so that no orphaned loop runs
# on beside a resumed one (Linux PR_SET_PDEATHSIG; elsewhere an orphan runs to its end).
CHILD = """
import argparse, ctypes, os, signal, sys
try:
    ctypes.CDLL(None).prctl(1, signal.SIGTERM)
except (AttributeError, OSError):
    pass
if os.getppid() != int(sys.argv.pop(1)):
    sys.exit(130)
from autoresearch.commands import loop
parser = loop.add_parser(argparse.ArgumentParser(prog="autoresearch").add_subparsers())
sys.exit(loop.run(parser.parse_args(sys.argv[1:])))
"""
_CHILDREN: set[subprocess.Popen] = set()  # repeats in flight in this process: where a cancel goes


class GroupError(ValueError):
    """The group directory cannot hold these repeats; the message says why."""


def repeat_name(index: int) -> str:
    return f"{REPEAT_PREFIX}{index:02d}"


def is_group(path: str | Path) -> bool:
    return (Path(path) / GROUP_FILE).is_file()


def repeat_dirs(group: str | Path) -> list[Path]:
    """The campaign directories of a group, in repeat order (``repeat-*/`` holding a campaign.json)."""
    found = [
        d
        for d in Path(group).glob(f"{REPEAT_PREFIX}*")
        if d.name[len(REPEAT_PREFIX) :].isdigit() and CampaignPaths(d).campaign_json.is_file()
    ]
    return sorted(found, key=lambda d: int(d.name[len(REPEAT_PREFIX) :]))


@dataclass(frozen=True)
class RepeatTask:
    name: str
    root: str  # the repeat's campaign directory
    meta: CampaignMeta  # its campaign.json


@dataclass(frozen=True)
class Group:
    root: Path
    meta: dict[str, Any]  # repeats.json
    tasks: list[RepeatTask]

    def write(self) -> None:
        """repeats.json first (the arm), then each repeat's campaign.json."""
        self.root.mkdir(parents=True, exist_ok=True)
        write_json_atomic(self.root / GROUP_FILE, self.meta)
        for task in self.tasks:
            Path(task.root).mkdir(exist_ok=True)
            task.meta.write(task.root)


def plan_group(
    root: Path,
    *,
    family: Family,
    proposer: str,
    settings: dict[str, Any],
    repeats: int | None,
    session: dict[str, Any],
) -> Group:
    """The group at ``root``: a new one, or the existing one continued (same arm, as many or more repeats).

    ``settings`` are the loop settings shared by every repeat (``seed`` is the first repeat's); for an
    existing group they are its saved settings overridden by the flags given again.
    """
    saved = read_json(root / GROUP_FILE) if is_group(root) else None
    if saved is None:
        if CampaignPaths(root).campaign_json.exists():
            raise GroupError(
                f"{root} is a single campaign, not a group of repeats; choose another --campaign"
            )
        if root.exists() and any(root.iterdir()):
            raise GroupError(
                f"{root} already exists and is not a group of repeats; choose another --campaign"
            )
        if repeats is None:
            raise GroupError(f"{root}: no group of repeats here to resume; start one with --repeats N")
        saved = {"created": session["started"], "sessions": []}
    else:
        for key, value in (("family_name", family.name), ("proposer", proposer)):
            if saved[key] != value:
                raise GroupError(
                    f"{root} is a group of {key} {saved[key]!r}, not {value!r}; a group is one arm"
                )
        if settings["seed"] != saved["settings"]["seed"]:
            raise GroupError(
                f"{root}: this group's seeds start at {saved['settings']['seed']}; --seed cannot change"
            )
        if repeats is not None and repeats < saved["repeats"]:
            raise GroupError(f"{root} holds {saved['repeats']} repeats; --repeats {repeats} cannot shrink it")
        repeats = repeats or saved["repeats"]
    seeds = [settings["seed"] + i for i in range(repeats)]
    meta = {
        "family": portable_path(family.path),
        "family_name": family.name,
        "proposer": proposer,
        "repeats": repeats,
        "seeds": seeds,
        "settings": settings,
        "created": saved["created"],
        "sessions": [*saved["sessions"], session],
    }
    tasks = []
    for i, seed in enumerate(seeds):
        task_root = root / repeat_name(i)
        previous = CampaignMeta.read(task_root) if CampaignPaths(task_root).campaign_json.exists() else None
        campaign_meta = CampaignMeta(  # sessions: the repeat's own process adds one as it resumes
            family=portable_path(family.path),
            family_name=family.name,
            proposer=proposer,
            settings={**settings, "seed": seed},
            created=previous.created if previous else session["started"],
            sessions=previous.sessions if previous else (),
            group={"dir": portable_path(root), "repeat": i},
        )
        # absolute: a Ray worker need not share the working directory
        tasks.append(RepeatTask(repeat_name(i), str(task_root.resolve()), campaign_meta))
    return Group(root, meta, tasks)


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
    cmd = [
        sys.executable,
        "-c",
        CHILD,
        str(os.getpid()),
        "--resume",
        "--campaign",
        task.root,
        "--plain",
    ]
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
