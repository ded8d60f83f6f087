"""Validate a campaign directory's files and say how to repair each problem (``autoresearch check``).

What is checked: campaign.json and the campaign's family.json are readable JSON objects and the
family directory loads; proposals.jsonl holds one whole JSON record per line with iterations
1, 2, 3, ... exactly once each (in any order: with ``loop --workers K`` records follow the order
runs finish; a number held by a run still in flight, i.e. an intent without a record, may be
missing), every run it records has its run directory, unless the campaign is published: a
campaign committed without its ``runs/`` (patched train.py copies, logs, weights) is a valid
campaign, and check says so instead of reporting each run directory missing; runs.jsonl has whole
JSON lines, each run logged once and started by a proposal or an intent of this campaign, and every
run recorded as ran logged there; audit.json, where the audit wrote one, is a JSON object whose
step parts are objects with a known status. A torn last line (a crash mid-append) is reported too,
though the loop repairs it when it next starts.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from autoresearch.campaign.meta import CampaignMeta
from autoresearch.campaign.paths import CampaignError, CampaignPaths
from autoresearch.campaign.records import Status, parse_status
from autoresearch.campaign.store import Campaign
from autoresearch.family import FamilyError
from autoresearch.journal import JournalError

PUBLISHED = "published without its run directories (runs/): the records and logs carry the results"


@dataclass(frozen=True)
class Problem:
    where: str  # file[:line], relative to the campaign directory
    what: str
    repair: str
    breaks_trail: bool = False  # proposals.jsonl no longer reads as iterations 1, 2, ... (resume refuses it)

    def __str__(self) -> str:
        return f"{self.where}: {self.what}\n    repair: {self.repair}"


def _lines(path: Path) -> tuple[list[tuple[int, Any]], list[Problem]]:
    """(line number, parsed JSON) of every whole line, and the problems of the others."""
    pieces = path.read_bytes().split(b"\n")
    parsed, problems = [], []
    for lineno, line in enumerate(pieces[:-1], start=1):
        if not line.strip():
            continue
        try:
            parsed.append((lineno, json.loads(line)))
        except (ValueError, RecursionError):  # RecursionError: nested too deeply to parse
            problems.append(
                Problem(
                    f"{path.name}:{lineno}",
                    "not a JSON line (readers stop at it)",
                    f"move line {lineno} out of {path.name} (e.g. into {path.name}.torn)",
                )
            )
    if pieces[-1].strip():
        problems.append(
            Problem(
                f"{path.name}:{len(pieces)}",
                "torn last line without its newline (a crash mid-append)",
                f"`autoresearch loop --resume` moves it to {path.name}.torn; or delete that fragment",
            )
        )
    return parsed, problems


def _read_object(path: Path, name: str) -> tuple[dict[str, Any] | None, Problem | None]:
    try:
        obj = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None, Problem(name, "missing", "this is not a campaign directory, or restore the file")
    except (OSError, ValueError) as err:
        return None, Problem(name, f"unreadable ({err})", f"restore {name} from a backup")
    if not isinstance(obj, dict):
        return None, Problem(name, "does not hold a JSON object", f"restore {name} from a backup")
    return obj, None


def _check_family(meta: CampaignMeta, root: Path, notes: list[str]) -> list[Problem]:
    """The family's problems; for a published campaign a family not in this checkout is a note (its
    records carry the results; its audit needs the family back)."""
    if (
        not any(path.is_dir() for path in meta.family_paths(root))
        and not CampaignPaths(root).runs_dir.is_dir()
    ):
        notes.append(f"its family ({meta.family}) is not here: restore it to audit or resume the campaign")
        return []
    try:
        meta.open_family(root)
    except CampaignError as err:
        repair = "restore the family it ran, or resume with --family DIR where it now is"
        return [Problem("campaign.json", str(err).split("campaign.json: ", 1)[-1], repair)]
    except FamilyError as err:
        return [Problem("campaign.json", f"its family does not load: {err}", "fix the family")]
    return []


def _check_meta(paths: CampaignPaths, notes: list[str]) -> list[Problem]:
    """The problems of campaign.json, of its family and of the campaign's family.json."""
    raw, problem = _read_object(paths.campaign_json, "campaign.json")
    if raw is not None:
        try:
            meta = CampaignMeta.from_json(raw)
        except CampaignError as err:
            problem = Problem(
                "campaign.json", str(err).removeprefix("campaign.json: "), "restore it from a backup"
            )
    problems = [problem] if problem else _check_family(meta, paths.root, notes)
    if paths.family_json.exists():
        registry, problem = _read_object(paths.family_json, "family.json")
        family_name = (raw or {}).get("family_name")
        if problem:
            problems.append(
                Problem("family.json", problem.what, "delete it: the loop rewrites it from the records")
            )
        elif family_name and registry.get("name") != family_name:
            problems.append(
                Problem(
                    "family.json",
                    f"belongs to family {registry.get('name')!r}, not {family_name!r}",
                    "delete it: the loop rewrites it from the records",
                )
            )
    return problems


