"""Exit statuses, and one policy for turning an error into a one-line message and one of them.

Every command follows it (docs/autoresearch-loop.md, docs/audit.md), and so does each repeat of a
group, a loop in a process of its own: 1 is kept for a failed prepare.py --check (loop) and a
campaign with problems (check), 130 for an interrupt.
"""

from __future__ import annotations

import errno
import sys

EXIT_ERROR = 2  # bad input, or a file that does not hold what it must
EXIT_NO_SPACE = 3  # the disk, a quota or a file-size limit refused a write; what was recorded stands
NO_SPACE = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def error_exit(name: str, err: BaseException, again: str = "run the same command again") -> int:
    """Say ``err`` in one line on stderr and return its exit status: EXIT_NO_SPACE when the disk
    refused a write, else EXIT_ERROR. ``again`` says how to go on once space is freed."""
    text = " ".join(str(err).split())
    if isinstance(err, OSError) and err.errno in NO_SPACE:
        print(
            f"autoresearch {name}: error: out of disk space ({text}); free some, then {again}",
            file=sys.stderr,
        )
        return EXIT_NO_SPACE
    print(f"autoresearch {name}: error: {text}", file=sys.stderr)
    return EXIT_ERROR
