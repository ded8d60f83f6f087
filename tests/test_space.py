import math
import random
import statistics

import pytest
from loop_helpers import TOY_FAMILY

from autoresearch.family import Family
from autoresearch.space import SearchSpace, SpaceError, ValidationError, canonical_key

AXES = ("a", "b")


@pytest.fixture(scope="module")
def space():
    return Family.load(TOY_FAMILY).space


def test_canonical_forms(space):
    got = space.validate(
        {"BATCH_SIZE": 64.0, "EPOCHS": 3.0, "DROPOUT": 0, "MOMENTUM": -0.0, "USE_NORM": True}
    )
    assert got == {"EPOCHS": 3, "MOMENTUM": 0.0, "BATCH_SIZE": 64, "USE_NORM": True, "DROPOUT": 0.0}
    assert type(got["EPOCHS"]) is int and type(got["BATCH_SIZE"]) is int and type(got["DROPOUT"]) is float
    assert math.copysign(1, got["MOMENTUM"]) == 1.0
    assert canonical_key({"LEARNING_RATE": 1e-3, "EPOCHS": 5}) == canonical_key(
        {"EPOCHS": 5, "LEARNING_RATE": 0.001}
    )


@pytest.mark.parametrize(
    ("name", "value", "why"),
    [
        ("EPOCHS", True, "expected an integer"),
        ("EPOCHS", "3", "expected an integer"),
        ("EPOCHS", 3.5, "expected an integer"),
        ("EPOCHS", 61, "outside [0, 60]"),
        ("EPOCHS", None, "expected an integer"),
        ("LEARNING_RATE", "1e-3", "expected a number"),
        ("LEARNING_RATE", float("nan"), "not finite"),
        ("LEARNING_RATE", float("inf"), "not finite"),
        ("LEARNING_RATE", 0.5, "outside"),
        ("LEARNING_RATE", False, "expected a number"),
        ("MOMENTUM", 1.0, "outside [0.0, 1.0)"),
        ("MOMENTUM", [0.5], "expected a number"),
        ("DROPOUT", {"v": 0.1}, "expected a number"),
        ("BATCH_SIZE", 48, "is not one of 16, 32, 64, 128"),
        ("BATCH_SIZE", "64", "is not one of"),
        ("BATCH_SIZE", True, "is not one of"),
        ("ACTIVATION", "TANH", "is not one of 'tanh', 'relu', 'gelu'"),
        ("ACTIVATION", 1, "is not one of"),
        ("USE_NORM", 1, "expected true or false"),
        ("USE_NORM", "true", "expected true or false"),
    ],
)
def test_refusals_name_the_reason(space, name, value, why):
    with pytest.raises(ValidationError, match=r"^" + name) as err:
        space.validate({name: value})
    assert why in str(err.value)


def test_unknown_keys_and_non_maps(space):
    with pytest.raises(ValidationError, match=r"unknown key.*'HIDDEN'.*the editable keys are EPOCHS"):
        space.validate({"HIDDEN": 3, "EPOCHS": 5})
    with pytest.raises(ValidationError, match="must be an object"):
        space.validate("EPOCHS=5")
    with pytest.raises(ValidationError, match="missing value"):
        space.validate_full({"EPOCHS": 5})
    # Every reason is reported at once.
    with pytest.raises(ValidationError, match=r"EPOCHS.*; LEARNING_RATE"):
        space.validate({"EPOCHS": -1, "LEARNING_RATE": "x"})


def test_sampling_laws(space):
    rng = random.Random(1)
    draws = [space.sample(rng) for _ in range(3000)]
    for d in draws[:200]:
        assert space.validate_full(d) == d
    epochs = [d["EPOCHS"] for d in draws]
    assert min(epochs) == 5 and max(epochs) == 50  # the random_range sub-range, inclusive
    logs = [math.log10(d["LEARNING_RATE"]) for d in draws]
    assert abs(statistics.median(logs) - (-2.5)) < 0.1  # log-uniform over [1e-4, 1e-1]
    assert abs(statistics.mean(d["DROPOUT"] for d in draws) - 0.25) < 0.02  # uniform over [0, 0.5]
    assert max(d["MOMENTUM"] for d in draws) < 1.0
    for name, choices in (("BATCH_SIZE", [16, 32, 64, 128]), ("ACTIVATION", ["tanh", "relu", "gelu"])):
        counts = [sum(d[name] == c for d in draws) for c in choices]
        assert min(counts) > 0.8 * len(draws) / len(choices)
    assert 0.45 < statistics.mean(d["USE_NORM"] for d in draws) < 0.55
    assert [space.sample(random.Random(7)) for _ in range(2)] == [
        space.sample(random.Random(7)) for _ in range(2)
    ]


