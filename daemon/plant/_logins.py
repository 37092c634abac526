"""Failed logins per client address, for the OPC UA sessions (``_sessions``) and the metrics' basic authentication
(``_metrics_http``): after ``[plant] login_failures`` failures within ``login_window_s`` from one address, its next
logins are refused without a check until the oldest failure has left the window."""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable

LOGIN_CLIENTS_KEPT = 4096  # addresses whose failed logins are remembered (the oldest forgotten first)


class LoginGate:
    """Failed logins per client address within a sliding window."""

    def __init__(self, failures: int, window_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.failures, self.window_s, self.clock = failures, window_s, clock
        self._failed: dict[str, deque[float]] = {}

    def waiting(self, client: str) -> bool:
        """Whether ``client`` has used up its failed logins of the window."""
        times = self._failed.get(client)
        if times is None:
            return False
        while times and self.clock() - times[0] > self.window_s:
            times.popleft()
        return len(times) >= self.failures

    def failed(self, client: str) -> None:
        if client not in self._failed and len(self._failed) >= LOGIN_CLIENTS_KEPT:
            self._failed.pop(next(iter(self._failed)))
        self._failed.setdefault(client, deque(maxlen=self.failures)).append(self.clock())
