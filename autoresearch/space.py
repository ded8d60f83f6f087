"""The configuration space of a family (paper Eq. config-space) and its validation.

Every value a proposer suggests passes through :meth:`SearchSpace.validate` before anything is
written or run. Validation is strict on purpose: a proposer's output is untrusted text, so a
value is accepted only if it already has the declared Python type (``True`` is not an int,
``"1e-3"`` is not a number) and lies inside the declared domain. The validated value is put into
a canonical form so that equal configurations compare equal for deduplication.
"""

from __future__ import annotations

import json
import math
import random
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

PARAM_TYPES = ("int", "real", "log-real", "categorical", "bool")
NUMERIC_TYPES = ("int", "real", "log-real")
# What a key-free arm searches: every parameter's declared bounds (the paper's Table 1), or each
# parameter's ``random_range`` where it declares one (its bounds where it does not).
SPACES = ("bounds", "random-range")


class SpaceError(ValueError):
    """The search space declared in family.json is malformed."""


class ValidationError(ValueError):
    """A proposed value or override map is refused; the message says why."""


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def is_finite_number(value: Any) -> bool:
    """A number a float holds finitely. JSON integers are unbounded and ``math.isfinite(10**400)``
    raises OverflowError, so an integer counts only when float() can hold it."""
    if not _is_number(value):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def _describe(value: Any) -> str:
    try:
        text = repr(value)
    except ValueError:  # an integer of more digits than int -> str converts
        return f"an integer of about {value.bit_length() * 0.30103:.0f} digits"
    return text if len(text) <= 80 else text[:77] + "..."