def _check_proposals(paths: CampaignPaths) -> tuple[list[dict[str, Any]], list[Problem]]:
    """The records in order, and the problems of proposals.jsonl."""
    if not paths.proposals.exists():
        return [], []
    lines, problems = _lines(paths.proposals)
    problems = [replace(p, breaks_trail="torn" not in p.what) for p in problems]
    records: list[dict[str, Any]] = []
    first_line: dict[int, int] = {}
    by_iteration: dict[int, Any] = {}
    for lineno, record in lines:
        where = f"proposals.jsonl:{lineno}"
        iteration = record.get("iteration") if isinstance(record, dict) else None
        if not isinstance(iteration, int) or isinstance(iteration, bool) or iteration < 1:
            problems.append(
                Problem(
                    where, "not a proposals record (no iteration number)", f"move line {lineno} out", True
                )
            )
            continue
        if iteration in first_line:
            earlier = first_line[iteration]
            same = by_iteration[iteration] == record
            problems.append(
                Problem(
                    where,
                    f"iteration {iteration} again (first at line {earlier})"
                    + ("" if same else ", with a different record: two processes wrote this campaign"),
                    f"delete line {lineno}"
                    if same
                    else f"keep the lines before {lineno}, move line {lineno} and later ones out, and move "
                    "the run directories of the iterations they held out of runs/; `autoresearch loop "
                    "--resume` then runs them again",
                    breaks_trail=True,
                )
            )
            continue
        status = parse_status(record.get("status"))
        if status is None:
            problems.append(
                Problem(
                    where,
                    f"unknown status {record.get('status')!r}",
                    f"restore line {lineno} from a backup, or treat it as the first bad line (see above)",
                    breaks_trail=True,
                )
            )
        first_line[iteration], by_iteration[iteration] = lineno, record
        records.append(record)
        run_id = record.get("run_id")
        if (
            status is not None
            and status.started_a_run
            and paths.runs_dir.is_dir()  # a published campaign has none at all
            and not (isinstance(run_id, str) and paths.run_dir(run_id).is_dir())
        ):
            problems.append(
                Problem(
                    where,
                    f"iteration {iteration} records run {run_id!r}, but runs/{run_id} is missing",
                    "restore that run directory from a backup (the record stands, but its train.py, log "
                    "and result are gone)",
                )
            )
    return records, problems + _gaps(paths, first_line, records)


def _in_flight(paths: CampaignPaths, recorded_runs: set[Any]) -> set[int]:
    """Iterations held by a run in flight (or interrupted and not yet resumed): an intent, no record."""
    try:
        intents = Campaign(paths.root).intents()
    except (CampaignError, JournalError, OSError):  # a damaged intent: the gaps are then reported
        return set()
    return {intent.iteration for intent in intents if intent.run_id not in recorded_runs}


def _gaps(paths: CampaignPaths, first_line: dict[int, int], records: list[dict[str, Any]]) -> list[Problem]:
    """Iteration numbers below the highest recorded one that have no record and no run in flight."""
    if not first_line:
        return []
    # runs in flight are recorded before a stop record: a number below one is lost, not in flight
    stops = [r["iteration"] for r in records if (parse_status(r.get("status")) or Status.RAN).ends_campaign]
    held = {i for i in _in_flight(paths, {r.get("run_id") for r in records}) if i > max(stops, default=0)}
    missing = [i for i in range(1, max(first_line)) if i not in first_line and i not in held]
    problems = []
    while missing:
        low = high = missing.pop(0)
        while missing and missing[0] == high + 1:
            high = missing.pop(0)
        after = min((i for i in first_line if i > high), default=high + 1)
        lineno = first_line[after]
        before = max((i for i, n in first_line.items() if n < lineno), default=None)
        problems.append(
            Problem(
                f"proposals.jsonl:{lineno}",
                (f"iteration {after} follows {before}: " if before else f"iteration {after} comes first: ")
                + (f"iteration {low} is missing" if low == high else f"iterations {low}-{high} are missing"),
                f"keep the lines before {lineno}, move line {lineno} and later ones out, and move the "
                "run directories of the iterations they held out of runs/; `autoresearch loop "
                "--resume` then runs them again",
                breaks_trail=True,
            )
        )
    return problems


