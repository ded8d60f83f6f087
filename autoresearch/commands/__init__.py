"""One module per ``autoresearch`` subcommand, each with ``add_parser(subparsers)`` and ``run(args) -> int``."""
