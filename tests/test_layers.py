"""How the packages may depend on each other: the tracker library never on the tool, no module on another's
private names or private modules (``docs/design/code.md``, "Layers" and "A public face"; issue #46)."""

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


#: What the tool may import of the tracker library: its public names, and its public box-geometry module.
SPTPT_PUBLIC = {"sptpt", "sptpt.boxes"}


def test_the_tool_uses_only_the_tracker_librarys_public_names():
    import sptpt

    offenders = [f"{path.relative_to(ROOT)}:{line} imports {module}" for path in SOURCES
                 if module_name(path).startswith("annotator") for line, module, _ in imports_of(path)
                 if module.split(".")[0] == "sptpt" and module not in SPTPT_PUBLIC]
    assert not offenders
    named = {name for path in SOURCES if module_name(path).startswith("annotator")
             for _, module, name in imports_of(path) if module == "sptpt" and name is not None}
    assert named <= set(sptpt.__all__), named - set(sptpt.__all__)
    for name in sptpt.__all__:  # each public name resolves
        assert getattr(sptpt, name) is not None


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
    """``(name, first line, lines)`` of each function or method in ``source`` longer than ``limit`` lines of code:
    from its def to its last line, its docstring left out (a public function's numpydoc sections are not code)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            lines = node.end_lineno - node.lineno + 1
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
                    and isinstance(first.value.value, str):
                lines -= first.end_lineno - first.lineno + 1
            if lines > limit:
                found.append((node.name, node.lineno, lines))
    return found


def function_text(name: str, lines: int, indent: str = "", docstring: int = 0) -> str:
    """A function of exactly ``lines`` lines of code, def line included, after a docstring of ``docstring`` lines."""
    doc = f'{indent}    """' + "\n".join(["d"] * docstring) + '"""\n' if docstring else ""
    return f"{indent}def {name}():\n" + doc + "".join(f"{indent}    x = {k}\n" for k in range(lines - 1))


@pytest.mark.parametrize("source, expected", [
    (function_text("fits", 80), []),
    (function_text("over", 81), [("over", 1, 81)]),
    ("class C:\n" + function_text("method", 81, indent="    "), [("method", 2, 81)]),
    ("x = 1\n\n" + function_text("later", 90), [("later", 3, 90)]),
    (function_text("documented", 80, docstring=40), []),
    (function_text("long_anyway", 81, docstring=40), [("long_anyway", 1, 81)]),
])
def test_long_functions_counts_from_def_to_the_last_line_of_the_body_without_the_docstring(source, expected):
    assert long_functions(source) == expected


def test_no_function_in_the_tool_is_over_80_lines():
    offenders = [f"{path.relative_to(ROOT)}:{line} {name} has {lines} lines"
                 for path in sorted(ROOT.glob("annotator/**/*.py"))
                 for name, line, lines in long_functions(path.read_text(encoding="utf-8"))]
    assert not offenders


#: The tool's layers, from the bottom up: a module may import its own layer and those below, never one above
#: (typing-only and function-level imports included). An entry names a module and every module inside it;
#: ``annotator`` itself is the package's public face, at the top.
LAYERS: list[tuple[str, list[str]]] = [
    ("foundations", ["annotator.version", "annotator.output_files", "annotator.errors", "annotator.atomic",
                     "annotator.wording", "annotator.text_input", "annotator.allocator", "annotator.provenance",
                     "annotator.html_pages", "annotator.box_input", "annotator.output_folder"]),
    ("what a run is made of", ["annotator.tracks", "annotator.track_store", "annotator.checkpoint",
                               "annotator.frame_sources", "annotator.progress", "annotator.render",
                               "annotator.otb_format", "annotator.corrections", "annotator.nanotrack",
                               "annotator.kmeans_child"]),
    ("doubt and settings", ["annotator.flagging", "annotator.failure", "annotator.config"]),
    # Fitting the failure model scores its folds as evaluation does: above it, though inside annotator.failure.
    ("views of a store", ["annotator.exports", "annotator.evaluation", "annotator.run_report",
                          "annotator.failure.fit"]),
    ("the tracking engine", ["annotator.pass_cache", "annotator.pipeline"]),
    ("a run and its review", ["annotator.publish", "annotator.run", "annotator.review"]),
    ("batches", ["annotator.manifest", "annotator.batch"]),
    ("the public face and the commands", ["annotator", "annotator.commands", "annotator.cli"]),
]
TOOL_MODULES = {module_name(path): path for path in SOURCES if module_name(path).split(".")[0] == "annotator"}


def layer_of(module: str) -> int:
    """The index in LAYERS of the entry that names ``module`` or its closest package."""
    best = None
    for index, (_, entries) in enumerate(LAYERS):
        for entry in entries:
            if (module == entry or (entry != "annotator" and module.startswith(entry + "."))) \
                    and (best is None or len(entry) > len(best[1])):
                best = (index, entry)
    assert best is not None, f"{module} is in no layer of tests/test_layers.py: add it where it belongs"
    return best[0]


def tool_imports(importer: str, path: Path) -> set[str]:
    """The tool's modules ``importer`` makes Python import: each named module, and the packages on the way to it
    (its own packages and the root aside: Python imports those before ``importer`` itself)."""
    found = set()
    for _, module, name in imports_of(path):
        if module.split(".")[0] != "annotator":
            continue
        target = f"{module}.{name}" if name is not None and f"{module}.{name}" in TOOL_MODULES else module
        parts = target.split(".")
        for depth in range(2, len(parts) + 1):
            package = ".".join(parts[:depth])
            if package in TOOL_MODULES and package != importer and not importer.startswith(package + "."):
                found.add(package)
    return found


def import_graph() -> dict[str, set[str]]:
    return {module: tool_imports(module, path) for module, path in TOOL_MODULES.items()}


def test_every_module_of_the_tool_has_a_layer():
    for module in TOOL_MODULES:
        layer_of(module)


def test_no_import_in_the_tool_points_up_a_layer():
    offenders = [f"{importer} ({LAYERS[layer_of(importer)][0]}) imports {module} ({LAYERS[layer_of(module)][0]})"
                 for importer, modules in import_graph().items() for module in sorted(modules)
                 if layer_of(module) > layer_of(importer)]
    assert not offenders


def import_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as ``[a, b, ..., a]``, or None: depth-first, in the modules' order."""
    state: dict[str, int] = {}  # 1 on the current path, 2 done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


