"""Where the service keeps its state (journal, images, status file): one rule for every command.

``--state-dir`` when given; else systemd's ``$STATE_DIRECTORY`` (set by ``StateDirectory=`` in the
unit; when the unit lists several, the first); else ``/var/lib/monoguide``. An empty ``--state-dir`` is a
usage error, never the current directory.

One service per state directory: :class:`ServiceLock` holds an exclusive ``flock`` on ``service.lock`` for the
service's whole life (the kernel drops it when the process ends, however it ends); a second service is refused
with :class:`StateDirInUse` naming the first one's PID. Readers (``status``, ``journal``) never take it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
from collections.abc import Mapping
from pathlib import Path

from monoguide.daemon.errors import StateDirInUse, StateDirInvalid, StateDirMissing

DEFAULT_STATE_DIR = Path("/var/lib/monoguide")
LOCK_FILE = "service.lock"
STATE_DIR_HELP = "The service's state directory (default: $STATE_DIRECTORY, else /var/lib/monoguide)."


def state_dir(given: Path | str | None = None, environ: Mapping[str, str] | None = None) -> Path:
    """The state directory: ``given``, else ``$STATE_DIRECTORY`` (its first entry), else the default. An empty
    ``given`` is :class:`StateDirInvalid` (``Path("")`` would be the current directory)."""
    if given is not None:
        if not str(given).strip():
            raise StateDirInvalid("--state-dir is empty: give the service's state directory (or leave the option "
                                  "out for $STATE_DIRECTORY, else /var/lib/monoguide)")
        return Path(given)
    environ = os.environ if environ is None else environ
    from_systemd = environ.get("STATE_DIRECTORY", "").split(":")[0]
    return Path(from_systemd) if from_systemd else DEFAULT_STATE_DIR


def existing_state_dir(given: Path | str | None = None) -> Path:
    """:func:`state_dir`, which must exist: else :class:`StateDirMissing` naming it and where it came from."""
    path = state_dir(given)
    if not path.is_dir():
        origin = "--state-dir" if given is not None else (
            "$STATE_DIRECTORY" if os.environ.get("STATE_DIRECTORY") else "the default")
        what = "is not a directory" if path.exists() else "does not exist"
        raise StateDirMissing(f"state directory {path} ({origin}) {what}: no service has run here;"
                              " give --state-dir the service's directory")
    return path


class ServiceLock:
    """The exclusive lock of one state directory, held from :meth:`acquire` until :meth:`release` or the end of
    the process. The file holds the holder's PID (for the message of the one refused)."""

    def __init__(self, directory: Path) -> None:
        self.path = Path(directory) / LOCK_FILE
        self._fd: int | None = None

    def acquire(self) -> None:
        """Take the lock or raise :class:`StateDirInUse` naming the PID that holds it."""
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o640)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = _read_pid(fd)
            os.close(fd)
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise
            raise StateDirInUse(f"state directory {self.path.parent} is in use by another monoguide service "
                                f"(PID {holder or 'unknown'}, lock {self.path}): one service per state directory; "
                                "stop that one or give --state-dir another directory") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, 0)
            os.close(self._fd)  # closing drops the flock
            self._fd = None

    def __enter__(self) -> ServiceLock:
        self.acquire()
        return self

    def __exit__(self, *_exc: object) -> None:
        self.release()


def _read_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode(errors="replace").strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None
