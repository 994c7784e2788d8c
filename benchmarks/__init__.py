"""Benchmarks of the tracker and the tool, run from the project root as ``python -m benchmarks.<name>``.

Each module's docstring gives its commands; ``benchmarks/RESULTS.md`` holds what they measured. Modules whose name
starts with an underscore are the benchmarks' shared helpers.
"""
