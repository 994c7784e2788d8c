"""sptpt-annotate: the headless annotation tool built on the ``sptpt`` tracker."""

__version__ = "0.2.0"
