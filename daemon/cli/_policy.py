"""One way for every command to end: its exit status and the one line that says why on standard error.

Exit status: **0** done; **1** failed (a device, a refusal, a check: the message says which); **2** bad usage or a
bad config (nothing was started; the message names the option or the key). Two conventions on top, each where
it is documented: ``status`` exits **3** when no service runs (as ``systemctl status``), and the long runs
(``simulate``, ``calibrate``) exit **130** when interrupted (Ctrl-C, as a shell does).

The line is ``CODE message`` — the error's stable code, then its message, optionally after what the command was
doing (``CALIBRATION_RESIDUAL_TOO_LARGE step 'sfi' refused: ...``) — plain text, never wrapped or coloured, so
that a script or a log reader can take the first word.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NoReturn, TypeVar

import typer

from monoguide.daemon.cli._console import say, stderr_console
from monoguide.daemon.errors import StateDirInvalid
from monoguide.drivers.errors import ConfigError
from monoguide.solver.errors import MonoguideError

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2
EXIT_NOT_RUNNING = 3  # `monoguide status`: no service runs (LSB, as `systemctl status` of an inactive unit)
EXIT_INTERRUPTED = 130  # Ctrl-C during a long run (128 + SIGINT, as a shell reports it)
USAGE_ERRORS: tuple[type[MonoguideError], ...] = (ConfigError, StateDirInvalid)
"""Errors that are the caller's input — a config file or an option — not a failure of the run: exit 2."""

T = TypeVar("T")


def exit_status(error: MonoguideError) -> int:
    """2 for a bad config or usage (:data:`USAGE_ERRORS`), else 1."""
    return EXIT_USAGE if isinstance(error, USAGE_ERRORS) else EXIT_FAILED


def error_line(error: MonoguideError, doing: str | None = None) -> str:
    """``CODE message``, or ``CODE doing: message``."""
    return f"{error.code} {doing}: {error.message}" if doing else f"{error.code} {error.message}"


def report(error: MonoguideError, doing: str | None = None) -> None:
    """The error's line on standard error (the run goes on: a batch command reports each failure)."""
    say(stderr_console(), error_line(error, doing))


def fail(error: MonoguideError, doing: str | None = None, status: int | None = None) -> NoReturn:
    """Say why on standard error and end the command with its exit status (:func:`exit_status` unless given)."""
    report(error, doing)
    raise typer.Exit(exit_status(error) if status is None else status)


def reporting_errors(command: Callable[[], T], doing: str | None = None) -> T:
    """Run ``command``; a monoguide error ends the command as :func:`fail` says."""
    try:
        return command()
    except MonoguideError as error:
        fail(error, doing)
