"""How the commands write numbers, poses and times, alike in every table."""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any


def xyzabc(values: Sequence[float] | None) -> str:
    """A pose or an offset as x y z (mm, 3 decimals), A B C (deg, 4 decimals); empty when there is none."""
    if values is None:
        return ""
    x, y, z, a, b, c = (float(v) for v in values)
    return f"{x:.3f} {y:.3f} {z:.3f}, {a:.4f} {b:.4f} {c:.4f}"


def local_time(unix_s: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(unix_s))


def number(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def text(value: Any) -> str:
    return "-" if value is None else str(value)


def yes(value: Any) -> str:
    return "no" if value is None else "yes"
