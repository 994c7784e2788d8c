"""One module per subcommand; ``annotator.cli`` registers them."""
