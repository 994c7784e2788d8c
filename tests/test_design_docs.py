"""The design documents the code cites live in the repository, in ``docs/design/``, and every citation reaches them.

No file of the project points at a document kept outside the repository (the development setup's algorithm
specification or house-style notes, by name or by their section numbers). Every document of ``docs/design/`` the
code names exists, and so does every heading it cites after the name (``docs/design/tracker.md``, "SNIC
superpixels"), as does every heading a Markdown link into ``docs/design/`` points at.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "docs" / "design"

#: What is scanned: the repository's own text files (folders and top-level files).
SCANNED_FOLDERS = ("sptpt", "sptpt_dev", "annotator", "templates", "tests", "docs", "benchmarks")
SCANNED_FILES = ("README.md", "pyproject.toml")
TEXT_SUFFIXES = {".py", ".md", ".j2", ".sh", ".toml", ".yaml", ".yml", ".txt", ".cfg"}
#: Generated folders that git ignores (environments, runs, caches): not the project's text.
SKIPPED_FOLDERS = {"__pycache__", "_env", "_runs", "_reader_env", "_labelstudio_env"}

#: Citations of documents outside the repository. The names are split so that this file does not cite them.
OUTSIDE = [
    re.compile(re.escape("SPTPT" + "_SPEC"), re.I),
    re.compile(re.escape("STYLE" + ".md")),
    # The specification's section numbers without its name (the word, then a number, an A-number or "section"
    # and a number), and its list of acceptance checks.
    re.compile(r"\bspec(?:'s)?\s+(?:section\s+)?A?\d", re.I),
    re.compile(r"\bappendix\s+check", re.I),
]

#: A document of ``docs/design/`` by its path, then (after its closing backticks) the quoted headings it cites, if any:
#: ``, "A"``, ``, "A" and "B"``, ``, "A", "B" and "C"``.
CITATION = re.compile(r'docs/design/(?P<name>[\w.-]+?\.md)`*(?P<headings>(?:(?:,\s*|,?\s+and\s+)"[^"]+")*)')
QUOTED = re.compile(r'"([^"]+)"')
MARKDOWN_LINK = re.compile(r"\]\((?P<target>[^)\s#]*\.md)(?:#(?P<anchor>[^)\s]+))?\)")


def scanned_files() -> list[Path]:
    files = [ROOT / name for name in SCANNED_FILES]
    for folder in SCANNED_FOLDERS:
        for here, folders, names in os.walk(ROOT / folder):
            folders[:] = sorted(f for f in folders if f not in SKIPPED_FOLDERS and not f.startswith("."))
            files += [Path(here) / name for name in sorted(names) if Path(name).suffix in TEXT_SUFFIXES]
    return files


def outside_citations(text: str) -> list[str]:
    """The citations of documents outside the repository in ``text``."""
    return [match.group(0) for pattern in OUTSIDE for match in pattern.finditer(text)]


def flattened(text: str) -> str:
    """``text`` on one line: comment markers at the start of continued lines dropped and whitespace runs made one
    space, so that a citation wrapped over lines of a docstring or a comment reads as one."""
    return re.sub(r"\s+", " ", re.sub(r"\n[ \t]*#:?", "\n", text))


def cited(text: str) -> list[tuple[str, list[str]]]:
    """``(file name, [headings])`` of each ``docs/design/`` citation in ``text``."""
    return [(match["name"], QUOTED.findall(match["headings"])) for match in CITATION.finditer(flattened(text))]


def headings(path: Path) -> list[str]:
    """The Markdown headings of ``path`` (outside fenced code)."""
    found, fenced = [], False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and (match := re.match(r"#{1,6}\s+(.+?)\s*#*$", line)):
            found.append(match.group(1))
    return found


def anchor(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


@pytest.mark.parametrize("text, expected", [
    ("see " + "SPTPT" + "_SPEC.md 2.3", 1),
    ("(" + "STYLE" + '.md, "A public face")', 1),
    ("(spec " "A1)", 1),  # split, here and below, so that this file does not cite them
    ("(spec section " "5)", 1),
    ("the spec's " "2.4 says", 1),
    ("Appendix " "check 5.", 1),
    ('(``docs/design/tracker.md``, "SNIC superpixels")', 0),
    ("spec = importlib.util.spec_from_file_location(name, path)", 0),
    ("the paper's specification", 0),
])
def test_outside_citations_are_recognised(text, expected):
    assert len(outside_citations(text)) == expected


@pytest.mark.parametrize("text, expected", [
    ('(``docs/design/tracker.md``, "SNIC superpixels")', [("tracker.md", ["SNIC superpixels"])]),
    ('See ``docs/design/tracker.md``, "Dictionary" and\n    "Non-negative sparse codes".',
     [("tracker.md", ["Dictionary", "Non-negative sparse codes"])]),
    ('``docs/design/tracker.md``, "Dictionary", "Tensor pooling" and "Update schedule"',
     [("tracker.md", ["Dictionary", "Tensor pooling", "Update schedule"])]),
    ('# see docs/design/tracker.md,\n# "Update schedule"', [("tracker.md", ["Update schedule"])]),
    ("resolved in ``docs/design/tracker.md``), or", [("tracker.md", [])]),
    ('docs/design/code.md, to reproduce "the paper"', [("code.md", [])]),
])
def test_citations_are_read_with_their_headings(text, expected):
    assert cited(text) == expected


@pytest.mark.parametrize("heading, expected", [
    ("SNIC superpixels", "snic-superpixels"),
    ("Non-negative sparse codes", "non-negative-sparse-codes"),
    ("A public face", "a-public-face"),
])
def test_anchors_are_githubs(heading, expected):
    assert anchor(heading) == expected


def test_the_scan_covers_the_code_the_tests_and_the_docs():
    scanned = {path.relative_to(ROOT).as_posix() for path in scanned_files()}
    for expected in ("sptpt/params.py", "sptpt/_kernels/snic.py", "annotator/evaluation/metrics.py",
                     "tests/test_layers.py", "docs/presets.md", "docs/design/tracker.md", "README.md"):
        assert expected in scanned


def test_no_file_cites_a_document_outside_the_repository():
    offenders = [f"{path.relative_to(ROOT)}: {citation!r}" for path in scanned_files()
                 for citation in outside_citations(path.read_text(encoding="utf-8", errors="replace"))]
    assert not offenders


def test_every_design_citation_names_an_existing_file_and_heading():
    offenders, count = [], 0
    for path in scanned_files():
        for name, cited_headings in cited(path.read_text(encoding="utf-8", errors="replace")):
            count += 1
            where = f"{path.relative_to(ROOT)} cites docs/design/{name}"
            if not (DESIGN / name).is_file():
                offenders.append(f"{where}, which does not exist")
                continue
            offenders += [f'{where}, "{heading}": no such heading' for heading in cited_headings
                          if heading not in headings(DESIGN / name)]
    assert not offenders
    assert count >= 20  # the code does cite the design documents


def test_every_markdown_link_into_the_design_documents_reaches_a_file_and_heading():
    offenders = []
    for path in scanned_files():
        if path.suffix != ".md":
            continue
        for match in MARKDOWN_LINK.finditer(path.read_text(encoding="utf-8")):
            target = (path.parent / match["target"]).resolve()
            if DESIGN not in target.parents:
                continue
            where = f"{path.relative_to(ROOT)} links {match.group(0)}"
            if not target.is_file():
                offenders.append(f"{where}: no such file")
            elif match["anchor"] and match["anchor"] not in {anchor(h) for h in headings(target)}:
                offenders.append(f"{where}: no such heading")
    assert not offenders


def test_each_design_heading_is_unique():
    """A heading is cited by its text, so two sections of one document must not share it."""
    for path in sorted(DESIGN.glob("*.md")):
        found = headings(path)
        assert len(found) == len(set(found)), path.name
