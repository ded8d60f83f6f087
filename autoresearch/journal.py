"""Durable append-only JSONL logs and atomic JSON files.

A record is appended as one whole line by a single ``os.write`` on an ``O_APPEND`` descriptor,
under a lock file shared with every other writer (``<file>.lock``, the same lock a family's
train.py takes on ``--runs-log``), then fsync'ed. A crash can therefore leave at most a torn
last line without its newline; :func:`repair_torn_tail` moves such a fragment to ``<file>.torn``
before anything else is appended, so it is never glued to the next record: a writer repairs, a
reader never does. Readers skip an unterminated last line (it is either torn or still being
written), so reading a log changes nothing and needs no write access, not even for a lock file.

Non-finite floats are written as Python's json writes them (``NaN``, ``Infinity``), which
:func:`read_jsonl` reads back.
"""

from __future__ import annotations

import json
import os
import stat
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from filelock import FileLock, Timeout

LOCK_TIMEOUT_S = 120.0


class JournalError(RuntimeError):
    """A log cannot be read or written."""


def lock_for(path: str | os.PathLike[str]) -> FileLock:
    """The inter-process lock guarding appends to ``path``."""
    return FileLock(f"{os.fspath(path)}.lock", timeout=LOCK_TIMEOUT_S)


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def _naming(path: Path) -> Iterator[None]:
    """An OSError of a write on a descriptor (a full disk) names no file: name ``path``."""
    try:
        yield
    except OSError as err:
        if err.filename is None:
            err.filename = str(path)
        raise


def locked(path: Path):
    """``path``'s lock, taken (a context manager); JournalError when another writer holds it too long."""
    try:
        return lock_for(path).acquire()
    except Timeout:
        raise JournalError(f"{path}: could not take {path}.lock within {LOCK_TIMEOUT_S:.0f} s") from None


def _torn_start(path: Path) -> int | None:
    """Offset of an unterminated last line, or None when the file ends with a newline."""
    size = path.stat().st_size
    if size == 0:
        return None
    with open(path, "rb") as f:
        pos, chunk = size, 4096
        while pos > 0:
            step = min(chunk, pos)
            f.seek(pos - step)
            block = f.read(step)
            if pos == size and block.endswith(b"\n"):
                return None
            newline = block.rfind(b"\n")
            if newline >= 0:
                return pos - step + newline + 1
            pos -= step
    return 0


def repair_torn_tail(path: str | os.PathLike[str]) -> bool:
    """Move an unterminated last line of ``path`` to ``<path>.torn``; True when one was found."""
    path = Path(path)
    if not path.exists():
        return False
    with locked(path):
        start = _torn_start(path)
        if start is None:
            return False
        with open(path, "rb+") as f:
            f.seek(start)
            keep_torn(path, f.read())
            f.truncate(start)
            f.flush()
            os.fsync(f.fileno())
    return True


def keep_torn(path: str | os.PathLike[str], fragment: bytes) -> None:
    """Append ``fragment``, a line that lost its newline, to ``<path>.torn``, durably."""
    fd = os.open(f"{os.fspath(path)}.torn", os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, fragment + b"\n")
        os.fsync(fd)
    finally:
        os.close(fd)


def encode_line(record: Any) -> bytes:
    # json.dumps escapes newlines inside strings, so a record is always exactly one line.
    return (json.dumps(record, separators=(",", ":")) + "\n").encode("utf-8")


def append_jsonl(path: str | os.PathLike[str], record: Any) -> None:
    """Append ``record`` as one line, durably, under the file's lock."""
    append_line(path, encode_line(record))


def append_line(path: str | os.PathLike[str], data: bytes) -> None:
    """Append one whole line (as another writer wrote it), durably, under the file's lock."""
    if not data.endswith(b"\n") or b"\n" in data[:-1]:
        raise ValueError(f"{path}: an appended record must be exactly one line")
    path = Path(path)
    with locked(path), _naming(path):
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            written = os.write(fd, data)
            while written < len(data):  # regular files never write short in practice; be exact anyway
                written += os.write(fd, data[written:])
            os.fsync(fd)
        finally:
            os.close(fd)


def read_jsonl(path: str | os.PathLike[str]) -> list[Any]:
    """Every complete line of ``path`` parsed as JSON ([] when the file does not exist)."""
    path = Path(path)
    if not path.exists():
        return []
    lines = path.read_bytes().split(b"\n")
    records = []
    for lineno, line in enumerate(lines[:-1], start=1):  # the last piece is unterminated or empty
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except ValueError as err:
            raise JournalError(f"{path}:{lineno}: not a JSON line ({err})") from None
        except RecursionError:
            raise JournalError(f"{path}:{lineno}: not a JSON line (nested too deeply)") from None
    return records


class Journal:
    """An append-only JSONL file. Opening it changes nothing (a reader skips a torn last line); a
    writer calls :meth:`repair` before its first append."""

    def __init__(self, path: str | os.PathLike[str]):
        self.path = Path(path)

    def repair(self) -> bool:
        """Move a torn last line left by a crash to ``<file>.torn``; True when one was found."""
        return repair_torn_tail(self.path)

    def append(self, record: Any) -> None:
        append_jsonl(self.path, record)

    def read(self) -> list[Any]:
        return read_jsonl(self.path)


def _temp_beside(path: Path) -> tuple[int, str]:
    """A new temporary file next to ``path``, with the mode ``path`` has, or the mode a plain open()
    gives a new file (0666 less the umask): mkstemp's 0600 would turn a shared 0644 file private."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        try:
            mode = stat.S_IMODE(os.stat(path).st_mode)
        except FileNotFoundError:
            mode = 0o666 & ~_umask()
        os.fchmod(fd, mode)
    except BaseException:
        os.close(fd)
        Path(tmp).unlink(missing_ok=True)
        raise
    return fd, tmp


def _umask() -> int:
    """The process's umask, read without changing it where Linux shows it (os.umask sets it, racing
    other threads that create files meanwhile)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_json_atomic(path: str | os.PathLike[str], obj: Any) -> None:
    """Write ``obj`` as JSON so that ``path`` holds either the old or the new content, never a mix.
    The file keeps its mode."""
    path = Path(path)
    fd, tmp = _temp_beside(path)
    try:
        with _naming(path), os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(obj, f, indent=2)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def read_json(path: str | os.PathLike[str]) -> Any:
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except ValueError as err:
        raise JournalError(f"{path}: not valid JSON ({err})") from None
    except RecursionError:
        raise JournalError(f"{path}: not valid JSON (nested too deeply)") from None


def update_json(path: str | os.PathLike[str], change: Callable[[dict[str, Any]], None]) -> dict[str, Any]:
    """Read-modify-write the JSON object in ``path`` ({} when absent) under its lock, replacing it
    atomically: two writers never lose each other's changes. Returns the object as written."""
    path = Path(path)
    with locked(path):
        data = read_json(path) if path.exists() else {}
        if not isinstance(data, dict):
            raise JournalError(f"{path}: must hold a JSON object")
        change(data)
        write_json_atomic(path, data)
    return data
