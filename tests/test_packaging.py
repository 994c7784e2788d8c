"""The distribution matches the code: every package is shipped, and the required dependencies are what the tool
imports at run time (the optional ones behind an extra, with a one-line error when missing).

The wheel itself is built, installed without the source tree and run on the sample by ``.ci/wheel_smoke``.
"""

from __future__ import annotations

import ast
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
#: Import name -> distribution name, where they differ.
DISTRIBUTION = {"cv2": "opencv-python-headless", "sklearn": "scikit-learn", "yaml": "pyyaml", "PIL": "pillow",
                "imageio_ffmpeg": "imageio-ffmpeg", "distributed": "dask"}
#: Runtime modules that import an optional extra's package, and the extra.
OPTIONAL = {"distributed": "cluster", "matplotlib": "plots"}


def _requirement_name(requirement: str) -> str:
    for stop in "[<>=!~; ":
        requirement = requirement.split(stop)[0]
    return requirement.lower()


def _third_party_imports() -> set[str]:
    names: set[str] = set()
    for path in [*ROOT.glob("annotator/**/*.py"), *ROOT.glob("sptpt/**/*.py")]:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return {n for n in names if n not in sys.stdlib_module_names and n not in ("annotator", "sptpt")}


def test_required_dependencies_are_what_the_tool_imports():
    imported = {DISTRIBUTION.get(n, n).lower() for n in _third_party_imports() if n not in OPTIONAL}
    declared = {_requirement_name(r) for r in PYPROJECT["project"]["dependencies"]}
    assert imported - declared == set(), "imported at run time but not declared"
    assert declared - imported == set(), "declared but never imported at run time"


def test_optional_imports_are_behind_their_extras():
    extras = PYPROJECT["project"]["optional-dependencies"]
    for module, extra in OPTIONAL.items():
        assert module in _third_party_imports()
        assert {_requirement_name(r) for r in extras[extra]} == {DISTRIBUTION.get(module, module)}


def test_every_package_of_the_tree_is_shipped():
    listed = set(PYPROJECT["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for top in ("annotator", "sptpt")
             for p in (ROOT / top).rglob("__init__.py")}
    assert found | {"annotator.templates"} == listed
    assert PYPROJECT["tool"]["setuptools"]["package-dir"] == {"annotator.templates": "templates"}
    assert any((ROOT / "annotator" / "data").glob("*.json"))


@pytest.mark.parametrize("feature, extra", [("--scheduler", "cluster"), ("eval --out", "plots")])
def test_a_missing_extra_is_one_line_naming_the_pip_command(monkeypatch, feature, extra):
    import importlib.util

    from annotator.errors import EXIT_USAGE, ToolError, require_extra

    real = importlib.util.find_spec
    module = {"cluster": "distributed", "plots": "matplotlib"}[extra]
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == module else real(name, *a))
    with pytest.raises(ToolError) as caught:
        require_extra(feature)
    assert caught.value.exit_code == EXIT_USAGE
    assert f"pip install 'sptpt-annotate[{extra}]'" in str(caught.value) and "\n" not in str(caught.value)
