"""One module per subcommand; ``annotator.cli`` registers them. Nothing here is for import from outside."""

__all__: list[str] = []
