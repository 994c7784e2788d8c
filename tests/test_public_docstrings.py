"""The public API's docstrings follow numpydoc, checked by numpydoc's own validator, and their examples run.

The public API is what ``annotator.__all__`` and ``sptpt.__all__`` name. Every function there documents each
parameter (with a type and a description) and what it returns; every class documents its constructor's
parameters, or, for a dataclass, each field (in a Parameters or Attributes section, or by a docstring or ``#:``
comment at the field). The entry points a user starts from carry an Examples section, run here as doctests.
"""

from __future__ import annotations

import ast
import dataclasses
import doctest
import inspect
import os
import textwrap
from pathlib import Path

import pytest

numpydoc_validate = pytest.importorskip("numpydoc.validate")
from numpydoc.docscrape import NumpyDocString  # noqa: E402

import annotator  # noqa: E402
import sptpt  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: numpydoc's checks the public API keeps: a docstring, every parameter documented with a type and a description,
#: none unknown or out of order, a Returns section with a description, known sections in the right order.
CHECKS = {"GL08", "GL06", "GL07", "PR01", "PR02", "PR03", "PR04", "PR06", "PR07", "PR10", "RT01", "RT03", "YD01"}
#: Where a user starts: each has an Examples section that runs.
WITH_EXAMPLES = ["annotator.annotate", "annotator.apply_corrections", "annotator.read_store",
                 "annotator.resolve_config", "annotator.open_frames", "annotator.evaluate_result_file",
                 "sptpt.Tracker", "sptpt.preset", "sptpt.check_params"]


def public_objects() -> list[tuple[str, object]]:
    found = []
    for package in (annotator, sptpt):
        for name in package.__all__:
            obj = getattr(package, name)
            if inspect.isfunction(obj) or inspect.isclass(obj):
                found.append((f"{package.__name__}.{name}", obj))
    return found


def documented_fields(cls: type) -> set[str]:
    """The fields of ``cls`` with a docstring (a string right after it), a ``#:`` comment above it or a comment at
    the end of its line."""
    source = textwrap.dedent(inspect.getsource(cls))
    lines = source.splitlines()
    body = ast.parse(source).body[0].body  # type: ignore[attr-defined]
    found = set()
    for k, node in enumerate(body):
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            continue
        follows = body[k + 1] if k + 1 < len(body) else None
        if isinstance(follows, ast.Expr) and isinstance(follows.value, ast.Constant) \
                and isinstance(follows.value.value, str):
            found.add(node.target.id)
        elif node.lineno >= 2 and lines[node.lineno - 2].strip().startswith("#:"):
            found.add(node.target.id)
        elif "#" in lines[node.lineno - 1]:  # a comment at the end of the field's line, not a tool's
            comment = lines[node.lineno - 1].split("#", 1)[1].strip()
            if not comment.startswith(("type:", "noqa")):
                found.add(node.target.id)
    return found


def constructor_parameters(cls: type) -> list[str]:
    """What a caller passes to build ``cls``: a dataclass's fields, else ``__init__``'s named parameters."""
    if getattr(cls, "_is_protocol", False):
        return []  # a Protocol is implemented, not built
    if dataclasses.is_dataclass(cls):
        return [f.name for f in dataclasses.fields(cls) if not f.name.startswith("_")]
    named = inspect.signature(cls.__init__).parameters.values()  # type: ignore[misc]
    return [p.name for p in named if p.name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]


def problems_of(name: str, obj) -> list[str]:
    result = numpydoc_validate.validate(f"{obj.__module__}.{obj.__qualname__}")
    errors = [(code, message) for code, message in result["errors"] if code in CHECKS]
    if inspect.isclass(obj):
        # A class's parameters may be documented as Parameters or as Attributes (what a dataclass's fields are),
        # or at a dataclass's field; numpydoc reads only the first.
        doc = NumpyDocString(inspect.getdoc(obj) or "")
        documented = {part.strip() for section in ("Parameters", "Attributes") for entry in doc[section]
                      for part in entry.name.split(",")}
        for klass in obj.__mro__:
            if dataclasses.is_dataclass(klass) and klass.__module__.split(".")[0] in ("annotator", "sptpt"):
                documented |= documented_fields(klass)
        errors = [(code, message) for code, message in errors if code not in ("PR01", "PR02", "PR03")]
        missing = [p for p in constructor_parameters(obj) if p not in documented]
        if missing:
            errors.append(("PR01", f"parameters {missing} not documented"))
    return [f"{name}: {code} {message}" for code, message in errors]


@pytest.mark.parametrize("name, obj", public_objects(), ids=lambda value: value if isinstance(value, str) else "")
def test_every_public_name_follows_numpydoc(name, obj):
    assert not problems_of(name, obj)


@pytest.mark.parametrize("name", WITH_EXAMPLES)
def test_the_entry_points_have_examples_that_run(name, tmp_path, monkeypatch):
    package, attribute = name.split(".")
    obj = getattr(annotator if package == "annotator" else sptpt, attribute)
    tests = doctest.DocTestFinder(recurse=False).find(obj, name, globs={})
    assert tests and tests[0].examples, f"{name} has no Examples section"
    # The examples read the project's sample from the repository's folder and write where they run.
    samples = tmp_path / "samples"
    samples.symlink_to(ROOT / "samples", target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in tests:
        runner.run(test)
    summary = runner.summarize(verbose=False)
    assert summary.failed == 0, f"{name}: {summary.failed} of {summary.attempted} examples failed"
    assert os.getcwd() == str(tmp_path)
