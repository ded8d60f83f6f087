"""The package's layers (docs/overview.md, "The layers"): every module imports only from its own layer
and the layers below, no two modules import each other round a circle, and the agent stays apart from
the envs and torch. Read from the code's own import statements, those inside functions included."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "autoresearch"
# Bottom up. A part is a module or a sub-package directly under autoresearch/.
LAYERS = (
    ("direction", "extras", "space", "journal", "editable", "provenance", "splits", "exits"),
    ("verdicts", "ledger"),
    ("family",),
    ("proposers", "templates"),
    ("execution",),
    ("campaign",),
    ("loop", "optuna_journal"),
    ("audit",),
    ("compare",),
    ("commands",),
    ("cli", "__main__"),
)
LAYER = {part: i for i, parts in enumerate(LAYERS) for part in parts}


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> set[str]:
    """Every autoresearch module that ``path`` imports, at any depth of its code."""
    found, package = set(), module_name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            found |= {base} | {f"{base}.{alias.name}" for alias in node.names}
    return {name for name in found if name == "autoresearch" or name.startswith("autoresearch.")}


def part(module: str) -> str | None:
    """The layer part of a module: ``autoresearch.execution.runner`` -> ``execution``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


MODULES = {module_name(p): p for p in PACKAGE.rglob("*.py")}
GRAPH = {name: {m for m in imports(p) if m in MODULES and m != name} for name, p in MODULES.items()}


def test_every_part_has_a_layer():
    assert {part(m) for m in MODULES} - {None} <= set(LAYER), "a new module: give it a layer in LAYERS"


def test_no_module_imports_from_a_layer_above_its_own():
    upward = [
        f"{name} (layer {LAYER[part(name)]}) imports {target} (layer {LAYER[part(target)]})"
        for name, targets in GRAPH.items()
        if part(name) is not None
        for target in targets
        if part(target) is not None and LAYER[part(target)] > LAYER[part(name)]
    ]
    assert upward == []


def test_no_modules_import_each_other_round_a_circle():
    circles, state = [], {}

    def visit(name: str, path: list[str]) -> None:
        state[name] = "open"
        for target in sorted(GRAPH[name]):
            if state.get(target) == "open":
                circles.append(" -> ".join([*path[path.index(target) :], target]))
            elif target not in state:
                visit(target, [*path, target])
        state[name] = "done"

    for name in sorted(GRAPH):
        if name not in state:
            visit(name, [name])
    assert circles == []


def test_the_agent_never_imports_the_envs_torch_or_a_family_and_the_envs_never_the_agent():
    for path in PACKAGE.rglob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        names |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and not n.level}
        assert not {n.split(".")[0] for n in names} & {"cwh_envs", "torch", "families"}, path
    for path in (ROOT / "cwh_envs").rglob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        names |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and not n.level}
        assert "autoresearch" not in {n.split(".")[0] for n in names}, path
