"""Where the service keeps its state (journal, images, status file): one rule for every command.

``--state-dir`` when given; else systemd's ``$STATE_DIRECTORY`` (set by ``StateDirectory=`` in the
unit; when the unit lists several, the first); else ``/var/lib/monoguide``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from monoguide.solver.errors import MonoguideError

DEFAULT_STATE_DIR = Path("/var/lib/monoguide")
STATE_DIR_HELP = "The service's state directory (default: $STATE_DIRECTORY, else /var/lib/monoguide)."


class StateDirMissing(MonoguideError):
    """The state directory does not exist or is not a directory (wrong --state-dir, or the service never ran)."""

    code = "STATE_DIR_MISSING"
    plc_code = 640


def state_dir(given: Path | str | None = None, environ: Mapping[str, str] | None = None) -> Path:
    """The state directory: ``given``, else ``$STATE_DIRECTORY`` (its first entry), else the default."""
    if given is not None and str(given):
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
