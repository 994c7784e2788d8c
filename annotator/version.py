"""The tool's version, recorded in every file a run writes: a module of its own, below everything that records it,
so that no module imports the package's ``__init__`` (the public face, at the top of the layers)."""

__version__ = "0.2.0"
