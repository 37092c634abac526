"""A listening TCP socket of the plant whose connections are counted per client address and in all, each handled as
a task of its own and all ended by :meth:`Listener.stop`: the OPC UA relay (``_front``) and the metrics endpoint
(``_metrics_http``) each own one. A connection beyond a limit is handed to the owner's ``busy`` answer and closed;
the others to its ``handler``, and closed when it returns or the client goes away."""

from __future__ import annotations

import asyncio
import contextlib
from collections import Counter
from collections.abc import Awaitable, Callable
from typing import Any

# (reader, writer, the client's IP address); busy: (writer, client, the limit reached)
Handler = Callable[[asyncio.StreamReader, asyncio.StreamWriter, str], Awaitable[None]]
Busy = Callable[[asyncio.StreamWriter, str, str], Awaitable[None]]
STOP_S = 5.0


class Listener:
    """``total`` and ``per_client``: the connections at once; ``names``: the keys of those limits, for the refusal."""

    def __init__(self, total: int, per_client: int, names: tuple[str, str]) -> None:
        self.total, self.per_client, self.names = total, per_client, names
        self.open: Counter[str] = Counter()  # client IP -> its connections now
        self._server: asyncio.Server | None = None
        self._connections: set[asyncio.Task[Any]] = set()

    async def listen(self, host: str, port: int, handler: Handler, busy: Busy, **options: Any) -> None:
        """Listen (``options``: those of ``asyncio.start_server``); raises OSError when it cannot."""
        async def connection(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            await self._connection(reader, writer, handler, busy)

        self._server = await asyncio.start_server(connection, host, port, **options)

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
        for task in list(self._connections):
            task.cancel()
        if self._connections:
            await asyncio.wait(self._connections, timeout=STOP_S)
        if self._server is not None:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._server.wait_closed(), STOP_S)
            self._server = None

    # --- private ------------------------------------------------------------------------------------

    async def _connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, handler: Handler,
                          busy: Busy) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._connections.add(task)
        peer = writer.get_extra_info("peername")
        client = str(peer[0]) if isinstance(peer, tuple) else "?"
        counted = False
        try:
            if sum(self.open.values()) >= self.total:
                await busy(writer, client, f"{self.names[0]} reached")
            elif self.open[client] >= self.per_client:
                await busy(writer, client, f"{self.names[1]} reached")
            else:
                self.open[client] += 1
                counted = True
                await handler(reader, writer, client)
        except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError):
            pass  # the client went away, or the other side did
        finally:
            if counted:
                self.open[client] -= 1
                if not self.open[client]:
                    del self.open[client]
            writer.close()
            self._connections.discard(task)
