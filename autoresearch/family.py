"""Load and validate a family directory (docs/family-contract.md).

family.json is the registry: the declaration and the current best. autoresearch writes under a
family directory only what its audit owns: family.json's best (its verify step) and ledger.json (the
seed noise, the promotions: autoresearch.ledger); campaigns and their runs live outside it
(:meth:`Family.check_outside`). Every error names the file and field that is missing or invalid.

A family may declare ``protocols``: named restrictions of its search space (``loop --protocol NAME``,
:meth:`Family.under_protocol`), e.g. the paper's space within a wider one, and of what counts as
feasible (a protocol's ``limits``: upper bounds on fields of a run's record, e.g. its fuel).

A family that declares ``"test_split": true`` scores a run on a sealed test split when its
train.py is given ``--eval-split test``. Only the audit asks for it; :meth:`Family.search_registry`
is the registry as every proposer sees it, without a number measured on that split.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from autoresearch.direction import Direction
from autoresearch.editable import EditableError, read_region
from autoresearch.journal import JournalError
from autoresearch.ledger import LEDGER_FILE, Ledger
from autoresearch.space import NUMERIC_TYPES, SearchSpace, SpaceError, ValidationError
from autoresearch.splits import SPLIT_IDS, ScoredRun, Split, recorded_split_ids, split_mismatches, split_parts

REQUIRED_FILES = ("program.md", "program_blind.md", "train.py", "family.json", "prepare.py")
TEXT_FILES = ("program.md", "program_blind.md", "train.py")  # read as UTF-8 text by the loop
# A family name becomes part of paths (runs/<name>-...): a plain file name, nothing to escape.
PLAIN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


def own_file(name: str) -> bool:
    """Whether a file of this name in a family directory is one of the family's own, not what runs
    leave there: the log of manual runs and its lock, byte code, hidden files (what ``init`` copies
    from a template and the Ray executor ships to its workers)."""
    return not (name.startswith((".", "runs.jsonl")) or name.endswith((".pyc", ".lock")))


class FamilyError(ValueError):
    """The family directory does not satisfy the contract."""


def _number(value: Any) -> bool:
    try:
        return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    except OverflowError:  # an integer float() cannot hold (10**400): JSON integers are unbounded
        return False


def _limits_ok(limits: Any) -> bool:
    """A ``limits`` object: field names to finite numbers."""
    return isinstance(limits, dict) and all(
        isinstance(k, str) and k and _number(v) for k, v in limits.items()
    )


@dataclass(frozen=True)
class Family:
    path: Path
    name: str
    program: str
    program_blind: str
    train_source: str
    registry: dict[str, Any]  # family.json
    ledger: Ledger
    space: SearchSpace

    @property
    def metric(self) -> str:
        return self.registry["metric"]

    @property
    def metric_label(self) -> str:
        """What the metric is, with its unit, for figures and reports: family.json's ``metric_label``,
        else the metric's field name."""
        return self.registry.get("metric_label") or self.metric

    @property
    def direction(self) -> Direction:
        """sigma_dir: Direction.MAXIMIZE (+1) when larger metric values are better, MINIMIZE (-1) when smaller are."""
        return Direction.of(self.registry["direction"])

    @property
    def target(self) -> float | None:
        return self.registry.get("target")

    @property
    def feasibility_field(self) -> str | None:
        return self.registry.get("feasibility_field")

    @property
    def constraints_field(self) -> str | None:
        return self.registry.get("constraints_field")

    @property
    def limits(self) -> dict[str, float]:
        """The campaign protocol's ``limits``: field -> the largest value a feasible run may report
        (every split's metrics are held to them); empty outside such a protocol."""
        return dict(self.registry.get("limits") or {})

    @property
    def tail_fields(self) -> dict[str, str] | None:
        """family.json's ``tails``: the fields of a split's metrics that describe its worst starts,
        ``runaway_field`` (the share beyond the family's runaway bound) and ``worst_field``; None
        when undeclared (autoresearch.audit.tails)."""
        return self.registry.get("tails")

    @property
    def has_test_split(self) -> bool:
        """Whether train.py scores on a sealed test split with ``--eval-split test``."""
        return self.registry.get("test_split") is True

    @property
    def split_ids(self) -> dict[str, str]:
        """family.json's ``split_ids``: the identity of the data each split is scored on (empty when
        the family pins none); see :func:`autoresearch.splits.split_mismatches`."""
        return dict(self.registry.get(SPLIT_IDS) or {})

    def off_split(
        self, final_metric: dict[str, Any] | None, splits: tuple[Split, ...] = tuple(Split)
    ) -> list[str]:
        """Where a run's FINAL_METRIC says it was scored on data other than the family pins (one line
        per split of ``splits`` it holds metrics for); empty when it was not."""
        held = tuple(s for s in splits if s in split_parts(final_metric or {}))
        return split_mismatches(recorded_split_ids(final_metric), self.split_ids, held)

    @property
    def axes(self) -> tuple[str, ...]:
        return tuple(self.registry["axes"])

    @property
    def baseline_config(self) -> dict[str, Any]:
        return dict(self.registry["baseline"]["config"])

    @property
    def time_budget(self) -> float | None:
        """family.json's ``time_budget``: the training seconds a run of this family is granted by
        default (``loop`` grants it unless told otherwise; karpathy/autoresearch fixes one), so that
        runs are comparable and a campaign's length is known. None when the family declares none."""
        return self.registry.get("time_budget")

    @property
    def default_seed(self) -> int:
        return self.registry.get("default_seed", 0)

    @property
    def seed_noise(self) -> dict[str, Any] | None:
        return self.ledger.seed_noise

    @property
    def best(self) -> dict[str, Any] | None:
        """The current best: {"config", "metric"}, and "time_budget" (training seconds) and "limits"
        (a protocol's) when it was certified under them (family.json's)."""
        return self.registry.get("best")

    def search_registry(self) -> dict[str, Any]:
        """What a campaign copies and every proposer is shown: family.json and the seed noise beside
        it, as one registry, without any number measured on the sealed test split (:func:`search_view`)."""
        declared = {k: v for k, v in self.registry.items() if k != "seed_noise"}  # the old layout's
        return search_view({**declared, "seed_noise": self.seed_noise})

    @property
    def sigma(self) -> float | None:
        """The measured seed noise (std of the metric), when ``autoresearch noise`` has run."""
        return self.seed_noise["std"] if self.seed_noise else None

    def check_outside(self, directory: str | os.PathLike[str]) -> None:
        """Refuse a campaign or run directory at or under the family directory, which holds only the
        family's own files (docs/family-contract.md)."""
        resolved = Path(directory).resolve()
        if resolved == self.path or self.path in resolved.parents:
            raise FamilyError(
                f"{directory}: inside the family directory {self.path}; put campaigns and runs outside it"
            )

    def is_feasible(self, metrics: dict[str, Any]) -> bool:
        """A run counts as best or as reaching the target only when its feasibility field is true (in
        its FINAL_METRIC object, or in one split's metrics) and it reports every limited field within
        its limit (a field missing or not a number fails it)."""
        field = self.feasibility_field
        if field is not None and metrics.get(field) is not True:
            return False
        return all(
            _number(metrics.get(name)) and metrics[name] <= limit for name, limit in self.limits.items()
        )

    def scored(self, final_metric: dict[str, Any]) -> ScoredRun:
        """What a run scored on each split, read from its valid FINAL_METRIC object."""
        return ScoredRun.read(final_metric, self.metric, self.is_feasible)

    def constraints(self, final_metric: dict[str, Any] | None) -> dict[str, float] | None:
        """The run's graded constraints (name -> value, <= 0 satisfied): its constraints field's, and
        for each limit ``<field>_over_limit`` (the field minus its limit). None when there are none,
        or when its FINAL_METRIC object lacks a well-formed constraints field or a limited field."""
        metrics, field = final_metric or {}, self.constraints_field
        if field is None and not self.limits:
            return None
        if field:
            values = metrics.get(field)
        else:  # the gate as 0/1 beside the limits, so that the graded constraints still grade it
            gate = self.feasibility_field
            values = {gate: 0.0 if metrics.get(gate) is True else 1.0} if gate else {}
        if not isinstance(values, dict) or (field and not values):
            return None
        graded = {**values, **{f"{name}_over_limit": metrics.get(name) for name in self.limits}}
        if not all(_number(v) for v in graded.values()):
            return None
        over = {f"{name}_over_limit": limit for name, limit in self.limits.items()}
        return {str(name): float(v) - over.get(name, 0.0) for name, v in graded.items()}

    def completed(self, config: dict[str, Any]) -> dict[str, Any]:
        """An earlier run's configuration with every parameter the search space has gained since at
        its baseline value (the family contract: a new parameter's default keeps the old behaviour)."""
        return {**self.baseline_config, **config}

    @property
    def protocols(self) -> tuple[str, ...]:
        """The protocols family.json declares (``protocols``): named restrictions of its search space."""
        return tuple(self.registry.get("protocols") or {})

    def under_protocol(self, name: str | None) -> Family:
        """This family searched under the protocol ``name`` (None: the whole declared space): every
        parameter of an excluded axis held at its baseline value, and the protocol's bounds in place
        of the declared ones. The train.py, the baseline and the best stay; the registry every
        proposer is shown says which protocol it searches (``protocol``) and the ``limits`` a feasible
        run is held to under it."""
        if name is None:
            return self
        if name not in self.protocols:
            known = ", ".join(self.protocols) or "none"
            raise FamilyError(
                f"--protocol {name}: family {self.name!r} declares no such protocol (it declares {known})"
            )
        registry = json.loads(json.dumps(self.registry))
        registry["search_space"] = protocol_space(registry, name)
        registry["protocol"] = name
        if self.registry["protocols"][name].get("limits"):
            registry["limits"] = self.registry["protocols"][name]["limits"]
        space = SearchSpace.from_json(registry["search_space"], self.axes)
        return replace(self, registry=registry, space=space)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Family:
        path = Path(path).resolve()
        registry, ledger, space, train_source, problems = _read(path)
        if problems:
            raise FamilyError(problems[0])
        return cls(
            path=path,
            name=registry["name"],
            program=(path / "program.md").read_text(encoding="utf-8"),
            program_blind=(path / "program_blind.md").read_text(encoding="utf-8"),
            train_source=train_source,  # the text that was checked, read once
            registry=registry,
            ledger=ledger,
            space=space,
        )


