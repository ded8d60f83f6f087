"""Build (--warm-cache) or verify (--check) every data set this family's train.py can read.

    python prepare.py --warm-cache   # once, slow: expert solves for the whole pool
    python prepare.py --check        # seconds: exit 1 naming whatever is missing or inconsistent

The sets are read from train.py's constants (cwh_envs.prepare holds the logic, shared by families).
"""

import sys
from pathlib import Path

from cwh_envs.prepare import main

if __name__ == "__main__":
    sys.exit(main(Path(__file__).parent, __doc__))
