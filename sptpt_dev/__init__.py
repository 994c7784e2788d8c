"""Development code that the tool itself never runs, kept out of the wheel.

* :mod:`sptpt_dev.synthetic`: synthetic clips with exact ground truth, for the tests, the benchmarks and
  ``samples/make_sample.py``.

Importable from a source checkout: the tests put the project root on ``sys.path`` (pyproject.toml,
``[tool.pytest.ini_options] pythonpath``), the benchmarks and the sample script do it themselves.
"""