def family_problems(path: str | os.PathLike[str]) -> list[str]:
    """Every problem of a family directory that can be seen without running it, one line each:
    missing files, family.json field by field, and train.py's editable region against it
    (``autoresearch check --family``; :meth:`Family.load` raises the first)."""
    return _read(Path(path).resolve())[-1]


def _read(path: Path) -> tuple[Any, Ledger | None, SearchSpace | None, str | None, list[str]]:
    """(family.json's registry, the ledger, the search space, train.py's text, every problem found)."""
    if not path.is_dir():
        return None, None, None, None, [f"{path}: not a directory"]
    missing = [f for f in REQUIRED_FILES if not (path / f).is_file()]
    problems = [f"{path}: missing {', '.join(missing)} (see docs/family-contract.md)"] if missing else []
    if "family.json" in missing:
        return None, None, None, None, problems
    try:
        registry = json.loads((path / "family.json").read_text(encoding="utf-8"))
    except ValueError as err:  # bad UTF-8 included
        return None, None, None, None, [*problems, f"{path / 'family.json'}: not valid JSON ({err})"]
    except RecursionError:
        return (
            None,
            None,
            None,
            None,
            [*problems, f"{path / 'family.json'}: not valid JSON (nested too deeply)"],
        )
    space, registry_problems = _registry_problems(registry, path / "family.json")
    problems += registry_problems
    ledger = None
    if isinstance(registry, dict):
        where = path / LEDGER_FILE if (path / LEDGER_FILE).exists() else path / "family.json"
        try:
            ledger = Ledger.read(path, registry)
        except JournalError as err:
            problems.append(str(err))
        else:
            problems += _noise_problems(ledger.seed_noise, where)
    texts = {name: _text(path / name, problems) for name in TEXT_FILES if name not in missing}
    source = texts.get("train.py")
    if space is not None and source is not None:
        problems += _train_py_problems(source, registry, space, path / "train.py")
    return registry, ledger, space, source, problems


