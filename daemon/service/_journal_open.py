"""Opening the journal's file: the service's open (created, or upgraded in place from an older schema version, the
readers' indexes made, WAL with ``synchronous=FULL``) and every reader's (``mode=ro``, else ``immutable``; nothing
created, upgraded or locked). Either refuses a file that is not a monoguide journal this release reads."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from monoguide.daemon.errors import JournalError, JournalNotADatabase, JournalSchemaUnknown
from monoguide.daemon.service._journal_schema import (
    _INDEX_SCHEMA,
    _INTENT_SCHEMA,
    _SCHEMA,
    APPLICATION_ID,
    BUSY_TIMEOUT_MS,
    FILTER_INDEX_SCHEMA,
    READABLE_VERSIONS,
    SCHEMA_VERSION,
    SqliteErrors,
    upgrade_script,
)


def open_read_only(path: Path) -> tuple[sqlite3.Connection, int, bool]:
    """The reader's connection to the journal at ``path``, its schema version and whether it was opened
    ``immutable`` (the ``-shm`` file missing and not to be made: it then sees no later commit)."""
    if not path.is_file():
        raise JournalError(f"journal {path}: no such file")
    uri = path.resolve().as_uri()
    db = None
    immutable = False
    for query in ("mode=ro", "mode=ro&immutable=1"):
        try:
            db = sqlite3.connect(f"{uri}?{query}", uri=True, timeout=BUSY_TIMEOUT_MS / 1000,
                                 check_same_thread=False)
            with SqliteErrors(path, "open read-only"):
                version = db.execute("PRAGMA user_version").fetchone()[0]
                application_id = db.execute("PRAGMA application_id").fetchone()[0]
            immutable = "immutable" in query
            break
        except (sqlite3.Error, JournalError) as exc:
            if db is not None:
                db.close()
                db = None
            if isinstance(exc, JournalNotADatabase):  # the file itself: no other open mode can read it
                raise
            if query.endswith("immutable=1"):
                raise JournalError(f"journal {path}: cannot open read-only: {exc}") from exc
    assert db is not None
    if application_id != APPLICATION_ID or version not in READABLE_VERSIONS:
        db.close()
        raise JournalSchemaUnknown(f"journal {path}: not a monoguide journal this monoguide reads "
                                   f"(application_id {application_id:#x}, schema version {version}; reads "
                                   f"{', '.join(map(str, READABLE_VERSIONS))})")
    return db, version, immutable


def open_for_writing(path: Path) -> sqlite3.Connection:
    """The service's connection to the journal at ``path``, at :data:`SCHEMA_VERSION` (created or upgraded)."""
    try:
        # check_same_thread off: the service commits from a worker thread, one call at a time
        db = sqlite3.connect(path, timeout=BUSY_TIMEOUT_MS / 1000, isolation_level="DEFERRED",
                             check_same_thread=False)
    except sqlite3.Error as exc:
        raise JournalError(f"journal {path}: cannot open: {exc}") from exc
    try:
        with SqliteErrors(path, "open"):
            version = db.execute("PRAGMA user_version").fetchone()[0]
            application_id = db.execute("PRAGMA application_id").fetchone()[0]
            tables = db.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
        if version == 0 and application_id == 0 and tables == 0:
            with SqliteErrors(path, "create the schema"):
                db.executescript(f"BEGIN; {_SCHEMA} {_INTENT_SCHEMA} {_INDEX_SCHEMA}"
                                 f" PRAGMA application_id = {APPLICATION_ID};"
                                 f" PRAGMA user_version = {SCHEMA_VERSION}; COMMIT;")
        elif application_id != APPLICATION_ID:
            raise JournalSchemaUnknown(f"journal {path}: an SQLite database but not a monoguide journal"
                                       f" (application_id {application_id:#x}, {tables} objects); refusing to"
                                       " touch it — move it away or point --state-dir elsewhere")
        elif version not in READABLE_VERSIONS:
            newer = " (written by a newer monoguide?)" if version > SCHEMA_VERSION else ""
            raise JournalSchemaUnknown(f"journal {path}: schema version {version}{newer}; this monoguide"
                                       f" reads versions {', '.join(map(str, READABLE_VERSIONS))} only")
        elif version < SCHEMA_VERSION:  # additive, no row rewritten (_journal_schema._UPGRADES)
            with SqliteErrors(path, f"upgrade the schema from version {version}"):
                db.executescript(upgrade_script(version))
        with SqliteErrors(path, "index what readers filter on"):
            db.executescript(FILTER_INDEX_SCHEMA)
        with SqliteErrors(path, "set WAL mode"):
            mode = db.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            db.execute("PRAGMA synchronous = FULL")
        if mode != "wal":
            raise JournalError(f"journal {path}: SQLite refused WAL mode (got {mode!r})")
    except BaseException:
        db.close()
        raise
    return db
