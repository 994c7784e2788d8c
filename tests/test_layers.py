"""How the packages may depend on each other: the tracker library never on the tool, no module on another's
private names or private modules (STYLE.md, "A public face"; issue #46)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted([*ROOT.glob("annotator/**/*.py"), *ROOT.glob("sptpt/**/*.py")])


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def imports_of(path: Path) -> list[tuple[int, str, str | None]]:
    """``(line, module, name)`` of each import of a project module; ``name`` None for ``import module``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found += [(node.lineno, node.module, alias.name) for alias in node.names]
        elif isinstance(node, ast.Import):
            found += [(node.lineno, alias.name, None) for alias in node.names]
    return [(line, module, name) for line, module, name in found if module.split(".")[0] in ("annotator", "sptpt")]


def test_the_tracker_library_never_imports_the_tool():
    offenders = [f"{path.relative_to(ROOT)}:{line} imports {module}" for path in SOURCES
                 if module_name(path).startswith("sptpt") for line, module, _ in imports_of(path)
                 if module.split(".")[0] == "annotator"]
    assert not offenders


def test_no_module_imports_another_modules_private_names():
    offenders = []
    for path in SOURCES:
        here = module_name(path)
        for line, module, name in imports_of(path):
            if name is not None and private(name) and module != here:
                offenders.append(f"{path.relative_to(ROOT)}:{line} imports {name} from {module}")
        tree = ast.parse(path.read_text(encoding="utf-8"))
        aliases = {alias.asname or alias.name: alias.name for node in ast.walk(tree) if isinstance(node, ast.Import)
                   for alias in node.names if alias.name.split(".")[0] in ("annotator", "sptpt")}
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and private(node.attr) and isinstance(node.value, ast.Name) \
                    and node.value.id in aliases and aliases[node.value.id] != here:
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} uses {node.value.id}.{node.attr}")
    assert not offenders


def private_module_outside_its_package(importer: str, module: str) -> str | None:
    """The private part of ``module`` (``annotator.exports._review``: ``_review``) when ``importer`` is not inside
    the package that holds it; None when ``module`` has no private part or ``importer`` may use it."""
    parts = module.split(".")
    for depth, part in enumerate(parts):
        if private(part):
            owner = ".".join(parts[:depth])
            inside = importer == owner or importer.startswith(owner + ".")
            return None if inside else part
    return None


@pytest.mark.parametrize("importer, module, expected", [
    ("annotator.review.imports", "annotator.exports._review", "_review"),
    ("annotator.exports.cvat", "annotator.exports._review", None),
    ("annotator.exports", "annotator.exports._review", None),
    ("sptpt.tracker", "sptpt._kernels.snic", None),
    ("annotator.pipeline", "sptpt._kernels.snic", "_kernels"),
    ("annotator.review.imports", "annotator.exports.review_tools", None),
])
def test_private_module_rule(importer, module, expected):
    assert private_module_outside_its_package(importer, module) == expected


def test_no_module_imports_another_packages_private_module():
    offenders = [f"{path.relative_to(ROOT)}:{line} imports {module}" for path in SOURCES
                 for line, module, _ in imports_of(path)
                 if private_module_outside_its_package(module_name(path), module)]
    assert not offenders


#: Longest function in ``annotator/`` (def line to the last line of its body, docstring included): issue #46.
MAX_FUNCTION_LINES = 80


def long_functions(source: str, limit: int = MAX_FUNCTION_LINES) -> list[tuple[str, int, int]]:
    """``(name, first line, lines)`` of each function or method in ``source`` longer than ``limit`` lines."""
    return [(node.name, node.lineno, node.end_lineno - node.lineno + 1) for node in ast.walk(ast.parse(source))
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno >= limit]


def function_text(name: str, lines: int, indent: str = "") -> str:
    """A function of exactly ``lines`` lines, def line included."""
    return f"{indent}def {name}():\n" + "".join(f"{indent}    x = {k}\n" for k in range(lines - 1))


@pytest.mark.parametrize("source, expected", [
    (function_text("fits", 80), []),
    (function_text("over", 81), [("over", 1, 81)]),
    ("class C:\n" + function_text("method", 81, indent="    "), [("method", 2, 81)]),
    ("x = 1\n\n" + function_text("later", 90), [("later", 3, 90)]),
])
def test_long_functions_counts_from_def_to_the_last_line_of_the_body(source, expected):
    assert long_functions(source) == expected


def test_no_function_in_the_tool_is_over_80_lines():
    offenders = [f"{path.relative_to(ROOT)}:{line} {name} has {lines} lines"
                 for path in sorted(ROOT.glob("annotator/**/*.py"))
                 for name, line, lines in long_functions(path.read_text(encoding="utf-8"))]
    assert not offenders
