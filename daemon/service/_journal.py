"""The journal: one SQLite row per finished cycle, committed before the PLC is told DONE.

A row holds the measurement record (``docs/measurement-record.md``) the cycle solved, its result or its
error (code, PLC code, message), the time each stage took, the robot's actual poses at the captures and
the paths of the images. The cycle counter (PLC register 13) is the number of the last committed row, so
it survives restarts.

Durability: WAL mode with ``synchronous=FULL``. WAL already survives a kill -9 of the process at
``NORMAL``; ``FULL`` also fsyncs the WAL at every commit, so a row the PLC was told about survives a power
cut too. The price is one fsync per cycle (cycles are seconds apart) — nothing next to a camera frame.
:meth:`Journal.commit_cycle` returns only after that commit, and returns the cycle number the PLC
is then given: the natural order is journal first, PLC after.

**An intent before every offset.** Before an offset goes to the robot, :meth:`Journal.commit_intent` commits
it (the cycle's number, the robot request's sequence number, the six numbers, the cycle's job, part tag and start)
in the table ``offset_intent``;
the cycle's row and the intent's outcome are committed together afterwards (:meth:`Journal.commit_cycle` with
``intent_outcome``). An intent without an outcome (the controller lost mid-write, the service killed between
the robot's acknowledgement and the commit) is settled against what the robot says it holds
(:meth:`Journal.settle_intent`), so no offset the robot received is missing from the journal.

**Cycle numbers** are SQLite integers (64 bit): they count on past 65,535 and 2^31; PLC register 13 shows them
modulo 65536. A journal that was recreated continues after the number the PLC last showed
(:meth:`Journal.continue_numbering`). The file's identity (device and inode) is checked before every commit: a
journal deleted or replaced under a running service is :class:`JournalReplaced`, never a silent write into an
unlinked file.

**A damaged row costs that row alone.** Reading never raises for what a row holds: a column that cannot be
decoded reads as its empty value and the row's ``damaged`` says which and why (``_journal_rows``).

Images live under ``<state dir>/images``; :meth:`Journal.prune_images` deletes those of the oldest
cycles beyond a size or age limit and marks their rows (the row itself is kept).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from monoguide.daemon.errors import (
    JournalEntryInvalid,
    JournalEntryMissing,
    JournalError,
    JournalReplaced,
)
from monoguide.daemon.service._journal_open import open_for_writing, open_read_only
from monoguide.daemon.service._journal_query import CycleQuery, error_codes, find_cycles
from monoguide.daemon.service._journal_rows import (
    JournalRow,
    OffsetIntent,
    decoded_json,
    images_shape,
    intent_from_row,
    journal_text,
    row_from,
    timings_shape,
)
from monoguide.daemon.service._journal_schema import (
    APPLICATION_ID,
    IMAGES_DIR,
    INTENT_OUTCOMES,
    JOURNAL_FILE,
    LAST_CYCLES_QUERY,
    MAX_NUMBER,
    PRUNE_QUERY,
    SCHEMA_VERSION,
    CycleEntry,
    PruneReport,
    SqliteErrors,
    checked_duration,
    cycle_select,
    dumps,
    file_size,
    intent_select,
    last_cycles_query,
    outcome_of,
)

__all__ = ["APPLICATION_ID", "INTENT_OUTCOMES", "JOURNAL_FILE", "LAST_CYCLES_QUERY", "PRUNE_QUERY", "SCHEMA_VERSION",
           "CycleEntry", "CycleQuery", "Journal", "JournalRow", "OffsetIntent", "PruneReport"]


class Journal:
    """The journal of one state directory. Open it once per process; the service is the only writer.

    ``read_only=True`` is every reader's open (``journal``, ``status``, the operator page, the plant
    interfaces): SQLite's ``mode=ro``, nothing created, upgraded or locked for writing; a write raises
    ``sqlite3.OperationalError`` turned into :class:`JournalError`. A WAL journal is read through its ``-shm``
    file, which the service keeps while it runs; where that file is missing and cannot be created (the service
    stopped, a state directory the reader may not write), the file is opened ``immutable`` — nobody writes it then.
    """

    def __init__(self, state_dir: Path | str, *, read_only: bool = False) -> None:
        self.state_dir = Path(state_dir)
        self.path = self.state_dir / JOURNAL_FILE
        self.images_dir = self.state_dir / IMAGES_DIR
        self.read_only = read_only
        self.immutable = False  # read-only and opened `immutable`: it sees no later commit (reopen it then)
        self._image_sizes: dict[str, int] = {}  # stored image path -> bytes, looked up once (prune_images)
        if read_only:
            self._db, self.version, self.immutable = open_read_only(self.path)
        else:
            try:
                self.images_dir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise JournalError(f"journal {self.path}: cannot create {self.images_dir}: {exc}") from exc
            self._db, self.version = open_for_writing(self.path), SCHEMA_VERSION
        self._db.text_factory = journal_text  # text that is not UTF-8 damages its row, not the query
        self._identity = self._file_identity()
        # self.version: the file's schema version. A reader reads the journal as that version holds it (the service
        # has upgraded it to SCHEMA_VERSION): what it does not hold reads as null
        self._cycle_select = cycle_select(self.version)
        self._last_cycles = last_cycles_query(self.version)
        self._intent_select = intent_select(self.version)

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # --- writing ------------------------------------------------------------------------------------

    def commit_cycle(self, entry: CycleEntry, number: int | None = None, *,
                     intent_outcome: tuple[str, str] | None = None) -> int:
        """Store one finished cycle and commit it (fsynced); return its number, the new cycle counter.

        ``number``: the cycle's number when an intent was committed for it (:meth:`next_number` then); else the
        next one. ``intent_outcome`` (outcome, detail): settles that cycle's intent in the same transaction.
        Only after this returns may the PLC be told DONE. Raises :class:`JournalEntryInvalid` for an entry
        that contradicts itself and :class:`JournalError` when SQLite fails (nothing is then committed).
        """
        status, error_code, plc_code, message = outcome_of(entry)
        row = (
            number, entry.started_at, entry.finished_at, entry.job, entry.part_tag, status, error_code, plc_code,
            message, dumps("record", entry.record), dumps("result", entry.result),
            dumps("timings_s", entry.timings_s), dumps("poses_at_capture", entry.poses_at_capture),
            dumps("image_paths", [self._relative(p) for p in entry.image_paths]), checked_duration(entry),
        )
        self.check_identity()
        with self._sqlite("commit a cycle"), self._db:
            cursor = self._db.execute(
                "INSERT INTO cycle (number, started_at, finished_at, job, part_tag, status, error_code, plc_code,"
                " error_message, record_json, result_json, timings_json, poses_json, images_json, duration_s)"
                " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                row,
            )
            committed = int(cursor.lastrowid)
            if intent_outcome is not None:
                self._settle(committed, *intent_outcome, cleared=False)
        return committed

    def next_number(self) -> int:
        """The number the next committed cycle gets (the counter + 1)."""
        return self.cycle_counter() + 1

    def commit_intent(self, cycle: int, sequence: int, registers: tuple[float, ...], D_b: list[list[float]], *,
                      job: int | None = None, part_tag: int | None = None, started_at: float | None = None) -> None:
        """Commit the offset of cycle ``cycle`` (request ``sequence``) before it is sent: when this raises,
        nothing may be sent. ``registers``: x y z (mm) A B C (deg) as the PLC shows them; ``D_b`` the 4x4.
        ``job``, ``part_tag`` (PLC registers 1 and 3), ``started_at`` (Unix s): the cycle's, for the row rebuilt
        from the intent when the service ends before the cycle's own row is committed."""
        offset = dumps("offset", {"registers": [float(v) for v in registers], "D_b": D_b})
        self.check_identity()
        with self._sqlite(f"commit the offset intent of cycle {cycle}"), self._db:
            self._db.execute("INSERT INTO offset_intent (cycle, sequence, offset_json, intended_at, job, part_tag,"
                             " started_at) VALUES (?, ?, ?, ?, ?, ?, ?)",
                             (cycle, sequence, offset, time.time(), job, part_tag, started_at))

    def settle_intent(self, cycle: int, outcome: str, detail: str, *, cleared: bool = False) -> None:
        """Record what became of cycle ``cycle``'s offset (``INTENT_OUTCOMES``) and whether monoguide cleared
        it from the robot afterwards."""
        self.check_identity()
        with self._sqlite(f"settle the offset intent of cycle {cycle}"), self._db:
            self._settle(cycle, outcome, detail, cleared=cleared)

    def intent(self, cycle: int) -> OffsetIntent | None:
        if self._intent_select is None:  # a version-1 journal, read as it is: no intents yet
            return None
        with self._sqlite(f"read the offset intent of cycle {cycle}"):
            found = self._db.execute(f"{self._intent_select} WHERE cycle = ?", (cycle,)).fetchone()
        return None if found is None else intent_from_row(found)

    def unsettled_intents(self) -> list[OffsetIntent]:
        """Intents without an outcome, oldest first: offsets the robot may hold."""
        if self._intent_select is None:
            return []
        with self._sqlite("list unsettled offset intents"):
            rows = self._db.execute(f"{self._intent_select} WHERE outcome IS NULL ORDER BY cycle").fetchall()
        return [intent_from_row(found) for found in rows]

    def last_sequence(self) -> int:
        """The robot sequence number of the newest intent (0: none)."""
        if self._intent_select is None:
            return 0
        with self._sqlite("read the last offset intent"):
            found = self._db.execute("SELECT sequence FROM offset_intent ORDER BY cycle DESC LIMIT 1").fetchone()
        return found[0] if found and isinstance(found[0], int) else 0

    def continue_numbering(self, after: int) -> bool:
        """A journal with no cycle yet numbers its first cycle ``after + 1`` (the PLC's register 13 showed
        ``after``: a recreated journal must not count 1, 2, ... again). True when it changed the numbering."""
        if after <= 0:
            return False
        self.check_identity()
        with self._sqlite("continue the cycle numbering"), self._db:
            if self._db.execute("SELECT count(*) FROM cycle").fetchone()[0]:
                return False
            self._db.execute("DELETE FROM sqlite_sequence WHERE name = 'cycle'")
            self._db.execute("INSERT INTO sqlite_sequence (name, seq) VALUES ('cycle', ?)", (after,))
        return True

    def check_identity(self) -> None:
        """:class:`JournalReplaced` when the file at :attr:`path` is gone or is another file than the one opened."""
        try:
            now = self._file_identity()
        except FileNotFoundError:
            raise JournalReplaced(f"journal {self.path}: the file was deleted while the service ran; nothing more "
                                  "is committed and no offset is written until the service is restarted") from None
        if now != self._identity:
            raise JournalReplaced(f"journal {self.path}: the file was replaced by another (inode {self._identity[1]}"
                                  f" -> {now[1]}) while the service ran; nothing more is committed and no offset is "
                                  "written until the service is restarted")

    def amend_timings(self, number: int, timings_s: dict[str, float]) -> None:
        """Add timings known only after the commit (``plc_journal``, ``cycle``: they include the commit and
        the PLC's DONE) to cycle ``number``'s row; the rest of the row is never changed. Stored timings that
        cannot be decoded are left as they are (:class:`JournalEntryInvalid`)."""
        self.check_identity()
        with self._sqlite(f"amend cycle {number}"), self._db:
            found = self._db.execute("SELECT timings_json FROM cycle WHERE number = ?", (number,)).fetchone()
            if found is None:
                raise JournalEntryMissing(f"journal {self.path}: no cycle {number}")
            stored, damaged = decoded_json("timings_json", found[0], timings_shape, {})
            if damaged:
                raise JournalEntryInvalid(f"journal {self.path}: cycle {number}: {damaged[0]}; its timings are not "
                                          "amended")
            self._db.execute("UPDATE cycle SET timings_json = ? WHERE number = ?",
                             (dumps("timings_s", {**stored, **timings_s}), number))

    # --- reading ------------------------------------------------------------------------------------

    def cycle_counter(self) -> int:
        """The number of the last committed cycle (0 for a new journal): PLC register 13."""
        with self._sqlite("read the cycle counter"):
            found = self._db.execute("SELECT seq FROM sqlite_sequence WHERE name = 'cycle'").fetchone()
        return int(found[0]) if found else 0

    def cycle(self, number: int) -> JournalRow:
        if not 1 <= number <= MAX_NUMBER:  # SQLite's integers are 64-bit: a larger number is no cycle
            raise JournalEntryMissing(f"journal {self.path}: no cycle {number}: cycle numbers run from 1 to "
                                      f"{MAX_NUMBER} (counter {self.cycle_counter()})")
        with self._sqlite(f"read cycle {number}"):
            found = self._db.execute(f"{self._cycle_select} WHERE cycle.number = ?", (number,)).fetchone()
        if found is None:
            raise JournalEntryMissing(f"journal {self.path}: no cycle {number} (counter {self.cycle_counter()})")
        return row_from(found)

    def has_cycle(self, number: int) -> bool:
        with self._sqlite(f"look for cycle {number}"):
            return self._db.execute("SELECT 1 FROM cycle WHERE number = ?", (number,)).fetchone() is not None

    def last_cycles(self, count: int) -> list[JournalRow]:
        """The ``count`` most recent cycles, newest first."""
        with self._sqlite("list cycles"):
            rows = self._db.execute(self._last_cycles, (MAX_NUMBER, count)).fetchall()
        return [row_from(found) for found in rows]

    def find_cycles(self, query: CycleQuery) -> list[JournalRow]:
        """The cycles ``query`` filters (status, error code, job, time window), newest first, one page (below
        ``query.before``): each filter through an index of its own (``_journal_query``)."""
        with self._sqlite("find cycles"):
            return find_cycles(self._db, query, select=self._cycle_select)

    def error_codes(self) -> list[str]:
        """Every error code the journal holds, sorted."""
        with self._sqlite("list error codes"):
            return error_codes(self._db)

    def outcome_counts(self) -> dict[tuple[str, str | None], int]:
        """The number of cycles by (status, error code), for a reader's start (`plant`): counted in the indexes of
        status and of error code (a failed cycle always has its code), not in the rows."""
        with self._sqlite("count cycles by outcome"):
            rows = self._db.execute("SELECT 'ok', NULL, count(*) FROM cycle WHERE status = 'ok' UNION ALL"
                                    " SELECT 'error', error_code, count(*) FROM cycle WHERE error_code IS NOT NULL"
                                    " GROUP BY error_code")
            return {(status, code): int(n) for status, code, n in rows.fetchall() if n}

    def integrity_check(self) -> str:
        """SQLite's ``PRAGMA integrity_check``: ``"ok"`` or the damage it found."""
        with self._sqlite("check integrity"):
            return "\n".join(str(r[0]) for r in self._db.execute("PRAGMA integrity_check").fetchall())

    # --- images -------------------------------------------------------------------------------------

    def prune_images(self, max_bytes: int, max_age_s: float, now: float | None = None) -> PruneReport:
        """Delete the image files of the oldest cycles until the rest are younger than ``max_age_s`` and
        together at most ``max_bytes``; mark those rows ``images_pruned_at``. Call it between cycles.

        Whole cycles go together, oldest first; missing files count as already gone. Only the cycles whose
        images are kept are read (an index), and each file's size is looked up once (the files of a committed
        cycle are complete): the cost follows the images kept, not the journal's length.
        """
        now = time.time() if now is None else now
        with self._sqlite("list images"):
            rows = self._db.execute(PRUNE_QUERY).fetchall()
        sizes = self._image_sizes
        cycles = []
        for number, finished_at, images in rows:
            paths = decoded_json("images_json", images, images_shape, [])[0]  # unreadable: no file known to delete
            for stored in paths:
                if stored not in sizes:
                    sizes[stored] = file_size(self._absolute(stored))
            cycles.append((number, finished_at, paths))
        total = sum(sizes[stored] for _, _, paths in cycles for stored in paths)
        pruned: list[int] = []
        files = freed = 0
        for number, finished_at, paths in cycles:
            if now - finished_at <= max_age_s and total <= max_bytes:
                break
            for stored in paths:
                size = sizes.pop(stored, 0)
                if size:
                    self._absolute(stored).unlink(missing_ok=True)
                    files += 1
                    freed += size
                    total -= size
            pruned.append(number)
        if pruned:
            with self._sqlite("mark pruned images"), self._db:
                self._db.executemany("UPDATE cycle SET images_pruned_at = ? WHERE number = ?",
                                     [(now, number) for number in pruned])
        return PruneReport(len(pruned), files, freed)

    # --- private ------------------------------------------------------------------------------------

    def _settle(self, cycle: int, outcome: str, detail: str, *, cleared: bool) -> None:
        if outcome not in INTENT_OUTCOMES:
            raise JournalEntryInvalid(f"offset intent of cycle {cycle}: outcome {outcome!r} is not one of "
                                      f"{', '.join(INTENT_OUTCOMES)}")
        updated = self._db.execute("UPDATE offset_intent SET outcome = ?, detail = ?, cleared = ?, settled_at = ?"
                                   " WHERE cycle = ?", (outcome, detail, int(cleared), time.time(), cycle)).rowcount
        if not updated:
            raise JournalEntryMissing(f"journal {self.path}: no offset intent for cycle {cycle}")

    def _file_identity(self) -> tuple[int, int]:
        stat = os.stat(self.path)
        return stat.st_dev, stat.st_ino

    def _sqlite(self, doing: str) -> SqliteErrors:
        return SqliteErrors(self.path, doing)

    def _relative(self, path: str | Path) -> str:
        path = Path(path)
        try:
            return str(path.resolve().relative_to(self.state_dir.resolve()))
        except ValueError:
            return str(path)

    def _absolute(self, stored: str) -> Path:
        path = Path(stored)
        return path if path.is_absolute() else self.state_dir / path


