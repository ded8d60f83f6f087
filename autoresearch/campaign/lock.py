"""One process at a time writes a campaign.

Every command that writes a campaign directory (loop, audit, noise, verify, prune, random) holds
an exclusive ``flock`` on ``<campaign>/campaign.lock`` for its whole life. The kernel drops the
lock when the holder exits, however it dies (kill -9 included), so a lock file left behind never
blocks anyone; its content (the holder's pid and command) only serves to name the holder in the
refusal a second process gets. POSIX only, like the process-group handling in runner.py.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

from autoresearch.campaign.paths import CampaignError

LOCK_FILE = "campaign.lock"


class CampaignBusy(CampaignError):
    """Another live process holds the campaign's lock."""


def not_a_directory(root: Path) -> str | None:
    """Why ``root`` cannot be a campaign directory (a file, or nothing there), or None."""
    if root.is_dir():
        return None
    what = "is not a directory" if root.exists() else "does not exist"
    return f"{root} {what}; expected a campaign directory"


def _holder_text(fd: int) -> str:
    os.lseek(fd, 0, os.SEEK_SET)
    text = os.read(fd, 200).decode("utf-8", "replace").strip()
    return text or "another process"


class CampaignLock:
    """``with CampaignLock(root, "verify"):`` holds ``root``'s lock or raises :class:`CampaignBusy`;
    ``create=True`` makes the directory first (a new campaign)."""

    def __init__(self, root: str | os.PathLike[str], command: str, create: bool = False):
        self.root = Path(root)
        self.command = command
        self.create = create
        self._fd: int | None = None

    def acquire(self) -> CampaignLock:
        if self.create and not self.root.exists():
            try:
                self.root.mkdir(parents=True, exist_ok=True)
            except OSError as err:
                raise CampaignError(f"{self.root}: cannot create the directory ({err.strerror})") from None
        problem = not_a_directory(self.root)
        if problem:
            raise CampaignError(problem)
        path = self.root / LOCK_FILE
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            raise CampaignError(f"{path}: cannot open the campaign's lock ({err.strerror})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder_text(fd)
            os.close(fd)
            raise CampaignBusy(
                f"{self.root} is in use by {holder}; one process at a time writes a campaign: "
                "wait for it to end or stop it"
            ) from None
        os.ftruncate(fd, 0)
        os.write(fd, f"pid {os.getpid()} (autoresearch {self.command})\n".encode())
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the flock; the file stays, harmless
            self._fd = None

    def __enter__(self) -> CampaignLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def holder(root: str | os.PathLike[str]) -> str | None:
    """Who holds ``root``'s lock right now ("pid N (autoresearch CMD)"), or None when nobody does."""
    path = Path(root) / LOCK_FILE
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return _holder_text(fd)
    finally:
        os.close(fd)
    return None