def _text(path: Path, problems: list[str]) -> str | None:
    """The file's text, or None with the problem noted when it is not UTF-8."""
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        problems.append(f"{path}: not UTF-8 text ({err.reason} at byte {err.start})")
        return None


def _noise_problems(noise: Any, where: Path) -> list[str]:
    """The problems of the seed noise (ledger.json's, or the old layout's in family.json)."""
    problems = []
    if noise is not None and not (
        isinstance(noise, dict) and _number(noise.get("std")) and noise["std"] >= 0
    ):
        problems.append(f"{where}: 'seed_noise' must be null or an object with a finite 'std' >= 0")
    for part, name in ((noise, "seed_noise"), ((noise or {}).get(Split.TEST.value), "seed_noise.test")):
        for key in ("mean", "std"):  # read as numbers by the audit and the prompts
            if isinstance(part, dict) and key in part and not _number(part[key]):
                problems.append(f"{where}: '{name}.{key}' must be a finite number")
    return problems


def _registry_problems(registry: Any, where: Path) -> tuple[SearchSpace | None, list[str]]:
    """The search space (None when it does not parse) and every problem of a family.json."""
    if not isinstance(registry, dict):
        return None, [f"{where}: must hold a JSON object"]
    problems: list[str] = []

    def bad(field: str, why: str) -> None:
        problems.append(f"{where}: '{field}' {why}")

    for field in ("name", "metric"):
        if not isinstance(registry.get(field), str) or not registry[field]:
            bad(field, "must be a non-empty string")
    label = registry.get("metric_label")
    if label is not None and (not isinstance(label, str) or not label.strip()):
        bad("metric_label", "must be a non-empty string or null (the metric in words, with its unit)")
    name = registry.get("name")
    if isinstance(name, str) and name and (not PLAIN_NAME.fullmatch(name) or ".." in name):
        bad("name", f"must be a plain name (letters, digits, '_', '-', '.'; no '/' or '..'), got {name!r}")
    if registry.get("direction") not in ("maximize", "minimize"):
        bad("direction", f"must be 'maximize' or 'minimize', got {registry.get('direction')!r}")
    if registry.get("target") is not None and not _number(registry["target"]):
        bad("target", "must be a finite number or null")
    field = registry.get("feasibility_field")
    if field is not None and (not isinstance(field, str) or not field):
        bad("feasibility_field", "must be a field name or null")
    if not isinstance(registry.get("test_split", False), bool):
        bad("test_split", "must be true or false")
    ids = registry.get(SPLIT_IDS)
    if ids is not None and not (
        isinstance(ids, dict)
        and set(ids) <= {split.value for split in Split}
        and all(isinstance(v, str) and v for v in ids.values())
    ):
        bad(SPLIT_IDS, f"must be null or an object mapping split names ({', '.join(Split)}) to identities")
    if isinstance(ids, dict) and Split.TEST.value in ids and registry.get("test_split") is not True:
        bad(SPLIT_IDS, "pins a test split, but the family declares no test_split")
    constraints = registry.get("constraints_field")
    if constraints is not None and (not isinstance(constraints, str) or not constraints):
        bad("constraints_field", "must be a field name or null")
    if constraints is not None and field is None:
        bad("constraints_field", "needs a feasibility_field: the constraints grade that gate")
    tails = registry.get("tails")
    if tails is not None and not (
        isinstance(tails, dict)
        and isinstance(tails.get("runaway_field"), str)
        and tails["runaway_field"]
        and set(tails) <= {"runaway_field", "worst_field"}
        and all(isinstance(v, str) and v for v in tails.values())
    ):
        bad("tails", "must be null or an object with a 'runaway_field' (and optionally a 'worst_field') name")
    seed = registry.get("default_seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool):
        bad("default_seed", "must be an integer")
    budget = registry.get("time_budget")
    if budget is not None and not (_number(budget) and budget > 0):
        bad(
            "time_budget",
            f"must be a positive number of seconds or null (a run's training budget), got {budget!r}",
        )
    best = registry.get("best")
    if best is not None and not (isinstance(best, dict) and isinstance(best.get("config"), dict)):
        bad("best", "must be null or an object with a 'config'")
    for key in ("metric", "std"):
        if isinstance(best, dict) and best.get(key) is not None and not _number(best[key]):
            bad(f"best.{key}", "must be a finite number or null")
    if (
        isinstance(best, dict)
        and "time_budget" in best
        and not (_number(best["time_budget"]) and best["time_budget"] > 0)
    ):
        bad(
            "best.time_budget",
            "must be a positive number of seconds (the training budget it was certified under)",
        )
    if isinstance(best, dict) and "limits" in best and not _limits_ok(best["limits"]):
        bad("best.limits", "must map field names to finite numbers (the limits it was certified under)")
    axes = registry.get("axes")
    if not isinstance(axes, list) or not axes or not all(isinstance(a, str) and a for a in axes):
        bad("axes", "must be a non-empty list of names")
        return None, problems
    if len(set(axes)) != len(axes):
        bad("axes", "must not repeat a name")
    try:
        space = SearchSpace.from_json(registry.get("search_space"), tuple(axes))
    except SpaceError as err:
        return None, [*problems, f"{where}: {err}"]
    baseline = registry.get("baseline")
    if not isinstance(baseline, dict) or not isinstance(baseline.get("config"), dict):
        bad("baseline", "must be an object with a 'config'")
        return None, problems
    try:
        space.validate_full(baseline["config"])
    except ValidationError as err:
        bad("baseline.config", f"is not a point of the search space: {err}")
        return None, problems
    if baseline.get("metric") is not None and not _number(baseline["metric"]):
        bad("baseline.metric", "must be a finite number or null")
    if "limits" in registry:  # a gate changed under a family's campaigns would re-judge them silently
        bad("limits", "belongs in a protocol (protocols.NAME.limits), which each campaign records")
    problems += [f"{where}: {problem}" for problem in _protocol_problems(registry, tuple(axes))]
    return space, problems


def _train_py_problems(source: str, registry: dict[str, Any], space: SearchSpace, where: Path) -> list[str]:
    try:
        defaults = read_region(source).values()
    except EditableError as err:
        return [f"{where}: {err}"]
    if set(defaults) != set(space.names):
        extra, absent = sorted(set(defaults) - set(space.names)), sorted(set(space.names) - set(defaults))
        return [
            f"{where}: the editable region must assign exactly the search-space parameters"
            + (f"; not in search_space: {extra}" if extra else "")
            + (f"; not in the editable region: {absent}" if absent else "")
        ]
    try:
        canonical = space.validate_full(defaults)
    except ValidationError as err:
        return [f"{where}: an editable default is outside the search space: {err}"]
    baseline = space.validate_full(registry["baseline"]["config"])
    differing = [
        n for n in space.names if canonical[n] != baseline[n] or type(canonical[n]) is not type(baseline[n])
    ]
    if differing:
        return [
            f"{where}: baseline.config in family.json differs from the editable defaults for "
            + ", ".join(f"{n} ({baseline[n]!r} vs {canonical[n]!r})" for n in differing)
        ]
    return []


def protocol_space(registry: dict[str, Any], name: str) -> dict[str, Any]:
    """family.json's search space under its protocol ``name``: ``exclude_axes`` (each parameter of
    those axes held at its baseline value) and ``bounds`` (per parameter, ``low``/``high`` or
    ``choices`` in place of the declared ones; a ``random_range`` reaching outside them is dropped)."""
    protocol = registry["protocols"][name]
    baseline = registry["baseline"]["config"]
    space = json.loads(json.dumps(registry["search_space"]))
    for param, spec in space.items():
        if spec["axis"] in protocol.get("exclude_axes", ()):
            value = baseline[param]
            kept = {"type": spec["type"], "axis": spec["axis"]}
            if spec["type"] in NUMERIC_TYPES:
                kept |= {"low": value, "high": value}
            else:
                kept["choices"] = [value]
            space[param] = kept
    for param, narrowed in protocol.get("bounds", {}).items():
        space[param] = {**space[param], **narrowed}
        if "high" in narrowed:
            space[param].pop("high_exclusive", None)
        inside = space[param].get("random_range")
        if inside and not _within(inside, space[param]):
            del space[param]["random_range"]
    return space


def _within(sub: dict[str, Any], spec: dict[str, Any]) -> bool:
    if "choices" in sub:
        return all(choice in spec["choices"] for choice in sub["choices"])
    return spec["low"] <= sub["low"] and sub["high"] <= spec["high"]


def _protocol_problems(registry: dict[str, Any], axes: tuple[str, ...]) -> list[str]:
    """Each declared protocol must name known axes and parameters, and keep the baseline a point of
    its space."""
    protocols = registry.get("protocols")
    if protocols is None:
        return []
    if not isinstance(protocols, dict) or not all(isinstance(p, dict) for p in protocols.values()):
        return ["'protocols' must map names to objects"]
    problems = []
    for name, protocol in protocols.items():
        unknown = set(protocol) - {"exclude_axes", "bounds", "limits"}
        excluded = protocol.get("exclude_axes", [])
        bounds = protocol.get("bounds", {})
        limits = protocol.get("limits", {})
        if unknown or not isinstance(excluded, list) or not isinstance(bounds, dict):
            problems.append(
                f"protocols.{name}: takes 'exclude_axes' (a list), 'bounds' and 'limits' (objects) only"
            )
            continue
        if not _limits_ok(limits):
            problems.append(f"protocols.{name}: 'limits' must map field names to finite numbers")
            continue
        if set(excluded) - set(axes) or set(bounds) - set(registry["search_space"]):
            problems.append(f"protocols.{name}: names an axis or a parameter the family does not declare")
            continue
        try:
            space = SearchSpace.from_json(protocol_space(registry, name), axes)
            space.validate_full(registry["baseline"]["config"])
        except (SpaceError, ValidationError, TypeError, KeyError) as err:
            problems.append(f"protocols.{name}: {err}")
    return problems


def search_view(registry: dict[str, Any]) -> dict[str, Any]:
    """A copy of a family.json registry holding no number measured on the sealed test split: the
    seed noise without its ``test`` part and no audited family ``best`` (certified on that split;
    a campaign copy's own running best, ``campaign_best``, is a search value and stays). What a
    campaign copies and every proposer is shown, so the search never sees what certifies it."""
    view = json.loads(json.dumps(registry))
    if isinstance(view.get("seed_noise"), dict):
        view["seed_noise"].pop(Split.TEST.value, None)
    view.pop("best", None)
    return view


def _walk_up(start: Path):
    yield start
    yield from start.parents


def find_family_dir(name_or_path: str | os.PathLike[str]) -> Path:
    """A family given as a directory path, else ``./families/<name>``, else ``families/<name>``
    in the nearest parent of the working directory that has it."""
    given = Path(name_or_path)
    if given.is_dir():
        return given
    cwd = Path.cwd()
    if len(given.parts) == 1:
        for root in _walk_up(cwd):
            candidate = root / "families" / given.name
            if candidate.is_dir():
                return candidate
    raise FamilyError(
        f"no family {os.fspath(name_or_path)!r}: it is not a directory, and no families/{given.name} "
        f"exists in {cwd} or any of its parents"
    )


def resolve_family(name_or_path: str | os.PathLike[str]) -> Family:
    """The family :func:`find_family_dir` finds, loaded."""
    return Family.load(find_family_dir(name_or_path))