def _check_runs_log(paths: CampaignPaths, records: list[dict[str, Any]]) -> list[Problem]:
    lines, problems = _lines(paths.runs_log) if paths.runs_log.exists() else ([], [])
    recorded = {r.get("run_id") for r in records}
    first_line: dict[str, int] = {}
    for lineno, line in lines:
        where = f"runs.jsonl:{lineno}"
        run_id = line.get("run_id") if isinstance(line, dict) else None
        if not isinstance(run_id, str):
            problems.append(Problem(where, "a line without a run_id", f"move line {lineno} out"))
            continue
        if run_id in first_line:
            problems.append(
                Problem(
                    where,
                    f"run {run_id} logged again (first at line {first_line[run_id]})",
                    f"keep the line that matches runs/{run_id}/result.json and delete the other",
                )
            )
            continue
        first_line[run_id] = lineno
        if run_id not in recorded and not (paths.run_dir(run_id) / "intent.json").is_file():
            problems.append(
                Problem(
                    where,
                    f"run {run_id} was started by no proposal or intent of this campaign",
                    f"delete line {lineno}: it is not a result of this campaign",
                )
            )
    problems += [
        Problem(
            "runs.jsonl",
            f"run {r.get('run_id')!r} of iteration {r['iteration']} ran, but has no readable line here",
            "restore runs.jsonl from a backup, or append that record's 'final_metric' field ('record' in "
            "schema 1) to it as one line (train.py printed it as its FINAL_METRIC and logged it)",
        )
        for r in records
        if parse_status(r.get("status")) is Status.RAN and r.get("run_id") not in first_line
    ]
    return problems


# audit.json: the parts the audit steps write (autoresearch/audit: noise, verify, the prune rules,
# the random arms) and the status each holds. Parts of steps unknown here are left alone.
AUDIT_STEPS = re.compile(r"noise|verify|prune(_paired)?(_candidate)?|random(_matched)?")
AUDIT_DECIDED_BY = "prune_decided_by"
AUDIT_STATUSES = ("running", "done", "skipped")


def audit_problems(root: str | Path, shape_only: bool = False) -> list[Problem]:
    """The problems of the campaign's audit.json ([] without one): not a JSON object, or a known
    step's part that is not an object (what the audit steps and the report cannot read: all
    ``shape_only`` asks for) or holds no known status."""
    path = CampaignPaths(Path(root)).audit_json
    if not path.exists():
        return []
    repair = "delete audit.json, or the broken part; the audit steps write theirs again when run"
    data, problem = _read_object(path, "audit.json")
    if problem is not None:
        return [replace(problem, repair=repair)]
    problems = []
    for step, part in data.items():
        if step == AUDIT_DECIDED_BY:
            if not isinstance(part, dict) or not isinstance(part.get("key"), str):
                problems.append(Problem("audit.json", f"{step!r} is not an object with a 'key'", repair))
        elif AUDIT_STEPS.fullmatch(step):
            if not isinstance(part, dict):
                problems.append(Problem("audit.json", f"step {step!r} does not hold a JSON object", repair))
            elif not shape_only and part.get("status") not in AUDIT_STATUSES:
                problems.append(
                    Problem(
                        "audit.json",
                        f"step {step!r} has status {part.get('status')!r}, not one of {', '.join(AUDIT_STATUSES)}",
                        repair,
                    )
                )
    return problems


@dataclass(frozen=True)
class CheckResult:
    iterations: int
    problems: list[Problem]
    notes: list[str]  # facts that are not problems (e.g. a published campaign)


def check_campaign(root: str | Path) -> CheckResult:
    """Every problem of the campaign in ``root`` (which must be a directory)."""
    paths = CampaignPaths(Path(root))
    records, proposal_problems = _check_proposals(paths)
    notes = [PUBLISHED] if records and not paths.runs_dir.is_dir() else []
    problems = _check_meta(paths, notes)
    problems += proposal_problems + _check_runs_log(paths, records) + audit_problems(root)
    iterations = sum(parse_status(r.get("status")) is not Status.STOPPED for r in records)
    return CheckResult(iterations, problems, notes)


def trail_problems(root: str | Path) -> list[Problem]:
    """The problems that make a campaign untrustworthy to read back: in proposals.jsonl duplicates,
    gaps, lines that are not records (a torn last line is not one: readers skip it); and an
    audit.json the audit steps and the report cannot read (:func:`audit_problems`)."""
    _, problems = _check_proposals(CampaignPaths(Path(root)))
    return [p for p in problems if p.breaks_trail] + audit_problems(root, shape_only=True)


def trail_refusal(root: str | Path) -> str | None:
    """Why a campaign is not read back (:func:`trail_problems`), in one line naming the first problem
    and the repairs' command; None when nothing stands in the way."""
    problems = trail_problems(root)
    if not problems:
        return None
    more = f" (and {len(problems) - 1} more problem(s))" if len(problems) > 1 else ""
    return (
        f"{root}: {problems[0].where}: {problems[0].what}{more}; see `autoresearch check --campaign {root}` "
        "for the repairs"
    )