def test_categorical_random_range_and_exclusive_int():
    space = SearchSpace.from_json(
        {
            "K": {"type": "int", "low": 0, "high": 3, "high_exclusive": True, "axis": "a"},
            "C": {
                "type": "categorical",
                "choices": ["x", "y", "z"],
                "axis": "b",
                "random_range": {"choices": ["y"]},
            },
        },
        AXES,
    )
    draws = [space.sample(random.Random(i)) for i in range(200)]
    assert {d["K"] for d in draws} == {0, 1, 2}
    assert {d["C"] for d in draws} == {"y"}
    with pytest.raises(ValidationError, match="outside"):
        space.validate({"K": 3})


@pytest.mark.parametrize(
    ("spec", "why"),
    [
        ({"type": "float", "axis": "a"}, "'type' must be one of"),
        ({"type": "int", "low": 0, "high": 5, "axis": "zz"}, "'axis' must be one of"),
        ({"type": "int", "low": 0.5, "high": 5, "axis": "a"}, "integer 'low' and 'high'"),
        ({"type": "log-real", "low": 0, "high": 1, "axis": "a"}, "'low' > 0"),
        ({"type": "real", "low": 1, "high": 1, "high_exclusive": True, "axis": "a"}, "is empty"),
        ({"type": "real", "low": 0, "high": "1", "axis": "a"}, "finite numbers"),
        ({"type": "categorical", "choices": [], "axis": "a"}, "non-empty 'choices'"),
        ({"type": "categorical", "choices": [1, 1], "axis": "a"}, "distinct"),
        ({"type": "categorical", "choices": [True, False], "axis": "a"}, "strings or finite numbers"),
        ({"type": "bool", "axis": "a", "low": 0}, "unknown field"),
        (
            {"type": "int", "low": 0, "high": 5, "axis": "a", "random_range": {"low": 0, "high": 9}},
            "random_range",
        ),
        ({"type": "bool", "axis": "a", "random_range": {"low": 0, "high": 1}}, "random_range"),
    ],
)
def test_malformed_spaces_are_refused(spec, why):
    with pytest.raises(SpaceError, match=why):
        SearchSpace.from_json({"P": spec}, AXES)
    with pytest.raises(SpaceError, match="Python identifier"):
        SearchSpace.from_json({"not a name": {"type": "bool", "axis": "a"}}, AXES)


def test_searched_spaces(space):
    bounds, narrow = space.searched("bounds"), space.searched("random-range")
    epochs = bounds.params["EPOCHS"]
    assert (epochs.low, epochs.high, epochs.random_range) == (0, 60, None)  # the declared bounds
    assert (narrow.params["EPOCHS"].low, narrow.params["EPOCHS"].high) == (5, 50)
    assert narrow.params["MOMENTUM"] == bounds.params["MOMENTUM"]  # no random_range: its bounds
    rng = random.Random(0)
    assert max(bounds.sample(rng)["EPOCHS"] for _ in range(2000)) > 50
    assert narrow.contains({**space.sample(rng), "EPOCHS": 50})
    assert not narrow.contains({**space.sample(rng), "EPOCHS": 55}) and space.contains(
        {**space.sample(rng), "EPOCHS": 55}
    )
    with pytest.raises(ValueError, match="unknown search space 'full'"):
        space.searched("full")


def test_narrowed_choices_and_bools():
    narrow = SearchSpace.from_json(
        {
            "K": {
                "type": "categorical",
                "choices": ["x", "y", "z"],
                "axis": "a",
                "random_range": {"choices": ["y"]},
            },
            "F": {"type": "bool", "axis": "b", "random_range": {"choices": [True]}},
        },
        AXES,
    ).searched("random-range")
    assert narrow.params["K"].choices == ("y",)
    assert narrow.sample(random.Random(1)) == {"K": "y", "F": True}
    with pytest.raises(ValidationError, match="F: expected true, got False"):
        narrow.validate({"F": False})
