"""The one way a file the caller names is read as a config: the cell config (``--config``, ``[sim] truth_config``),
``simulate --calibration``, ``calibrate --values``, the plant file.

Such a file must be a regular file (a symbolic link to one is fine) of at most :data:`MAX_CONFIG_BYTES`: a named
pipe would block the command forever waiting for a writer, a device such as ``/dev/zero`` would fill memory, and
neither is ever opened (a serial port's lines change when it is opened). Anything else is refused unread with
:class:`~monoguide.daemon.errors.ConfigFileRefused` naming the path and what it is; a missing or unreadable file is
a :class:`~monoguide.drivers.errors.ConfigError` naming it. The caller's ``label`` starts each message (the path, or
``--values PATH``) and ``what`` says what the file is for.
"""

from __future__ import annotations

import os
import stat
import tomllib
from pathlib import Path
from typing import Any

from monoguide.daemon.errors import ConfigFileRefused
from monoguide.drivers.errors import ConfigError

MAX_CONFIG_BYTES = 4 * 1024 * 1024  # 4 MiB: a cell of many part types is well under 100 KiB
_MAX_TEXT = "4 MiB"
_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a named pipe (FIFO)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def read_config_bytes(path: str | os.PathLike[str], what: str = "config file", label: str | None = None) -> bytes:
    """The bytes of ``path``, a regular file of at most :data:`MAX_CONFIG_BYTES`; see the module's doc."""
    path = Path(path)
    label = str(path) if label is None else label
    try:
        _check(os.stat(path), label, what)  # before opening: a pipe or a device is never opened
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except FileNotFoundError as exc:
        raise ConfigError(f"{label}: no such {what}") from exc
    except OSError as exc:
        raise ConfigError(f"{label}: cannot read the {what}: {exc.strerror or exc}") from exc
    try:
        _check(os.fstat(fd), label, what)  # the file opened is the one checked (not swapped in between)
        data = _read_at_most(fd, MAX_CONFIG_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"{label}: cannot read the {what}: {exc.strerror or exc}") from exc
    finally:
        os.close(fd)
    if len(data) > MAX_CONFIG_BYTES:  # it grew while being read
        raise ConfigFileRefused(f"{label}: more than {_MAX_TEXT}: a {what} is at most {_MAX_TEXT}")
    return data


def read_config_text(path: str | os.PathLike[str], what: str = "config file", label: str | None = None) -> str:
    """:func:`read_config_bytes` as UTF-8 text."""
    data = read_config_bytes(path, what, label)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{str(path) if label is None else label}: not UTF-8 text (byte {exc.start} of the "
                          f"{what})") from exc


def read_config_toml(path: str | os.PathLike[str], what: str = "config file", label: str | None = None
                     ) -> dict[str, Any]:
    """:func:`read_config_text` parsed as TOML; :class:`ConfigError` ``not valid TOML`` with the parser's reason."""
    text = read_config_text(path, what, label)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{str(path) if label is None else label}: not valid TOML: {exc}") from exc


def _check(status: os.stat_result, label: str, what: str) -> None:
    if not stat.S_ISREG(status.st_mode):
        kind = next((name for test, name in _KINDS if test(status.st_mode)), "not a file")
        raise ConfigFileRefused(f"{label}: {kind}, not a regular file: a {what} must be a regular file of at most "
                                f"{_MAX_TEXT}")
    if status.st_size > MAX_CONFIG_BYTES:
        raise ConfigFileRefused(f"{label}: {status.st_size} bytes: a {what} is at most {_MAX_TEXT} "
                                f"({MAX_CONFIG_BYTES} bytes)")


def _read_at_most(fd: int, limit: int) -> bytes:
    chunks, size = [], 0
    while size < limit and (chunk := os.read(fd, min(65536, limit - size))):
        chunks.append(chunk)
        size += len(chunk)
    return b"".join(chunks)
