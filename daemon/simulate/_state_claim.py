"""One sim-cell per state file: the claim, an exclusive ``flock`` on ``<state file>.lock`` holding our pid.

The kernel releases the lock when the process ends, however it ends, so two sim-cells started together cannot
both run, and a state file left by a killed one is taken over. Only the owner ever writes or deletes the state
file and the files beside it (the tracker's targets, the robot's spec and truth): the claim names them
(:meth:`StateFileClaim.beside`) and deletes them on release, before its lock, while still holding it.
"""

from __future__ import annotations

import fcntl
import logging
import os
from pathlib import Path

from monoguide.daemon.simulate._owner import Owner
from monoguide.drivers.errors import ConfigError, DeviceBusy

log = logging.getLogger(__name__)

TAKE_ATTEMPTS = 5  # the lock file may be unlinked by its last owner between our open and our lock


class StateFileClaim(Owner):
    """This process's claim on a state file (an :class:`Owner`: released on the way out)."""

    def __init__(self, path: Path, lock_path: Path, fd: int) -> None:
        self.path = path
        self.lock_path = lock_path
        self._fd: int | None = fd
        self._files: list[Path] = []

    @classmethod
    def take(cls, path: Path) -> StateFileClaim:
        """Claim ``path`` atomically; :class:`DeviceBusy` naming it when a running sim-cell holds it,
        :class:`ConfigError` when it cannot be a state file (a directory, an unwritable place). A state file
        left by a dead sim-cell is taken over."""
        lock_path = path.with_name(path.name + ".lock")
        for candidate, what in ((path, "state file"), (lock_path, "state file's lock")):
            if candidate.is_dir():
                raise ConfigError(f"{what} {candidate} is a directory; give --state-file a file path")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f"state file {path}: cannot create its folder: {exc}") from exc
        for _ in range(TAKE_ATTEMPTS):
            try:
                fd = os.open(lock_path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            except OSError as exc:
                raise ConfigError(f"state file {path}: cannot open its lock {lock_path}: {exc}") from exc
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                owner = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "?"
                os.close(fd)
                raise DeviceBusy(f"a simulated cell is already running (pid {owner}) with state file {path}; stop "
                                 f"it or give another --state-file") from None
            if _same_file(fd, lock_path):  # not unlinked by its last owner between our open and our lock
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
                return cls(path, lock_path, fd)
            os.close(fd)
        raise DeviceBusy(f"state file {path}: its lock {lock_path} keeps changing hands; try again")

    def beside(self, suffix: str) -> Path:
        """A file of this sim-cell beside the state file (``<stem><suffix>``), deleted on release."""
        path = self.path.with_name(self.path.stem + suffix)
        self._files.append(path)
        return path

    def close(self) -> None:
        """Release the claim: delete the state file and the files beside it, then the lock, while still holding it."""
        if self._fd is None:
            return
        for path in (self.path, *self._files, self.lock_path):
            try:
                path.unlink(missing_ok=True)
            except OSError as exc:
                log.warning("cannot remove %s: %s", path, exc)
        os.close(self._fd)
        self._fd = None


def _same_file(fd: int, path: Path) -> bool:
    try:
        return os.fstat(fd).st_ino == os.stat(path).st_ino
    except FileNotFoundError:
        return False