@dataclass(frozen=True)
class ParamSpec:
    """One editable hyperparameter: its type, domain, axis and optional random-search sub-range."""

    name: str
    type: str
    axis: str
    low: float | None = None
    high: float | None = None
    high_exclusive: bool = False
    choices: tuple[Any, ...] | None = None
    random_range: Mapping[str, Any] | None = None

    @classmethod
    def from_json(cls, name: str, spec: Any, axes: tuple[str, ...]) -> ParamSpec:
        where = f"search_space[{name!r}]"
        if not name.isidentifier():
            raise SpaceError(f"{where}: the name must be a Python identifier")
        if not isinstance(spec, dict):
            raise SpaceError(f"{where} must be an object")
        kind = spec.get("type")
        if kind not in PARAM_TYPES:
            raise SpaceError(f"{where}: 'type' must be one of {', '.join(PARAM_TYPES)}, got {kind!r}")
        axis = spec.get("axis")
        if axis not in axes:
            raise SpaceError(f"{where}: 'axis' must be one of the family's axes {list(axes)}, got {axis!r}")
        allowed = {"type", "axis", "random_range"}
        fields: dict[str, Any] = {}
        if kind in NUMERIC_TYPES:
            allowed |= {"low", "high", "high_exclusive"}
            low, high = spec.get("low"), spec.get("high")
            if not (is_finite_number(low) and is_finite_number(high)):
                raise SpaceError(f"{where}: 'low' and 'high' must be finite numbers a float can hold")
            if kind == "int" and not (isinstance(low, int) and isinstance(high, int)):
                raise SpaceError(f"{where}: an int parameter needs integer 'low' and 'high'")
            if kind == "log-real" and low <= 0:
                raise SpaceError(f"{where}: a log-real parameter needs 'low' > 0")
            exclusive = spec.get("high_exclusive", False)
            if not isinstance(exclusive, bool):
                raise SpaceError(f"{where}: 'high_exclusive' must be true or false")
            if not (low < high or (low == high and not exclusive)):
                raise SpaceError(f"{where}: the domain [{low}, {high}{')' if exclusive else ']'} is empty")
            if kind != "log-real" and not math.isfinite(float(high) - float(low)):  # the samplers' arithmetic
                raise SpaceError(f"{where}: the width high - low must be a number a float can hold")
            fields = {"low": low, "high": high, "high_exclusive": exclusive}
        elif kind == "bool" and "choices" in spec:  # a bool held to one value (a protocol's restriction)
            allowed.add("choices")
            choices = spec["choices"]
            if not (isinstance(choices, list) and choices and all(isinstance(c, bool) for c in choices)):
                raise SpaceError(
                    f"{where}: a bool parameter's 'choices' must be a non-empty list of true/false"
                )
            fields = {"choices": tuple(dict.fromkeys(choices))}
        elif kind == "categorical":
            allowed.add("choices")
            choices = spec.get("choices")
            if not isinstance(choices, list) or not choices:
                raise SpaceError(f"{where}: a categorical parameter needs a non-empty 'choices' list")
            for choice in choices:
                if not (isinstance(choice, str) or is_finite_number(choice)):
                    raise SpaceError(f"{where}: choices must be strings or finite numbers, got {choice!r}")
            if len({json.dumps(c) for c in choices}) != len(choices):
                raise SpaceError(f"{where}: choices must be distinct")
            fields = {"choices": tuple(choices)}
        unknown = sorted(set(spec) - allowed)
        if unknown:
            raise SpaceError(f"{where}: unknown field(s) {unknown} for type {kind!r}")
        param = cls(name=name, type=kind, axis=axis, random_range=spec.get("random_range"), **fields)
        if param.random_range is not None:
            param._check_random_range()
        return param

    def _check_random_range(self) -> None:
        where = f"search_space[{self.name!r}].random_range"
        rr = self.random_range
        if not isinstance(rr, dict):
            raise SpaceError(f"{where} must be an object")
        if self.type in NUMERIC_TYPES:
            if set(rr) != {"low", "high"}:
                raise SpaceError(f"{where}: a numeric parameter's sub-range is {{'low', 'high'}}")
            try:
                low, high = self.validate(rr["low"]), self.validate(rr["high"])
            except ValidationError as err:
                raise SpaceError(f"{where}: {err}") from None
            if low > high:
                raise SpaceError(f"{where}: low > high")
        else:
            choices = rr.get("choices")
            if set(rr) != {"choices"} or not isinstance(choices, list) or not choices:
                raise SpaceError(f"{where}: a {self.type} parameter's sub-range is {{'choices': [...]}}")
            for choice in choices:
                try:
                    self.validate(choice)
                except ValidationError as err:
                    raise SpaceError(f"{where}: {err}") from None

    def bounds_text(self) -> str:
        if self.type in NUMERIC_TYPES:
            return f"[{self.low}, {self.high}{')' if self.high_exclusive else ']'}"
        if self.type == "bool":
            return "true or false" if self.choices is None else " or ".join(map(str, self.choices)).lower()
        return "one of " + ", ".join(repr(c) for c in self.choices or ())

    def validate(self, value: Any) -> Any:
        """The canonical form of ``value``, or :class:`ValidationError` saying why it is refused."""
        name = self.name
        if self.type == "bool":
            if not isinstance(value, bool) or (self.choices is not None and value not in self.choices):
                raise ValidationError(f"{name}: expected {self.bounds_text()}, got {_describe(value)}")
            return value
        if self.type == "categorical":
            if isinstance(value, str) or _is_number(value):
                for choice in self.choices or ():
                    # A string never equals a number here, and 64.0 maps onto the choice 64.
                    if isinstance(choice, str) == isinstance(value, str) and choice == value:
                        return choice
            raise ValidationError(f"{name}: {_describe(value)} is not {self.bounds_text()}")
        if not _is_number(value):
            kind = "an integer" if self.type == "int" else "a number"
            raise ValidationError(f"{name}: expected {kind}, got {type(value).__name__} {_describe(value)}")
        if isinstance(value, float) and not math.isfinite(value):
            raise ValidationError(f"{name}: {value!r} is not finite")
        if self.type == "int" and isinstance(value, float) and not value.is_integer():
            raise ValidationError(f"{name}: expected an integer, got {value!r}")
        # Python compares an int with a float exactly, so an integer float() cannot hold (10**400)
        # is refused here as out of bounds before anything converts it.
        assert self.low is not None and self.high is not None
        above = value >= self.high if self.high_exclusive else value > self.high
        if value < self.low or above:
            raise ValidationError(f"{name}: {_describe(value)} is outside {self.bounds_text()}")
        return int(value) if self.type == "int" else float(value) + 0.0  # + 0.0 folds -0.0 into 0.0

    def sample(self, rng: random.Random) -> Any:
        """One draw from this axis's law (paper Eq. randsearch), over ``random_range`` if declared."""
        rr = self.random_range or {}
        if self.type in ("categorical", "bool"):
            choices = rr.get("choices") or self.choices or (False, True)
            return self.validate(rng.choice(list(choices)))
        low, high = rr.get("low", self.low), rr.get("high", self.high)
        exclusive = self.high_exclusive and high == self.high
        if self.type == "int":
            return rng.randint(int(low), int(high) - 1 if exclusive else int(high))
        while True:
            if self.type == "log-real":
                value = math.exp(rng.uniform(math.log(low), math.log(high)))
            else:
                value = rng.uniform(low, high)
            value = min(max(value, low), high)  # exp/log round-off can step just outside
            if not (exclusive and value >= high):
                return self.validate(value)

    def narrowed(self) -> ParamSpec:
        """This parameter with its domain replaced by its ``random_range`` (itself if none)."""
        rr = self.random_range
        if rr is None:
            return self
        if self.type in NUMERIC_TYPES:  # a valid sub-range's high lies inside the domain: inclusive
            low, high = self.validate(rr["low"]), self.validate(rr["high"])
            return replace(self, low=low, high=high, high_exclusive=False, random_range=None)
        return replace(self, choices=tuple(self.validate(c) for c in rr["choices"]), random_range=None)


