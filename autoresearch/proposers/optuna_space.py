"""A family's search space in Optuna's terms: one distribution per parameter, for the Optuna arms
(TPE, GP) and for the campaign's Optuna journal (autoresearch.optuna_journal)."""

from __future__ import annotations

import math

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


def distributions(space: SearchSpace) -> dict[str, BaseDistribution]:
    return {name: distribution(param) for name, param in space.params.items()}
