"""HistoryRead of the result events, read from the journal: a SCADA that was away reads the ``ResultReadyEventType``
events it missed (OPC 10000-11 ReadEventDetails on ``VisionSystem``), as many as the journal holds.

- ``StartTime`` before ``EndTime``: the events in that window, oldest first; ``StartTime`` after ``EndTime``, or
  only ``EndTime``: newest first; only ``StartTime``: oldest first from it. Both ends count (inclusive).
- ``NumValuesPerNode``: at most that many (0: no limit), never more than :data:`MAX_EVENTS` in one answer; the rest
  follows with the continuation point (a time, as asyncua's history service keeps it).
- The events are those sent live (``_result_data.fill_result_event``), their ``Time`` the journal row's; each has
  the EventId ``monoguide-result-<cycle>``, the same at every read.

Finding the window's first row costs a binary search over the cycle numbers (rows are numbered in commit order),
so a read costs what its answer holds, not what the journal holds.
"""

from __future__ import annotations

import copy
import datetime
from typing import Any

from asyncua import ua
from asyncua.common.events import Event
from asyncua.server.history import HistoryStorageInterface

from monoguide.daemon.plant._journal_reader import JournalReader
from monoguide.daemon.plant._result_data import ResultShapes, fill_result_event, result_message
from monoguide.daemon.plant._results import cycle_result
from monoguide.daemon.service import CycleQuery, Journal, JournalRow

MAX_EVENTS = 500  # the journal's page (MAX_PAGE)
NEXT_S = 1e-6  # a continuation starts just after the last event returned
_NO_TIME = datetime.datetime(1601, 1, 2, tzinfo=datetime.UTC)  # OPC UA's null DateTime is 1601-01-01


class JournalEventHistory(HistoryStorageInterface):
    """asyncua's history storage for events: read from the journal; nothing is stored, nothing written."""

    def __init__(self, reader: JournalReader, shapes: ResultShapes, sources: tuple[ua.NodeId, ...],
                 template: Any) -> None:
        super().__init__()
        self.reader, self.shapes, self.sources, self.template = reader, shapes, sources, template

    async def init(self) -> None:
        return None

    async def stop(self) -> None:
        self.reader.close()

    async def new_historized_node(self, node_id: ua.NodeId, period: datetime.timedelta | None,
                                  count: int = 0) -> None:
        return None

    async def save_node_value(self, node_id: ua.NodeId, datavalue: ua.DataValue) -> None:
        return None

    async def read_node_history(self, node_id: ua.NodeId, start: datetime.datetime | None,
                                end: datetime.datetime | None, nb_values: int) -> tuple[list[ua.DataValue], None]:
        return [], None  # the variables keep no history: the events do

    async def new_historized_event(self, source_id: ua.NodeId, evtypes: list[Any], period: datetime.timedelta | None,
                                   count: int = 0) -> None:
        return None

    async def save_event(self, event: Event) -> None:
        return None

    async def read_event_history(self, source_id: ua.NodeId, start: datetime.datetime | None,
                                 end: datetime.datetime | None, nb_values: int,
                                 evfilter: ua.EventFilter) -> tuple[list[Event], datetime.datetime | None]:
        if source_id not in self.sources:
            return [], None
        first, last = _seconds(start), _seconds(end)
        if first is None and last is None:
            return [], None
        count = min(nb_values or MAX_EVENTS, MAX_EVENTS)
        forward = first is not None and (last is None or first <= last)
        if forward:
            assert first is not None
            found = await self.reader.read(lambda journal: _forward(journal, first, last, count))
        else:
            upper = first if first is not None else last
            lower = last if first is not None else None
            assert upper is not None
            found = await self.reader.read(lambda journal: _backward(journal, upper, lower, count))
        rows, more = found or ([], None)
        return [self._event(row) for row in rows], more

    def _event(self, row: JournalRow) -> Event:
        event = copy.copy(self.template)
        result = cycle_result(row)
        fill_result_event(event, result, self.shapes)
        event.EventId = f"monoguide-result-{result.cycle}".encode()
        event.ReceiveTime = event.Time
        event.Message = ua.LocalizedText(result_message(result))
        return event


def _forward(journal: Journal, start: float, end: float | None, count: int) -> tuple[list[JournalRow],
                                                                                   datetime.datetime | None]:
    to = None if end is None else end + NEXT_S
    newest = journal.find_cycles(CycleQuery(finished_from=start, finished_to=to, limit=1))
    if not newest:
        return [], None
    first = _first_from(journal, start, newest[0].number)
    rows = journal.find_cycles(CycleQuery(finished_from=start, finished_to=to, before=first + count, limit=count))[::-1]
    more = rows and rows[-1].number < newest[0].number
    return rows, _time(rows[-1].finished_at + NEXT_S) if more else None


def _backward(journal: Journal, upper: float, lower: float | None, count: int) -> tuple[list[JournalRow],
                                                                                      datetime.datetime | None]:
    rows = journal.find_cycles(CycleQuery(finished_from=lower, finished_to=upper + NEXT_S, limit=count + 1))
    if len(rows) > count:
        return rows[:count], _time(rows[count - 1].finished_at - NEXT_S)
    return rows, None


def _first_from(journal: Journal, start: float, newest: int) -> int:
    """The smallest cycle number whose row (or the newest row below it) is not older than ``start``."""
    low, high = 1, newest
    while low < high:
        middle = (low + high) // 2
        below = journal.find_cycles(CycleQuery(before=middle + 1, limit=1))
        if below and below[0].finished_at >= start:
            high = middle
        else:
            low = middle + 1
    return low


def _seconds(moment: datetime.datetime | None) -> float | None:
    if moment is None or moment <= _NO_TIME.replace(tzinfo=moment.tzinfo or datetime.UTC):
        return None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=datetime.UTC)
    return moment.timestamp()


def _time(seconds: float) -> datetime.datetime:
    return datetime.datetime.fromtimestamp(seconds, datetime.UTC)
