"""The *Cycles* page: the journal's cycles newest first, a page at a time, filtered by status, error code, job and
finish time; each row its offset, RMS, sigmas and times. The URL's query is checked word by word: a value that is
not what the filter takes is a plain 400 page naming it, never a query."""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from monoguide.daemon.service import CycleQuery
from monoguide.daemon.web._rows import CycleRow

PAGE = 50
MAX_NUMBER = 2**63 - 1
_CODE = re.compile(r"^[A-Z][A-Z0-9_]{0,63}$")
FILTERS = ("status", "code", "job", "from", "to", "before", "limit")


class BadQuery(ValueError):
    """A filter value the page does not take (the message names it)."""


@dataclass(frozen=True)
class CyclesRequest:
    query: CycleQuery
    given: dict[str, str]  # the filters as given (for the form and the next page's link)


def cycles_request(params: dict[str, str]) -> CyclesRequest:
    """The page's filters from the URL's query (``status``, ``code``, ``job``, ``from``, ``to``: local date/time
    as ``YYYY-MM-DD[THH:MM]``, ``before``: a cycle number, ``limit``)."""
    unknown = sorted(set(params) - set(FILTERS))
    if unknown:
        raise BadQuery(f"unknown filter {unknown[0]!r}; the filters are {', '.join(FILTERS)}")
    given = {k: v.strip() for k, v in params.items() if v.strip()}
    status = given.get("status")
    if status not in (None, "ok", "error"):
        raise BadQuery(f"status {status!r}: ok or error")
    code = given.get("code")
    if code is not None and not _CODE.match(code):
        raise BadQuery(f"code {code!r}: an error code, e.g. HOLE_NOT_FOUND")
    query = CycleQuery(status=status, error_code=code, job=_whole(given, "job", 0, 65535),
                       finished_from=_time(given, "from"), finished_to=_time(given, "to"),
                       before=_whole(given, "before", 1, MAX_NUMBER) or 0,
                       limit=_whole(given, "limit", 1, 500) or PAGE)
    return CyclesRequest(query, given)


def cycle_line(row: CycleRow) -> dict[str, Any]:
    """One row of the list: what a person compares between cycles."""
    return {"number": row.number, "finished_at": row.finished_at, "job": row.job, "part_tag": row.part_tag,
            "status": row.status, "error_code": row.error_code, "plc_code": row.plc_code,
            "error_message": row.error_message, "offset": row.offset, "rms_px": row.rms_px, "sigma_mm": row.sigma_mm,
            "sigma_deg": row.sigma_deg, "cycle_s": row.cycle_s, "duration_s": row.duration_s,
            "unreadable": bool(row.unreadable)}


# --- private ------------------------------------------------------------------------------------


def _whole(given: dict[str, str], key: str, low: int, high: int) -> int | None:
    text = given.get(key)
    if text is None:
        return None
    if not text.isdigit() or not low <= int(text) <= high:
        raise BadQuery(f"{key} {text[:40]!r}: a whole number {low}..{high}")
    return int(text)


def _time(given: dict[str, str], key: str) -> float | None:
    text = given.get(key)
    if text is None:
        return None
    try:
        return datetime.fromisoformat(text).timestamp()  # local time, as the page shows times
    except (ValueError, OverflowError, OSError):
        raise BadQuery(f"{key} {text[:40]!r}: a date and time, YYYY-MM-DD or YYYY-MM-DDTHH:MM") from None
