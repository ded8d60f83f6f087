"""A campaign directory and the loop state folded from its proposals.jsonl.

The state is a pure function of the records: the live loop applies each record it writes
through :meth:`CampaignState.apply`, and ``--resume`` rebuilds the identical state by applying
the records read back from disk. Nothing else is kept in memory that the trail cannot restore.

Records are in the order they were written, which with ``loop --workers K`` is the order runs
finished, not iteration order: an iteration number is given when the proposal is made, and its
record is appended when its run ends. Each iteration is recorded at most once; a number missing
from the file belongs to a run in flight (its ``runs/<run_id>/intent.json``).
"""

from __future__ import annotations

import os
import sys
from dataclasses import asdict, dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from autoresearch import provenance
from autoresearch.family import Family
from autoresearch.journal import JournalError, read_json, write_json_atomic
from autoresearch.loop.verdicts import is_better, reaches_target
from autoresearch.space import canonical_key

STATUSES = ("ran", "failed", "pruned", "invalid", "stop_accepted", "stop_rejected", "stopped")
RUN_STATUSES = ("ran", "failed", "pruned")  # the statuses of an iteration whose experiment started
TERMINAL = ("stop_accepted", "stopped")
BASELINE_PROPOSER = "baseline"


# Every proposals.jsonl record has exactly these keys, in this order.
RECORD_KEYS = (
    "iteration",
    "time",
    "proposer",
    "status",
    "reason",
    "proposal",
    "overrides",
    "config",
    "run_id",
    "seed",
    "metric",
    "feasible",
    "record",
    "verdict",
    "best_so_far",
    "cost_usd",
    "input_tokens",
    "output_tokens",
    "cumulative_cost_usd",
    "elapsed_s",
    "trigger",
    "run_status",
    "wall_seconds",
    "returncode",
    "interrupted_run_ids",
    "progress",
)


