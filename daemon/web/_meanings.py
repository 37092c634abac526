"""What an error code means, for the person at the line: the first paragraph of its class's description (the
same classes the PLC table of docs/plc-interface.md is generated from)."""

from __future__ import annotations

import functools
import importlib
import inspect

from monoguide.solver.errors import MonoguideError, all_error_classes

# every module that defines error classes: the daemon's, the drivers', the solver's (with planning, calibration)
ERROR_MODULES = ("monoguide.daemon.errors", "monoguide.drivers.errors", "monoguide.solver.errors",
                 "monoguide.solver.planning.errors", "monoguide.solver.calibration.errors")


def meaning(code: str | None) -> str | None:
    """The description of error ``code`` (None: no such code, or none given)."""
    if not code:
        return None
    return _by_code().get(code)


@functools.cache
def _by_code() -> dict[str, str]:
    for module in ERROR_MODULES:
        importlib.import_module(module)
    out = {}
    for cls in all_error_classes():
        if cls is not MonoguideError and "code" in vars(cls):
            doc = inspect.getdoc(cls) or ""
            out[cls.code] = " ".join(doc.split("\n\n")[0].split())
    return out
