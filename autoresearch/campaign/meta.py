"""campaign.json: what a campaign runs, where its family is, and the sessions that ran it."""

from __future__ import annotations

import json
import os
import sys
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from autoresearch import provenance
from autoresearch.campaign.paths import CampaignError, CampaignPaths
from autoresearch.campaign.records import now
from autoresearch.family import Family
from autoresearch.journal import JournalError, read_json, write_json_atomic

# Seconds a time-budgeted run gets beyond its budget before it is killed: the interpreter and the
# family's imports, loading its data, scoring the policy and saving it (loop --eval-allowance).
EVAL_ALLOWANCE = 60.0


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


@dataclass(frozen=True)
class CampaignMeta:
    """campaign.json: what a campaign runs and the sessions that ran it. The one way the file is made
    (``loop``, each repeat of a ``--repeats`` group, the audit's random arm, tests) and read back
    (``--resume``, the audit, ``check``), so every writer agrees.

    ``settings`` are the writer's: the loop's flags (loop/session.py DEFAULTS) for a loop campaign,
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

    def noted(self, key: str, value: Any) -> CampaignMeta:
        """This campaign with ``key: value`` in its current (last) session's entry."""
        *before, current = self.sessions
        return replace(self, sessions=(*before, {**current, key: value}))

    def check_family(self, family: Family, root: str | Path | None = None) -> None:
        """Refuse a family other than the one this campaign ran: another name, or a family.json whose
        problem or search space differs from the recorded one (CampaignError naming both). A family
        that only grew since (new parameters held at their baseline value by every earlier run, new
        choices of a categorical, new fields) is the same one: judged against the registry the
        campaign in ``root`` was shown (:func:`autoresearch.provenance.family_hashes_as_seen`)."""
        if family.name != self.family_name:
            raise CampaignError(f"this campaign is of family {self.family_name!r}, not {family.name!r}")
        recorded = ((self.provenance or {}).get("family_files") or {}).get("family.json")
        found = provenance.family_hashes(family.path)["family.json"]
        if recorded and found != recorded and root is not None:
            seen = CampaignPaths(Path(root)).family_json
            shown = json.loads(seen.read_text(encoding="utf-8")) if seen.is_file() else None
            if isinstance(shown, dict) and recorded in provenance.family_hashes_as_seen(family.path, shown):
                return
        if recorded and found != recorded:
            raise CampaignError(
                f"{family.path / 'family.json'} is not the family.json this campaign ran (sha256 {found}, "
                f"recorded {recorded}): its metric, target, baseline or search space changed"
            )

    def family_paths(self, root: str | Path) -> list[Path]:
        """Where the family may be, in order: ``family_dir`` from the campaign directory ``root`` (a
        campaign moved with its family), then ``family`` as written (absolute, or relative to the
        working directory: a campaign copied elsewhere, or written before ``family_dir`` was kept),
        then, when relative, from each directory above the campaign (a campaign written before
        ``family_dir``, read from elsewhere than where its loop started, e.g. a repository's root)."""
        paths = [Path(root) / self.family_dir] if self.family_dir else []
        family = Path(self.family)
        above = [] if family.is_absolute() else [parent / family for parent in Path(root).resolve().parents]
        return [*paths, family, *above]

    def open_family(self, root: str | Path) -> Family:
        """The campaign's family, found from any working directory and checked to be the one it ran,
        under the protocol the campaign searched (its settings' ``protocol``, if any)."""
        path = next((p for p in self.family_paths(root) if p.is_dir()), None)
        if path is None:
            tried = ", ".join(str(p) for p in self.family_paths(root)[: 2 if self.family_dir else 1])
            if not Path(self.family).is_absolute():
                tried += f" and {self.family} under each directory above the campaign"
            raise CampaignError(
                f"{CampaignPaths(Path(root)).campaign_json}: its family directory does not exist (tried "
                f"{tried}; the {self.family_name!r} family it ran); pass --family DIR where it is now"
            )
        family = Family.load(path)
        self.check_family(family, root)
        return family.under_protocol(self.settings.get("protocol"))

    @property
    def time_budget(self) -> float | None:
        """The training seconds each of the campaign's runs is granted (``loop --time-budget``), or None."""
        return self.settings.get("time_budget")

    @property
    def run_timeout(self) -> float:
        """The hard wall-clock limit of one of the campaign's runs: its time budget plus the evaluation
        allowance when it grants one (for a family that ignores the budget), else ``timeout_per_run``."""
        if self.time_budget is not None:
            return float(self.time_budget) + self.eval_allowance
        return float(self.settings["timeout_per_run"])

    @property
    def eval_allowance(self) -> float:
        """Seconds granted beyond training for loading, scoring and saving (``loop --eval-allowance``)."""
        return float(self.settings.get("eval_allowance", EVAL_ALLOWANCE))

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
