"""What the plant interfaces refused, said at most once per ``[plant] refusal_log_s``: one warning line per kind of
refusal with its count and the addresses it came from, not a line per refusal — a flood of connections fills no
disk and still shows in the log within one interval.

A refusal after a quiet interval is logged at once; those that follow within the interval are counted and said
when it ends (:meth:`Refusals.tick`, called by the plant's loop at every poll, and at every refusal).
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

log = logging.getLogger("monoguide.daemon.plant")

ADDRESSES_SHOWN = 3  # the busiest addresses a line names; the rest are counted


@dataclass
class _Tally:
    count: int = 0
    addresses: Counter[str] = field(default_factory=Counter)


class Refusals:
    """Counts refusals by (interface, reason); logs them once per ``interval_s``. ``total`` keeps every count since
    the start (the metric ``monoguide_plant_refusals_total``)."""

    def __init__(self, interval_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.interval_s = interval_s
        self.clock = clock
        self.total: Counter[tuple[str, str]] = Counter()
        self._pending: dict[tuple[str, str], _Tally] = {}
        self._said_at = -float("inf")

    def refuse(self, interface: str, reason: str, address: str) -> None:
        """One refusal: ``interface`` ``opcua`` or ``metrics``, ``reason`` a short fixed phrase (the metric's
        label), ``address`` the client's IP address."""
        tally = self._pending.setdefault((interface, reason), _Tally())
        tally.count += 1
        tally.addresses[address] += 1
        self.total[(interface, reason)] += 1
        self.tick()

    def tick(self) -> None:
        """Log what is pending when the last lines are an interval old."""
        now = self.clock()
        if not self._pending or now - self._said_at < self.interval_s:
            return
        self._said_at = now
        for (interface, reason), tally in sorted(self._pending.items()):
            busiest = ", ".join(f"{a} ({n})" for a, n in tally.addresses.most_common(ADDRESSES_SHOWN))
            others = len(tally.addresses) - ADDRESSES_SHOWN
            more = f" and {others} other address{'es' if others > 1 else ''}" if others > 0 else ""
            log.warning("%s refused %d time%s (%s) from %s%s; at most one line per %g s", interface, tally.count,
                        "" if tally.count == 1 else "s", reason, busiest, more, self.interval_s)
        self._pending.clear()
