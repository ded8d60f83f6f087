import ast
import difflib

import pytest
from loop_helpers import TOY_FAMILY

from autoresearch.editable import EditableError, patch, read_region

TOY_SOURCE = (TOY_FAMILY / "train.py").read_text()

SOURCE = '''"""A docstring that mentions the Editable Configuration banner must not count."""
import os

# ===== Editable Configuration (the agent may change these values only) =====
LR = 1e-3  # learning rate, café
NAME = "it's"  # a string with a quote: ü
WIDTH = (
    64  # a parenthesised value over lines
)
FLAG = False
NEG = -2.5
# ===== Fixed Configuration (immutable below this line) =====
print(LR, NAME, WIDTH, FLAG, NEG)
'''


def test_reads_the_toy_region():
    region = read_region(TOY_SOURCE)
    assert region.values() == {
        "EPOCHS": 10,
        "LEARNING_RATE": 0.01,
        "MOMENTUM": 0.5,
        "BATCH_SIZE": 64,
        "ACTIVATION": "tanh",
        "USE_NORM": False,
        "DROPOUT": 0.0,
    }


def test_patch_keeps_comments_and_formatting():
    patched = patch(TOY_SOURCE, {"LEARNING_RATE": 0.003, "ACTIVATION": "gelu"})
    diff = [
        line
        for line in difflib.unified_diff(TOY_SOURCE.splitlines(), patched.splitlines(), lineterm="", n=0)
        if line[:1] in "+-" and not line.startswith(("+++", "---"))
    ]
    assert diff == [
        "-LEARNING_RATE = 0.01  # step size of the optimizer (log scale)",
        "+LEARNING_RATE = 0.003  # step size of the optimizer (log scale)",
        '-ACTIVATION = "tanh"  # hidden nonlinearity',
        "+ACTIVATION = 'gelu'  # hidden nonlinearity",
    ]
    assert patch(TOY_SOURCE, {}) == TOY_SOURCE


@pytest.mark.parametrize(
    "values",
    [
        {"LR": 3.0e-7, "NAME": 'say "hi" and it\'s \\ fine', "WIDTH": 128, "FLAG": True, "NEG": -0.0},
        {"NAME": "line\nbreak # not a comment", "NEG": 1e300},
        {"NAME": "é ü 漢字", "LR": 1.0},
    ],
)
def test_patch_round_trips_every_type(values):
    patched = patch(SOURCE, values)
    region = read_region(patched)
    for name, value in values.items():
        got = region.values()[name]
        assert got == value and type(got) is type(value)
    assert patched.count("café") == 1 and "# a parenthesised value over lines" in patched
    assert patched.splitlines()[-1] == "print(LR, NAME, WIDTH, FLAG, NEG)"


def test_a_hostile_string_stays_inert_data():
    payload = "tanh'\nimport os; os.system('touch /tmp/pwned')\n#"
    patched = patch(SOURCE, {"NAME": payload})
    tree = ast.parse(patched)
    # Still exactly the same statements: the payload is one string constant.
    assert [type(n).__name__ for n in tree.body] == [type(n).__name__ for n in ast.parse(SOURCE).body]
    assert read_region(patched).values()["NAME"] == payload


@pytest.mark.parametrize(
    ("values", "why"),
    [
        ({"UNKNOWN": 1}, "not in the editable region"),
        ({"LR": float("nan")}, "non-finite"),
        ({"LR": float("inf")}, "non-finite"),
        ({"LR": [1, 2]}, "type list"),
        ({"LR": {"a": 1}}, "type dict"),
        ({"LR": None}, "type NoneType"),
        ({"LR": object()}, "type object"),
    ],
)
def test_patch_refuses(values, why):
    with pytest.raises(EditableError, match=why):
        patch(SOURCE, values)


@pytest.mark.parametrize(
    ("source", "why"),
    [
        ("X = 1\n", "exactly one comment line containing 'Editable Configuration'"),
        ("# Editable Configuration\n# Editable Configuration\nX = 1\n# Fixed Configuration\n", "found 2"),
        ("# Editable Configuration\nX = 1\n", "no comment line containing 'Fixed Configuration'"),
        ("# Editable Configuration\nimport os\n# Fixed Configuration\n", "only `NAME = literal`"),
        ("# Editable Configuration\nX = os.getcwd()\n# Fixed Configuration\n", "not a literal"),
        ("# Editable Configuration\nX = 1 + 2\n# Fixed Configuration\n", "not a literal"),
        ("# Editable Configuration\nX += 1\n# Fixed Configuration\n", "only `NAME = literal`"),
        ("# Editable Configuration\nX = Y = 1\n# Fixed Configuration\n", "only `NAME = literal`"),
        ("# Editable Configuration\nX = 1\nX = 2\n# Fixed Configuration\n", "assigned twice"),
        ("# Editable Configuration\nX = (\n# Fixed Configuration\n1)\n", "straddles"),
        ("# Editable Configuration\nX = (\n", "cannot be tokenized|does not parse"),
    ],
)
def test_malformed_regions(source, why):
    with pytest.raises(EditableError, match=why):
        read_region(source)


def test_banner_text_inside_a_string_is_not_a_banner():
    source = (
        's = """\n# Editable Configuration\n"""\n# Editable Configuration\nX = 1\n# Fixed Configuration\n'
    )
    assert read_region(source).values() == {"X": 1}
