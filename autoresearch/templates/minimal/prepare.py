"""Toy family preparation: --warm-cache has nothing to cache; --check verifies the environment."""

import argparse
import sys


def check() -> list[str]:
    problems = []
    try:
        import filelock  # noqa: F401
    except ImportError:
        problems.append("the filelock package is missing (pip install filelock)")
    return problems


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--warm-cache", action="store_true", help="build slow caches once (no-op here)")
    group.add_argument("--check", action="store_true", help="fast precondition check")
    args = parser.parse_args()
    if args.warm_cache:
        print("toy family: nothing to cache")
        return 0
    problems = check()
    for problem in problems:
        print(f"check failed: {problem}", file=sys.stderr)
    if not problems:
        print("toy family: ready")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
