"""The one Jinja2 environment of the tool's HTML pages: a run's ``report.html`` and a batch's index.

Built once per process and shared: HTML autoescaped, an undefined name an error, the ``plural`` filter of
:mod:`annotator.wording`.
"""

from __future__ import annotations

import functools
from pathlib import Path

import jinja2

from annotator.wording import plural

__all__ = ["BATCH_TEMPLATE", "REPORT_TEMPLATE", "template_environment", "templates_dir"]

#: A run's review report.
REPORT_TEMPLATE = "report.html.j2"
#: A batch's index page.
BATCH_TEMPLATE = "batch_report.html.j2"


def templates_dir() -> Path:
    """The folder holding the Jinja2 templates.

    An installed package carries them as ``annotator/templates`` (pyproject.toml maps the source tree's top-level
    ``templates/`` there); a source checkout or an editable install reads ``templates/`` beside the package.
    """
    package = Path(__file__).resolve().parent
    candidates = [package / "templates", package.parent / "templates"]
    for candidate in candidates:
        if (candidate / REPORT_TEMPLATE).is_file():
            return candidate
    raise FileNotFoundError(f"report template {REPORT_TEMPLATE} not found in {' or '.join(map(str, candidates))}; "
                            "reinstall sptpt-annotate")


@functools.cache
def template_environment() -> jinja2.Environment:
    """The one Jinja2 environment of every HTML page (built on first use, then shared)."""
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(templates_dir())),
        autoescape=jinja2.select_autoescape(["html", "j2"]),
        undefined=jinja2.StrictUndefined,
    )
    env.filters["plural"] = plural
    return env
