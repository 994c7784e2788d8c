"""Keep ``benchmarks/RESULTS.md`` as named sections that each benchmark replaces on its own."""

from __future__ import annotations

import re
from pathlib import Path

from annotator.atomic import write_text_atomic

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"
HEADER = (
    "# Benchmark results\n\n"
    "Every figure below was measured by the command printed with it, on the machine it names.\n"
    "Sections are rewritten by the benchmark that owns them; misses against targets are stated.\n"
)


def update_section(name: str, markdown: str, path: Path = RESULTS) -> None:
    """Replace (or append) the section delimited by ``<!-- BEGIN name -->`` / ``<!-- END name -->``."""
    text = path.read_text() if path.exists() else HEADER
    block = f"<!-- BEGIN {name} -->\n{markdown.rstrip()}\n<!-- END {name} -->"
    pattern = re.compile(rf"<!-- BEGIN {re.escape(name)} -->.*?<!-- END {re.escape(name)} -->", re.S)
    text = pattern.sub(lambda _: block, text) if pattern.search(text) else text.rstrip() + "\n\n" + block + "\n"
    write_text_atomic(path, text)


def machine_line() -> str:
    import os
    import platform

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = ""
    try:
        kib = int(Path("/proc/meminfo").read_text().split()[1])
        mem = f", {kib / 2**20:.0f} GiB RAM"
    except (OSError, ValueError, IndexError):
        pass
    return f"{os.cpu_count()} cores ({cpu}){mem}, Python {platform.python_version()}"
