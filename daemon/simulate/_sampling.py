"""The service's resident memory, threads and open files, sampled from ``/proc`` while a simulated run plays."""

from __future__ import annotations

import os
import time
from pathlib import Path


def sample_process(pid: int) -> dict[str, float] | None:
    """Resident memory (MB, also its children's), threads and open files of process ``pid``; None when gone
    (or a zombie: no memory left to tell)."""
    fields = _status_fields(pid)
    try:
        fds = len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None
    if fields is None or "VmRSS" not in fields or "Threads" not in fields:
        return None
    sample = {"t": time.monotonic(), "rss_mb": fields["VmRSS"] / 1024.0, "threads": fields["Threads"],
              "fds": float(fds), "children_rss_mb": 0.0}
    try:
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        children = []
    for child in children:
        child_fields = _status_fields(int(child))
        if child_fields is not None:
            sample["children_rss_mb"] += child_fields.get("VmRSS", 0.0) / 1024.0
    return sample


def _status_fields(pid: int) -> dict[str, float] | None:
    """The numeric fields of ``/proc/<pid>/status`` (kB for the memory ones); None when the process is gone."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    fields = {}
    for line in text.splitlines():
        key, _, value = line.partition(":")
        words = value.split()
        if words and words[0].isdigit():
            fields[key] = float(words[0])
    return fields