@pytest.mark.parametrize("graph, expected", [
    ({"a": {"b"}, "b": {"c"}, "c": set()}, None),
    ({"a": {"b"}, "b": {"a"}}, ["a", "b", "a"]),
    ({"a": {"b"}, "b": {"c"}, "c": {"b"}}, ["b", "c", "b"]),
])
def test_import_cycle_finds_a_cycle_and_only_one(graph, expected):
    assert import_cycle(graph) == expected


def test_the_tools_import_graph_has_no_cycle_within_a_layer_either():
    assert import_cycle(import_graph()) is None


@pytest.mark.parametrize("importer, source, expected", [
    ("annotator.run_report", "from annotator.pipeline import Target\n", {"annotator.pipeline"}),
    ("annotator.run_report", "if TYPE_CHECKING:\n    from annotator.batch.workers import ItemOutcome\n",
     {"annotator.batch", "annotator.batch.workers"}),
    ("annotator.run_report", "def f():\n    import annotator.review.merge\n",
     {"annotator.review", "annotator.review.merge"}),
    ("annotator.review.merge", "from annotator.review.segments import x\n", {"annotator.review.segments"}),
    ("annotator.run", "from annotator.exports import views\n", {"annotator.exports", "annotator.exports.views"}),
])
def test_tool_imports_counts_typing_function_level_and_package_imports(importer, source, expected, tmp_path):
    path = tmp_path / "m.py"
    path.write_text(source, encoding="utf-8")
    assert tool_imports(importer, path) == expected
