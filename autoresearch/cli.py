"""The ``autoresearch`` command. Each subcommand lives in ``autoresearch/commands/<name>.py`` and
exposes ``add_parser(subparsers) -> ArgumentParser`` and ``run(args) -> int``; adding one is
adding its module name to :data:`COMMANDS`."""

from __future__ import annotations

import argparse
import importlib

from autoresearch import __version__

COMMANDS = ("loop", "noise", "verify", "prune", "random_arm", "audit", "report", "compare", "check", "export")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="autoresearch", description="An auditable research agent that drives a family directory."
    )
    parser.add_argument("--version", action="version", version=f"autoresearch {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        module = importlib.import_module(f"autoresearch.commands.{name}")
        module.add_parser(subparsers).set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args._run(args)
