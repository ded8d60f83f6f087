"""Read and patch the editable region of a family's train.py.

The region lies between a comment line containing ``Editable Configuration`` and the next
comment line containing ``Fixed Configuration``, and holds only top-level ``NAME = literal``
assignments. Reading uses ``ast`` (``ast.literal_eval`` on each value node, nothing is run);
patching writes ``repr`` of an already-validated scalar over the old value expression's exact
text span, so comments and formatting survive, then re-parses the result and checks that every
value reads back equal. Nothing from a proposal is ever evaluated or executed.
"""

from __future__ import annotations

import ast
import io
import math
import threading
import tokenize
from dataclasses import dataclass
from typing import Any

_PARSE_LOCK = threading.Lock()

OPEN_BANNER = "Editable Configuration"
CLOSE_BANNER = "Fixed Configuration"


class EditableError(ValueError):
    """train.py's editable region is malformed, or a patch was refused."""


@dataclass(frozen=True)
class Assignment:
    """One ``NAME = literal`` line: its value and the character span of the value expression."""

    name: str
    value: Any
    lineno: int
    start: int
    end: int


@dataclass(frozen=True)
class EditableRegion:
    source: str
    open_line: int  # 1-based line numbers of the two banners
    close_line: int
    assignments: dict[str, Assignment]

    def values(self) -> dict[str, Any]:
        return {name: a.value for name, a in self.assignments.items()}


def _comment_lines(source: str) -> list[tuple[int, str]]:
    """(line number, text) of every line that holds only a comment (tokenize skips strings)."""
    found = []
    try:
        for tok in tokenize.generate_tokens(io.StringIO(source).readline):
            if tok.type == tokenize.COMMENT and not tok.line[: tok.start[1]].strip():
                found.append((tok.start[0], tok.string))
    except (tokenize.TokenError, SyntaxError) as err:
        raise EditableError(f"train.py cannot be tokenized: {err}") from None
    return found


def _offsets(source: str) -> list[int]:
    starts, pos = [], 0
    for line in source.splitlines(keepends=True):
        starts.append(pos)
        pos += len(line)
    starts.append(pos)
    return starts


def read_region(source: str) -> EditableRegion:
    """Parse the editable region of ``source``; :class:`EditableError` names what is wrong."""
    comments = _comment_lines(source)
    opens = [n for n, text in comments if OPEN_BANNER in text]
    if len(opens) != 1:
        raise EditableError(
            f"train.py needs exactly one comment line containing {OPEN_BANNER!r}, found {len(opens)}"
        )
    closes = [n for n, text in comments if CLOSE_BANNER in text and n > opens[0]]
    if not closes:
        raise EditableError(
            f"train.py has no comment line containing {CLOSE_BANNER!r} after the editable banner"
        )
    open_line, close_line = opens[0], closes[0]
    try:
        # CPython 3.11's AST constructor is not safe across threads (seen here as "SystemError: AST
        # constructor recursion depth mismatch" under the audit's threaded pool), so parsing is serialised.
        with _PARSE_LOCK:
            tree = ast.parse(source)
    except SyntaxError as err:
        raise EditableError(f"train.py does not parse: {err}") from None

    lines = source.splitlines(keepends=True)
    starts = _offsets(source)

    def char_offset(lineno: int, col_bytes: int) -> int:
        # ast columns count UTF-8 bytes; the text is indexed by characters.
        line = lines[lineno - 1]
        return starts[lineno - 1] + len(line.encode("utf-8")[:col_bytes].decode("utf-8"))

    assignments: dict[str, Assignment] = {}
    for node in tree.body:
        end_lineno = node.end_lineno or node.lineno
        if end_lineno < open_line or node.lineno > close_line:
            continue
        if node.lineno < open_line or end_lineno > close_line:
            raise EditableError(f"line {node.lineno}: a statement straddles an editable-region banner")
        if not (
            isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)
        ):
            raise EditableError(
                f"line {node.lineno}: the editable region may hold only `NAME = literal` assignments"
            )
        name = node.targets[0].id
        if name in assignments:
            raise EditableError(f"line {node.lineno}: {name} is assigned twice in the editable region")
        try:
            value = ast.literal_eval(node.value)
        except ValueError:
            raise EditableError(f"line {node.lineno}: the value of {name} is not a literal") from None
        value_node = node.value
        start = char_offset(value_node.lineno, value_node.col_offset)
        end = char_offset(value_node.end_lineno or value_node.lineno, value_node.end_col_offset or 0)
        assignments[name] = Assignment(name, value, node.lineno, start, end)
    return EditableRegion(source, open_line, close_line, assignments)


def _literal(name: str, value: Any) -> str:
    """The source text for a scalar value; anything but bool/int/float/str is refused."""
    if isinstance(value, float) and not math.isfinite(value):
        raise EditableError(f"{name}: refusing to write the non-finite value {value!r}")
    if type(value) not in (bool, int, float, str):
        raise EditableError(f"{name}: refusing to write a value of type {type(value).__name__}")
    return repr(value)


def patch(source: str, values: dict[str, Any]) -> str:
    """``source`` with the named editable values replaced by ``values`` (already validated)."""
    region = read_region(source)
    unknown = [n for n in values if n not in region.assignments]
    if unknown:
        raise EditableError(f"not in the editable region: {', '.join(map(repr, unknown))}")
    patched = source
    for name in sorted(values, key=lambda n: region.assignments[n].start, reverse=True):
        a = region.assignments[name]
        patched = patched[: a.start] + _literal(name, values[name]) + patched[a.end :]

    check = read_region(patched)
    for name, assignment in region.assignments.items():
        got = check.assignments.get(name)
        want = values.get(name, assignment.value)
        if got is None or type(got.value) is not type(want) or got.value != want:
            raise EditableError(f"{name}: the patched file does not read back {want!r}")
    if set(check.assignments) != set(region.assignments):
        raise EditableError("the patched editable region does not hold the same names")
    starts = _offsets(source)
    head, tail = starts[region.open_line], len(source) - starts[region.close_line - 1]
    if patched[:head] != source[:head] or patched[-tail:] != source[-tail:]:
        raise EditableError("the patch touched text outside the editable region")
    return patched
