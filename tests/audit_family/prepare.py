"""Audit test family preparation: nothing to cache, nothing to check."""

import argparse
import sys

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--warm-cache", action="store_true")
    group.add_argument("--check", action="store_true")
    parser.parse_args()
    sys.exit(0)
