"""The ``autoresearch`` command. Each subcommand lives in ``autoresearch/commands/<module>.py`` and
exposes ``add_parser(subparsers) -> ArgumentParser`` and ``run(args) -> int``; adding one is adding
it to :data:`autoresearch.commands.MODULES` and its summary to ``SUMMARIES``.

Only the command being run is imported: ``autoresearch --help`` lists the others from their
summaries, so it starts without numpy, scipy or matplotlib.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from autoresearch import __version__
from autoresearch.commands import MODULES, SUMMARIES
from autoresearch.extras import MissingExtra


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser with ``command``'s full arguments (every command's, when None); the other
    commands are listed by name and summary only."""
    parser = argparse.ArgumentParser(
        prog="autoresearch", description="An auditable research agent that drives a family directory."
    )
    parser.add_argument("--version", action="version", version=f"autoresearch {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module_name in MODULES.items():
        if command is None or name == command:
            module = importlib.import_module(f"autoresearch.commands.{module_name}")
            module.add_parser(subparsers).set_defaults(_run=module.run)
        else:
            subparsers.add_parser(name, help=SUMMARIES[name])
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    # Top-level options take no value, so the first word that is not an option names the command
    # (none, or one that does not exist: argparse's own message, with nothing imported).
    command = next((word for word in argv if not word.startswith("-")), "")
    args = build_parser(command).parse_args(argv)
    try:
        return args._run(args)
    except MissingExtra as err:
        print(f"autoresearch {args.command}: {err}", file=sys.stderr)
        return 2
