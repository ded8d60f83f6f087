"""A group of repeats: N campaigns of one arm in one directory (``autoresearch loop --repeats N``).

```
<group>/
  repeats.json     GroupMeta: the arm (family, proposer, repeats, their seeds, the shared settings, sessions)
  repeat-00/ ...   ordinary campaign directories, repeat i seeding its proposer with seed + i
```

Planning a group writes repeats.json and each repeat's campaign.json; running it is the loop's
(autoresearch.loop.repeats).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from autoresearch.campaign.meta import CampaignMeta, portable_path
from autoresearch.campaign.paths import CampaignPaths
from autoresearch.family import Family, resolve_family
from autoresearch.journal import read_json, write_json_atomic

GROUP_FILE = "repeats.json"
REPEAT_PREFIX = "repeat-"


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
class GroupMeta:
    """repeats.json: the arm a group runs, and the sessions that ran it."""

    family: str  # the family directory, as campaign.json writes it (portable_path)
    family_name: str
    proposer: str
    repeats: int
    seeds: list[int]
    settings: dict[str, Any]  # the loop settings every repeat shares; seed is the first repeat's
    created: str
    sessions: list[dict[str, Any]]

    @classmethod
    def read(cls, root: str | Path) -> GroupMeta:
        return cls(**read_json(Path(root) / GROUP_FILE))

    def open_family(self, root: str | Path) -> Family:
        """The group's family, from any working directory: as its first repeat's campaign.json finds
        it (beside the campaign, wherever the group is resumed from), else where repeats.json says
        (relative to the working directory the group was started in)."""
        repeats = repeat_dirs(root)
        if repeats:
            return CampaignMeta.read(repeats[0]).open_family(repeats[0])
        return resolve_family(self.family)

    def write(self, root: str | Path) -> None:
        write_json_atomic(Path(root) / GROUP_FILE, asdict(self))


@dataclass(frozen=True)
class RepeatTask:
    name: str
    root: str  # the repeat's campaign directory
    meta: CampaignMeta  # its campaign.json


@dataclass(frozen=True)
class Group:
    root: Path
    meta: GroupMeta
    tasks: list[RepeatTask]

    def write(self) -> None:
        """repeats.json first (the arm), then each repeat's campaign.json."""
        self.root.mkdir(parents=True, exist_ok=True)
        self.meta.write(self.root)
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
    saved = GroupMeta.read(root) if is_group(root) else None
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
        created, sessions = session["started"], []
    else:
        for key, value in (("family_name", family.name), ("proposer", proposer)):
            if getattr(saved, key) != value:
                raise GroupError(
                    f"{root} is a group of {key} {getattr(saved, key)!r}, not {value!r}; a group is one arm"
                )
        if settings["seed"] != saved.settings["seed"]:
            raise GroupError(
                f"{root}: this group's seeds start at {saved.settings['seed']}; --seed cannot change"
            )
        if repeats is not None and repeats < saved.repeats:
            raise GroupError(f"{root} holds {saved.repeats} repeats; --repeats {repeats} cannot shrink it")
        repeats, created, sessions = repeats or saved.repeats, saved.created, saved.sessions
    seeds = [settings["seed"] + i for i in range(repeats)]
    meta = GroupMeta(
        portable_path(family.path),
        family.name,
        proposer,
        repeats,
        seeds,
        settings,
        created,
        [*sessions, session],
    )
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
