"""Replace a file atomically: a reader (or a crash) sees the old content or the new, never half of one.

:func:`write_atomic` writes the new content to a temporary file beside the target (same directory, so that
the rename cannot cross file systems; a unique name ``.<name>.<random>.tmp``), flushes and fsyncs it, and
renames it over the target with ``os.replace`` (atomic on POSIX). With ``durable=True`` the directory is
fsynced too, so that the rename itself survives a power cut — for files that must not be lost (a cell config,
the calibration session); a file rewritten every second (the status file) does without. On any failure — the
content cannot be encoded, the disk is full, ``before_replace`` refuses — the temporary file is removed and the
target is left as it was.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import stat
from collections.abc import Callable
from pathlib import Path

__all__ = ["write_atomic"]

NEW_FILE_MODE = 0o666  # what open() creates a file with, less the process's umask
_NAME_DRAWS = 100


def write_atomic(path: Path | str, content: str | bytes, *, mode: int | None = None, durable: bool = False,
                 encoding: str = "utf-8", before_replace: Callable[[Path], None] | None = None) -> Path:
    """Replace ``path`` with ``content`` (text is encoded with ``encoding``, newlines as given); return ``path``.

    ``mode``: the permission bits of the new file; default those of the file it replaces, or, for a new file,
    what ``open()`` would create (0o666 less the umask). ``before_replace(temporary)`` is called with the
    complete, synced temporary file before it replaces ``path`` (to load and check it); whatever it raises
    leaves ``path`` untouched. The directory must exist; OSError (and encoding errors) propagate."""
    path = Path(path)
    if mode is None:
        with contextlib.suppress(FileNotFoundError):
            mode = stat.S_IMODE(path.stat().st_mode)
    tmp, fd = _create_beside(path)
    try:
        with os.fdopen(fd, "wb") as out:
            if mode is not None:
                os.fchmod(out.fileno(), mode)
            out.write(content.encode(encoding) if isinstance(content, str) else content)
            out.flush()
            os.fsync(out.fileno())
        if before_replace is not None:
            before_replace(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if durable:
        _fsync_directory(path.parent)
    return path


# --- private -----------------------------------------------------------------------------------


def _create_beside(path: Path) -> tuple[Path, int]:
    """A new, empty temporary file in ``path``'s directory (created exclusively, mode 0o666 less the umask)."""
    for _ in range(_NAME_DRAWS):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
        try:
            return tmp, os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, NEW_FILE_MODE)
        except FileExistsError:  # 48 random bits taken: draw again
            continue
    raise FileExistsError(f"{path.parent}: no free temporary name for {path.name} in {_NAME_DRAWS} draws")


def _fsync_directory(directory: Path) -> None:
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
