"""A family's search space in Optuna's terms: one distribution per parameter, for the Optuna arms
(TPE, GP) and for the campaign's Optuna journal (autoresearch.optuna_journal).

``off_at_zero`` (``loop --off-at-zero``): a real parameter whose range starts at 0 (dropout, weight
decay) also gets a switch, ``NAME:off``, a categorical the sampler models like any other; a config
whose value is exactly 0 is told as switched off. A sampler's density over a continuous range puts no
mass on its end point, so without the switch it can come near "off" but never reach it, and a
regulariser that is merely small can cost as much as one that is large (a probe on rendezvous: dropout
0.002 doubled the hand recipe's terminal distance).
"""

from __future__ import annotations

import math
from typing import Any

from optuna.distributions import BaseDistribution, CategoricalDistribution, FloatDistribution, IntDistribution

from autoresearch.space import ParamSpec, SearchSpace


def distribution(param: ParamSpec) -> BaseDistribution:
    if param.type == "int":
        return IntDistribution(int(param.low), int(param.high) - (1 if param.high_exclusive else 0))
    if param.type in ("real", "log-real"):
        high = math.nextafter(param.high, param.low) if param.high_exclusive else param.high
        return FloatDistribution(float(param.low), float(high), log=param.type == "log-real")
    if param.type == "bool":
        return CategoricalDistribution(param.choices or (False, True))
    return CategoricalDistribution(tuple(param.choices or ()))


OFF = ":off"  # the suffix of a parameter's off switch (off_at_zero)


def switchable(space: SearchSpace) -> tuple[str, ...]:
    """The parameters ``off_at_zero`` gives a switch: the real ones whose range starts at 0."""
    return tuple(name for name, param in space.params.items() if param.type == "real" and param.low == 0)


def distributions(space: SearchSpace, off_at_zero: bool = False) -> dict[str, BaseDistribution]:
    result = {name: distribution(param) for name, param in space.params.items()}
    if off_at_zero:
        result |= {name + OFF: CategoricalDistribution((False, True)) for name in switchable(space)}
    return result


def to_params(config: dict[str, Any], switched: tuple[str, ...]) -> dict[str, Any]:
    """A config as Optuna params: each switched parameter's switch on where its value is exactly 0."""
    return config | {name + OFF: config[name] == 0 for name in switched}


def from_params(params: dict[str, Any], switched: tuple[str, ...]) -> dict[str, Any]:
    """Optuna params as a config: a parameter switched off is 0, whatever value was drawn beside it."""
    config = {name: value for name, value in params.items() if not name.endswith(OFF)}
    return config | {name: 0.0 for name in switched if params[name + OFF]}
