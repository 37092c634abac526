"""Where the service keeps its state (journal, images, status file): one rule for every command.

``--state-dir`` when given; else systemd's ``$STATE_DIRECTORY`` (set by ``StateDirectory=`` in the
unit; when the unit lists several, the first); else ``/var/lib/monoguide``. It must be a directory: an empty
``--state-dir`` (never the current directory), a file or anything else there that is not a directory, or one that
cannot be created is a usage error, :class:`StateDirInvalid` (exit 2), for every command that takes the option.

One service per state directory: :class:`ServiceLock` holds an exclusive ``flock`` on ``service.lock`` for the
service's whole life (the kernel drops it when the process ends, however it ends); a second service is refused
with :class:`StateDirInUse` naming the first one's PID. Readers (``status``, ``journal``) never take it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import stat
from collections.abc import Mapping
from pathlib import Path

from monoguide.daemon.errors import StateDirInUse, StateDirInvalid, StateDirMissing

DEFAULT_STATE_DIR = Path("/var/lib/monoguide")
LOCK_FILE = "service.lock"
HEALTH_FILE = "calibration-health.json"  # the calibration's health (the service writes it; `monoguide health` reads)
CLEAR_REQUEST = "calibration-health.clear"  # `monoguide health --clear REASON` leaves it; the service takes it
STATE_DIR_HELP = "The service's state directory (default: $STATE_DIRECTORY, else /var/lib/monoguide)."


def state_dir(given: Path | str | None = None, environ: Mapping[str, str] | None = None) -> Path:
    """The state directory: ``given``, else ``$STATE_DIRECTORY`` (its first entry), else the default. It need not
    exist yet; but something there that is not a directory (a file, a named pipe, ...), or a file where one of its
    parents should be, is :class:`StateDirInvalid` naming it and where it came from, as is an empty ``given``
    (``Path("")`` would be the current directory)."""
    environ = os.environ if environ is None else environ
    if given is not None:
        if not str(given).strip():
            raise StateDirInvalid("--state-dir is empty: give the service's state directory (or leave the option "
                                  "out for $STATE_DIRECTORY, else /var/lib/monoguide)")
        path = Path(given)
    else:
        from_systemd = environ.get("STATE_DIRECTORY", "").split(":")[0]
        path = Path(from_systemd) if from_systemd else DEFAULT_STATE_DIR
    if (problem := _not_a_directory(path)) is not None:
        raise StateDirInvalid(f"state directory {path} ({_origin(given, environ)}) {problem}: give --state-dir a "
                              "directory (one that does not exist yet is created by the service)")
    return path


def existing_state_dir(given: Path | str | None = None) -> Path:
    """:func:`state_dir`, which must exist: else :class:`StateDirMissing` naming it and where it came from."""
    path = state_dir(given)
    if not path.is_dir():
        raise StateDirMissing(f"state directory {path} ({_origin(given, os.environ)}) does not exist: no service has "
                              "run here; give --state-dir the service's directory")
    return path


def create_state_dir(directory: Path) -> None:
    """Create the state directory :func:`state_dir` gave (with its parents) when it does not exist, for the
    commands that write there (``run``, ``check``); one that cannot be created is :class:`StateDirInvalid` naming it
    and why."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StateDirInvalid(f"state directory {directory}: cannot create it: {exc.strerror or exc}") from None


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


def _not_a_directory(path: Path) -> str | None:
    """Why ``path`` cannot be a directory (something else is there, or a parent is not a directory), or None."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        return None  # not there yet: created by the service
    except NotADirectoryError:
        parent = next((p for p in path.parents if p.exists()), None)
        return f"is below {parent}, {_kind(parent)}" if parent is not None else "is below something not a directory"
    except OSError as exc:
        return f"cannot be looked at: {exc.strerror or exc}"
    return None if stat.S_ISDIR(mode) else f"is {_kind(path)}, not a directory"


def _kind(path: Path) -> str:
    try:
        mode = path.stat().st_mode
    except OSError:
        return "not a directory"
    kinds = ((stat.S_ISDIR, "a directory"), (stat.S_ISREG, "a regular file"), (stat.S_ISFIFO, "a named pipe (FIFO)"),
             (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))
    return next((name for test, name in kinds if test(mode)), "not a directory")


def _origin(given: Path | str | None, environ: Mapping[str, str]) -> str:
    if given is not None:
        return "--state-dir"
    return "$STATE_DIRECTORY" if environ.get("STATE_DIRECTORY", "").split(":")[0] else "the default"
