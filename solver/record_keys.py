"""The measurement record's strict key check, shared by its readers (``solver/record.py``, ``record_marks.py``)."""

from __future__ import annotations

from typing import Any

from monoguide.solver.errors import MissingKey, RecordError, UnknownKey


def check_keys(data: Any, required: tuple[str, ...], optional: tuple[str, ...], where: str) -> None:
    """``data`` must be an object with every ``required`` key and no key outside ``required + optional``."""
    if not isinstance(data, dict):
        raise RecordError(f"{where or 'record'}: expected an object, got {data!r}"[:200])
    known = required + optional
    for key in data:
        if key not in known:
            raise UnknownKey.naming(str(key), known, where)
    for key in required:
        if key not in data:
            raise MissingKey(f"{where + '.' if where else ''}{key}: missing")