class SearchSpace:
    """The product of the family's parameter domains, in family.json order."""

    def __init__(self, params: list[ParamSpec]):
        self.params: dict[str, ParamSpec] = {p.name: p for p in params}

    @classmethod
    def from_json(cls, search_space: Any, axes: tuple[str, ...]) -> SearchSpace:
        if not isinstance(search_space, dict) or not search_space:
            raise SpaceError("'search_space' must be a non-empty object")
        return cls([ParamSpec.from_json(name, spec, axes) for name, spec in search_space.items()])

    @property
    def names(self) -> list[str]:
        return list(self.params)

    def validate(self, overrides: Any) -> dict[str, Any]:
        """Canonical {name: value} for an override map, or :class:`ValidationError` with every reason."""
        if not isinstance(overrides, dict):
            raise ValidationError(
                f"overrides must be an object mapping names to values, got {_describe(overrides)}"
            )
        reasons, canonical = [], {}
        unknown = [k for k in overrides if k not in self.params]
        if unknown:
            reasons.append(
                f"unknown key(s) {', '.join(_describe(k) for k in unknown)}; "
                f"the editable keys are {', '.join(self.params)}"
            )
        for name, param in self.params.items():
            if name in overrides:
                try:
                    canonical[name] = param.validate(overrides[name])
                except ValidationError as err:
                    reasons.append(str(err))
        if reasons:
            raise ValidationError("; ".join(reasons))
        return canonical

    def validate_full(self, config: Any) -> dict[str, Any]:
        """Like :meth:`validate`, and every parameter must be present."""
        canonical = self.validate(config)
        missing = [name for name in self.params if name not in canonical]
        if missing:
            raise ValidationError(f"missing value(s) for {', '.join(missing)}")
        return canonical

    def searched(self, which: str) -> SearchSpace:
        """The space a key-free arm searches (one of :data:`SPACES`); its draws follow its own domains."""
        if which == "bounds":
            return SearchSpace([replace(p, random_range=None) for p in self.params.values()])
        if which == "random-range":
            return SearchSpace([p.narrowed() for p in self.params.values()])
        raise ValueError(f"unknown search space {which!r}; choose one of {', '.join(SPACES)}")

    def contains(self, config: Mapping[str, Any]) -> bool:
        try:
            self.validate_full(dict(config))
        except ValidationError:
            return False
        return True

    def sample(self, rng: random.Random) -> dict[str, Any]:
        return {name: param.sample(rng) for name, param in self.params.items()}

    def axes_of(self, names: list[str] | set[str]) -> set[str]:
        return {self.params[n].axis for n in names if n in self.params}


def canonical_key(mapping: Mapping[str, Any]) -> str:
    """A string equal for equal canonical maps (key order ignored); used for deduplication."""
    return json.dumps(dict(sorted(mapping.items())), sort_keys=True, separators=(",", ":"))
