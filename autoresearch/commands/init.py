"""``autoresearch init``: write a new family directory from a template."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from autoresearch.commands import SUMMARIES
from autoresearch.exits import EXIT_ERROR
from autoresearch.templates import TemplateError, write_family


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "init",
        help=SUMMARIES["init"],
        description="Write a working family (program.md, program_blind.md, train.py, family.json, "
        "prepare.py) into DIR, which must be absent or empty. The templates: minimal (a torch-free toy "
        "that runs in milliseconds; every parameter type), docking and rendezvous (the research families, "
        "which train with torch: the [families] extra), and any an installed package registers under "
        "the autoresearch.templates entry points. The new family has no seed noise and no best yet.",
        epilog="Example: autoresearch init my-family && autoresearch loop --family my-family --proposer random",
    )
    p.add_argument("dir", type=Path, help="the family directory to create")
    p.add_argument("--template", default="minimal", help="minimal (default), docking, rendezvous, ...")
    p.add_argument("--name", help="the family's name in family.json (default: the directory's name)")
    return p


def run(args: argparse.Namespace) -> int:
    try:
        registry = write_family(args.dir, args.template, args.name)
    except (TemplateError, OSError) as err:
        print(f"autoresearch init: error: {err}", file=sys.stderr)
        return EXIT_ERROR
    d = args.dir
    size = len(registry["search_space"])
    print(f"wrote family {registry['name']!r} ({args.template} template, {size} parameters) in {d}")
    print("next:")
    if args.template != "minimal":
        print(f"  (cd {d} && python prepare.py --warm-cache)   # builds its data sets once")
    print(f"  autoresearch check --family {d}")
    print(f"  autoresearch loop --family {d} --proposer random --max-runs 3")
    return 0
