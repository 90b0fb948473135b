"""One module per ``phireman`` subcommand; each exposes ``add_arguments(parser)`` and ``run(args) -> int``."""