def now() -> str:
    """A record's time stamp: UTC, to the second."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def count_iterations(records: list[dict[str, Any]]) -> int:
    """Iterations the loop has run: every record but the loop's own stop records, so that a campaign
    resumed with a larger --max-iters runs up to that many."""
    return sum(record.get("status") != "stopped" for record in records)


def new_record(**fields: Any) -> dict[str, Any]:
    """One proposals.jsonl record: every key of RECORD_KEYS, in order, unset ones None. The only
    way records are made (the loop, the audit's random arm, tests), so every writer agrees."""
    unknown = set(fields) - set(RECORD_KEYS)
    if unknown:
        raise ValueError(f"not proposals.jsonl record keys: {sorted(unknown)}")
    return {**dict.fromkeys(RECORD_KEYS), **fields}


def session(family: Family | None = None) -> dict[str, Any]:
    """One entry of campaign.json's ``sessions``: when a command started on the campaign, how (its
    path arguments portable, e.g. the absolute ``--campaign`` each repeat of a group is resumed with),
    and, given the family, what ran (autoresearch.provenance)."""
    argv = [portable_path(a) if Path(a).is_absolute() and Path(a).exists() else a for a in sys.argv[1:]]
    entry = {"started": now(), "argv": argv}
    if family is not None:
        entry["provenance"] = provenance.collect(family.path)
    return entry


def portable_path(path: str | Path) -> str:
    """``path`` as campaign files record it: relative to the working directory when inside it, so that a
    committed campaign holds no machine's absolute paths; absolute otherwise."""
    resolved = Path(path).resolve()
    try:
        return str(resolved.relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(resolved)


class CampaignError(RuntimeError):
    """The campaign directory is inconsistent or cannot be used."""


@dataclass(frozen=True)
class CampaignMeta:
    """campaign.json: what a campaign runs and the sessions that ran it. The one way the file is made
    (``loop``, each repeat of a ``--repeats`` group, the audit's random arm, tests) and read back
    (``--resume``, the audit, ``check``), so every writer agrees.

    ``settings`` are the writer's: the loop's flags (commands/loop.py DEFAULTS) for a loop campaign,
    the arm's draw for a random arm. ``group`` names the group a repeat belongs to.

    The family is found from any working directory: ``family_dir`` is its path relative to the
    campaign directory (written on every write), and :meth:`open_family` checks that what it finds
    there is the family the campaign ran, by name and by the hash of its family.json (its problem
    and search space) that the first session's provenance recorded.
    """

    family: str  # the family directory, relative to the writer's working directory (portable_path)
    family_name: str
    proposer: str
    settings: dict[str, Any]
    created: str
    sessions: tuple[dict[str, Any], ...] = ()
    group: dict[str, Any] | None = None  # {"dir": group directory, "repeat": index}
    family_dir: str | None = None  # the family directory relative to the campaign directory

    @classmethod
    def new(cls, family: Family, proposer: str, settings: dict[str, Any]) -> CampaignMeta:
        started = session(family)
        return cls(
            portable_path(family.path), family.name, proposer, settings, started["started"], (started,)
        )

    def resumed(self, family: Family, settings: dict[str, Any]) -> CampaignMeta:
        """This campaign continued by a new session, its family where it is now, with ``settings``."""
        self.check_family(family)
        return replace(
            self,
            family=portable_path(family.path),
            settings=settings,
            sessions=(*self.sessions, session(family)),
        )

    def check_family(self, family: Family) -> None:
        """Refuse a family other than the one this campaign ran: another name, or a family.json whose
        problem or search space differs from the recorded one (CampaignError naming both)."""
        if family.name != self.family_name:
            raise CampaignError(f"this campaign is of family {self.family_name!r}, not {family.name!r}")
        recorded = ((self.provenance or {}).get("family_files") or {}).get("family.json")
        found = provenance.family_hashes(family.path)["family.json"]
        if recorded and found != recorded:
            raise CampaignError(
                f"{family.path / 'family.json'} is not the family.json this campaign ran (sha256 {found}, "
                f"recorded {recorded}): its metric, target, baseline or search space changed"
            )

    def family_paths(self, root: str | Path) -> list[Path]:
        """Where the family may be, in order: ``family_dir`` from the campaign directory ``root`` (a
        campaign moved with its family), then ``family`` as written (absolute, or relative to the
        working directory: a campaign copied elsewhere, or written before ``family_dir`` was kept)."""
        paths = [Path(root) / self.family_dir] if self.family_dir else []
        return [*paths, Path(self.family)]

    def open_family(self, root: str | Path) -> Family:
        """The campaign's family, found from any working directory and checked to be the one it ran."""
        path = next((p for p in self.family_paths(root) if p.is_dir()), None)
        if path is None:
            tried = ", ".join(str(p) for p in self.family_paths(root))
            raise CampaignError(
                f"{CampaignPaths(Path(root)).campaign_json}: its family directory does not exist (tried "
                f"{tried}; the {self.family_name!r} family it ran); pass --family DIR where it is now"
            )
        family = Family.load(path)
        self.check_family(family)
        return family

    @property
    def provenance(self) -> dict[str, Any] | None:
        """What produced the campaign's first records: its first session's provenance (None when it
        was made before provenance was kept)."""
        return self.sessions[0].get("provenance") if self.sessions else None

    def to_json(self) -> dict[str, Any]:
        data = {**asdict(self), "sessions": list(self.sessions)}
        if self.group is None:
            del data["group"]
        if self.family_dir is None:
            del data["family_dir"]
        return data

    @classmethod
    def from_json(cls, data: Any, where: str = "campaign.json") -> CampaignMeta:
        if not isinstance(data, dict):
            raise CampaignError(f"{where}: does not hold a JSON object")
        missing = [k for k in ("family", "family_name", "proposer", "settings") if k not in data]
        if missing:
            raise CampaignError(f"{where}: lacks {', '.join(missing)}")
        settings = dict(data["settings"])
        if "space" in data:  # random arms written before the space moved into settings
            settings.setdefault("space", data["space"])
        return cls(
            data["family"],
            data["family_name"],
            data["proposer"],
            settings,
            data.get("created", ""),
            tuple(data.get("sessions", ())),
            data.get("group"),
            data.get("family_dir"),
        )

    @classmethod
    def read(cls, root: str | Path) -> CampaignMeta:
        path = CampaignPaths(Path(root)).campaign_json
        try:
            return cls.from_json(read_json(path), str(path))
        except JournalError as err:
            raise CampaignError(str(err)) from err

    def write(self, root: str | Path) -> None:
        """Write campaign.json into ``root``, with the family's path relative to it (``family`` is
        relative to this process's working directory, where it was set)."""
        where = os.path.relpath(Path(self.family).resolve(), Path(root).resolve())
        located = replace(self, family_dir=Path(where).as_posix())
        write_json_atomic(CampaignPaths(Path(root)).campaign_json, located.to_json())


@dataclass(frozen=True)
class CampaignPaths:
    root: Path

    @property
    def campaign_json(self) -> Path:
        return self.root / "campaign.json"

    @property
    def family_json(self) -> Path:
        return self.root / "family.json"

    @property
    def proposals(self) -> Path:
        return self.root / "proposals.jsonl"

    @property
    def runs_log(self) -> Path:
        return self.root / "runs.jsonl"

    @property
    def runs_dir(self) -> Path:
        return self.root / "runs"

    def run_dir(self, run_id: str) -> Path:
        return self.runs_dir / run_id


class CampaignState:
    """Counters, best, seen configurations, spend and history after the records applied so far."""

    def __init__(self, family: Family):
        self.family = family
        self.records: list[dict[str, Any]] = []
        self.n_runs_ok = 0
        self.n_experiments = 0  # successful runs the proposer chose (the baseline excluded)
        self.n_runs_attempted = 0
        self.consecutive_failures = 0
        self.cost_usd = 0.0
        self.input_tokens = 0
        self.output_tokens = 0
        self.elapsed_s = 0.0
        self.best: dict[str, Any] | None = None
        self.runs: list[tuple[float, bool]] = []  # (metric, feasible) of successful runs, in order
        self.seen_configs: dict[str, int] = {}  # canonical config -> iteration that ran it
        self.seen_overrides: dict[str, int] = {}
        self.axes_exercised: set[str] = set()
        self.run_ids: set[str] = set()
        self.recorded: set[int] = set()  # iteration numbers with a record
        self.history_full: list[dict[str, Any]] = []
        self.history_blind: list[dict[str, Any]] = []

    @classmethod
    def from_records(cls, family: Family, records: list[dict[str, Any]]) -> CampaignState:
        state = cls(family)
        for record in records:
            state.apply(record)
        return state

    @property
    def iterations(self) -> int:
        return count_iterations(self.records)

    @property
    def next_iteration(self) -> int:
        """The number after every recorded one (runs in flight may hold some numbers past it)."""
        return max(self.recorded, default=0) + 1

    @property
    def last(self) -> dict[str, Any] | None:
        return self.records[-1] if self.records else None

    @property
    def finished(self) -> bool:
        return self.last is not None and self.last["status"] in TERMINAL

    @property
    def best_metric(self) -> float | None:
        return self.best["metric"] if self.best else None

    @property
    def target_met(self) -> bool:
        return reaches_target(self.best_metric, self.family.target, self.family.direction)

    def current_values(self) -> dict[str, Any]:
        """The configuration the next overrides apply to: the best so far, else the baseline."""
        return dict(self.best["config"]) if self.best else self.family.baseline_config

    def best_after(self, metric: float | None, feasible: bool | None) -> float | None:
        if metric is not None and feasible and is_better(metric, self.best_metric, self.family.direction):
            return metric
        return self.best_metric

    def seen_at(self, overrides: dict[str, Any], config: dict[str, Any]) -> str | None:
        """Why (overrides, config) repeats an evaluated point (paper Eq. dedup), or None."""
        if canonical_key(overrides) in self.seen_overrides:
            return f"this override map was already run at iteration {self.seen_overrides[canonical_key(overrides)]}"
        if canonical_key(config) in self.seen_configs:
            return f"the resulting configuration was already run at iteration {self.seen_configs[canonical_key(config)]}"
        return None

    def warnings(self) -> tuple[str, ...]:
        """What the proposer must hear about the last iteration."""
        last = self.last
        if last is None:
            return ()
        i, reason = last["iteration"], last.get("reason")
        if last["status"] == "invalid":
            return (f"Iteration {i}: your proposal was refused and nothing ran: {reason}",)
        if last["status"] == "stop_rejected":
            return (f"Iteration {i}: your stop request was rejected: {reason}",)
        if last["status"] == "failed":
            return (f"Iteration {i}: run {last['run_id']} failed: {reason}",)
        if last["status"] == "pruned":
            return (f"Iteration {i}: run {last['run_id']} was stopped early: {reason}",)
        return ()

    def apply(self, record: dict[str, Any]) -> None:
        iteration = record.get("iteration")
        if not isinstance(iteration, int) or isinstance(iteration, bool) or iteration < 1:
            raise CampaignError(f"proposals.jsonl: record {len(self.records) + 1} has no iteration number")
        if iteration in self.recorded:
            raise CampaignError(f"proposals.jsonl: iteration {iteration} is recorded twice")
        if record.get("status") not in STATUSES:
            raise CampaignError(
                f"proposals.jsonl: iteration {iteration} has unknown status {record.get('status')!r}"
            )
        self.records.append(record)
        self.recorded.add(iteration)
        self.cost_usd += record.get("cost_usd") or 0.0
        self.input_tokens += record.get("input_tokens") or 0
        self.output_tokens += record.get("output_tokens") or 0
        self.elapsed_s = record.get("elapsed_s") or self.elapsed_s
        status = record["status"]
        if status in ("failed", "invalid", "stop_rejected"):
            self.consecutive_failures += 1
        if status in RUN_STATUSES:
            self._apply_run(record)

    def _apply_run(self, record: dict[str, Any]) -> None:
        config, overrides = record["config"], record["overrides"]
        self.n_runs_attempted += 1
        self.run_ids.add(record["run_id"])
        self.seen_configs.setdefault(canonical_key(config), record["iteration"])
        self.seen_overrides.setdefault(canonical_key(overrides), record["iteration"])
        metric_name = self.family.metric
        hypothesis = ((record.get("proposal") or {}).get("annotation") or {}).get("hypothesis")
        item = {
            "iteration": record["iteration"],
            "run_id": record["run_id"],
            "status": record.get("run_status", "ok" if record["status"] == "ran" else "failed"),
            "hypothesis": hypothesis,
            "overrides": overrides,
            "config": config,
            metric_name: record.get("metric"),
        }
        if record.get("progress"):
            item["progress"] = record["progress"]
        if record["status"] != "ran":  # failed, or pruned: neither counts as a result nor as a failure
            item["reason"] = record.get("reason")
        else:
            metric, feasible = record["metric"], bool(record["feasible"])
            self.n_runs_ok += 1
            self.consecutive_failures = 0
            self.runs.append((metric, feasible))
            if record.get("proposer") != BASELINE_PROPOSER:
                self.n_experiments += 1
                baseline = self.family.baseline_config
                self.axes_exercised |= self.family.space.axes_of(
                    {k for k in config if config[k] != baseline[k]}
                )
            if feasible and is_better(metric, self.best_metric, self.family.direction):
                self.best = {
                    "metric": metric,
                    "config": config,
                    "run_id": record["run_id"],
                    "iteration": record["iteration"],
                }
            aux = {
                k: v
                for k, v in (record.get("record") or {}).items()
                if k not in ("run_id", "config", metric_name)
            }
            item.update(feasible=feasible, verdict=record.get("verdict"), auxiliary=aux)
        self.history_full.append(item)
        self.history_blind.append({"config": config, metric_name: record.get("metric")})
