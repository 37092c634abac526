"""A real journal whose rows are damaged in place with sqlite3, as a flipped byte or a hand edit leaves them while
the file's integrity check stays ok: what each row held is known (seeded), and which rows were damaged, how.

``seed_journal`` writes the cycles through ``Journal`` (ok cycles with an acknowledged intent, failed ones), then
``damage`` spoils one column of each of some rows, drawn from a seed: every kind of :data:`DAMAGES` once
(``damaged_journal`` both); ``spoil`` runs the UPDATEs a test spoils its own rows with."""

from __future__ import annotations

import dataclasses
import json
import sqlite3
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.daemon.service import CycleEntry, Journal
from monoguide.drivers.errors import DeviceTimeout

EXAMPLE_RECORD = Path(__file__).parents[2] / "examples" / "example-record.json"
T0 = 1_790_000_000.0
D_B = [[1.0, 0.0, 0.0, 12.5], [0.0, 1.0, 0.0, -3.25], [0.0, 0.0, 1.0, 0.75], [0.0, 0.0, 0.0, 1.0]]


@dataclasses.dataclass(frozen=True)
class Damage:
    """One kind of damage: the column it spoils, the status of the rows it fits, how (an UPDATE's SET clause and
    its values from the stored value and a random generator) and how the row must name it (its start)."""

    column: str
    status: str
    spoil: Callable[[Any, np.random.Generator], tuple[str, tuple[Any, ...]]]
    named: Callable[[Any], str]


def _set(sql: str, *values: Any) -> Callable[[Any, np.random.Generator], tuple[str, tuple[Any, ...]]]:
    return lambda _stored, _rng: (sql, values)


def _truncated(stored: str, rng: np.random.Generator) -> tuple[str, tuple[Any, ...]]:
    return "result_json = ?", (stored[: int(rng.integers(1, len(stored) - 1))],)


def _not_utf8(stored: str, rng: np.random.Generator) -> tuple[str, tuple[Any, ...]]:
    raw = bytearray(stored.encode())
    raw[int(rng.integers(0, len(raw)))] = 0xFF
    return "record_json = CAST(? AS TEXT)", (bytes(raw),)


def _utf8_named(stored: str) -> str:
    return "record_json: not UTF-8 text (byte 0xff at "


def _with(key: str, value: Any, column: str) -> Callable[[Any, np.random.Generator], tuple[str, tuple[Any, ...]]]:
    return lambda stored, _rng: (f"{column} = ?", (json.dumps({**json.loads(stored), key: value}),))


def _pixel_text(stored: str, _rng: np.random.Generator) -> tuple[str, tuple[Any, ...]]:
    record = json.loads(stored)
    record["observations"][0]["pixel"] = "812.5 433.1"
    return "record_json = ?", (json.dumps(record),)


DAMAGES: dict[str, Damage] = {
    "result not JSON": Damage("result_json", "ok", _truncated, lambda _: "result_json: not JSON ("),
    "result empty text": Damage("result_json", "ok", _set("result_json = ''"),
                                lambda _: "result_json: not JSON (Expecting value at char 0)"),
    "record not UTF-8": Damage("record_json", "ok", _not_utf8, _utf8_named),
    "record a list": Damage("record_json", "ok", _set("record_json = '[1, 2, 3]'"),
                            lambda _: "record_json: a list ([1, 2, 3]), not an object"),
    "record pixel text": Damage("record_json", "ok", _pixel_text,
                                lambda _: "record_json: observation 1 is not"),
    "result rms a string": Damage("result_json", "ok", _with("rms_px", "0.05", "result_json"),
                                  lambda _: "result_json: rms_px is a string ('0.05'), not a number"),
    "result offset five numbers": Damage("result_json", "ok", _with("base_offset_xyzabc", [1, 2, 3, 4, 5],
                                                                    "result_json"),
                                         lambda _: "result_json: base_offset_xyzabc is not six numbers"),
    "result null on a good cycle": Damage("result_json", "ok", _set("result_json = NULL"),
                                          lambda _: "result_json: null on a good cycle"),
    "timings value a string": Damage("timings_json", "error", _with("measuring", "3.5", "timings_json"),
                                     lambda _: "timings_json: 'measuring' is a string ('3.5'), not a number"),
    "timings NaN": Damage("timings_json", "ok", _set("timings_json = '{\"measuring\": NaN}'"),
                          lambda _: "timings_json: not strict JSON (NaN is no JSON number)"),
    "started_at text": Damage("started_at", "ok", _set("started_at = 'garbage'"),
                              lambda _: "started_at: a string ('garbage'), not a number"),
    "job text": Damage("job", "error", _set("job = 'x7'"), lambda _: "job: a string ('x7'), not a whole number"),
    "plc_code a blob": Damage("plc_code", "error", _set("plc_code = X'0192'"),
                              lambda _: "plc_code: a blob (b'\\x01\\x92'), not a whole number"),
    "error_code null": Damage("error_code", "error", _set("error_code = NULL"),
                              lambda _: "error_code: null on a failed cycle"),
    "poses 3x3": Damage("poses_json", "ok", _set("poses_json = '[[[1, 0, 0], [0, 1, 0], [0, 0, 1]]]'"),
                        lambda _: "poses_json: pose 1 is not a 4x4 matrix"),
    "images a number": Damage("images_json", "error", _set("images_json = '[\"images/a.png\", 7]'"),
                              lambda _: "images_json: image 2 is a number (7), not a path"),
    "duration text": Damage("duration_s", "ok", _set("duration_s = 'x'"),
                            lambda _: "duration_s: a string ('x'), not a non-negative number"),
}
EMPTY = {"result_json": ("result", None), "record_json": ("record", None), "timings_json": ("timings_s", {}),
         "started_at": ("started_at", 0.0), "job": ("job", None), "plc_code": ("plc_code", 0),
         "error_code": ("error_code", None), "poses_json": ("poses_at_capture", []),
         "images_json": ("image_paths", []), "duration_s": ("duration_s", None)}


@dataclasses.dataclass
class Seeded:
    state_dir: Path
    entries: dict[int, CycleEntry]  # cycle number -> what was committed
    registers: dict[int, list[float]]  # cycle number -> its intent's offset (ok cycles)
    damaged: dict[int, str] = dataclasses.field(default_factory=dict)  # cycle number -> the kind of damage


def seed_journal(state_dir: Path, record: dict, count: int, seed: int) -> Seeded:
    """``count`` cycles, every third failed; the ok ones with a result, an intent and its acknowledgement."""
    rng = np.random.default_rng(seed)
    seeded = Seeded(state_dir, {}, {})
    with Journal(state_dir) as journal:
        for n in range(1, count + 1):
            started = T0 + 30.0 * n
            common: dict[str, Any] = {
                "started_at": started, "finished_at": started + 7.5, "job": int(rng.integers(1, 4)), "part_tag": n,
                "timings_s": {"measuring": round(float(rng.uniform(3, 5)), 3), "solve": 0.09},
                "poses_at_capture": [[[1.0, 0.0, 0.0, float(rng.uniform(1000, 2000))], [0.0, 1.0, 0.0, 580.0],
                                      [0.0, 0.0, 1.0, 1241.9], [0.0, 0.0, 0.0, 1.0]]] * 2,
                "image_paths": [f"images/cycle-{n}/S1.png"], "duration_s": round(float(rng.uniform(6, 8)), 4)}
            if n % 3 == 0:
                entry = CycleEntry(**common, record=dict(record, id=f"part-{n}"),
                                   error=DeviceTimeout(f"robot: measuring pose {n % 4 + 1} not reached"))
                journal.commit_cycle(entry)
            else:
                offset = [round(float(v), 6) for v in rng.uniform(-20, 20, 6)]
                result = {"id": f"part-{n}", "status": "ok", "rms_px": round(float(rng.uniform(0.02, 0.1)), 6),
                          "rotation_deg": 0.5, "grasp_shift_mm": 3.25, "sigma_rot_deg": 0.01, "sigma_trans_mm": 0.2,
                          "method": "ml", "base_offset_xyzabc": offset}
                entry = CycleEntry(**common, record=dict(record, id=f"part-{n}"), result=result)
                journal.commit_intent(n, n, tuple(offset), D_B, job=entry.job, part_tag=n, started_at=started)
                journal.commit_cycle(entry, n, intent_outcome=("acknowledged", f"request {n} acknowledged"))
                seeded.registers[n] = offset
            seeded.entries[n] = entry
    return seeded


def damage(seeded: Seeded, seed: int) -> None:
    """Spoil one column of a row for every kind of :data:`DAMAGES`, the rows drawn from ``seed`` among those of the
    kind's status; the file's integrity check stays ok."""
    rng = np.random.default_rng(seed)
    kinds = list(DAMAGES)
    rng.shuffle(kinds)
    db = sqlite3.connect(seeded.state_dir / "journal.sqlite3")
    try:
        for kind in kinds:
            d = DAMAGES[kind]
            free = [n for n, e in seeded.entries.items()
                    if n not in seeded.damaged and (e.error is None) == (d.status == "ok")]
            number = int(rng.choice(free))
            (stored,) = db.execute(f"SELECT {d.column} FROM cycle WHERE number = ?", (number,)).fetchone()
            sql, values = d.spoil(stored, rng)
            with db:
                db.execute(f"UPDATE cycle SET {sql} WHERE number = ?", (*values, number))
            seeded.damaged[number] = kind
        assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    finally:
        db.close()


def damaged_journal(state_dir: Path, count: int, seed: int) -> Seeded:
    """``count`` cycles of the example record (``seed_journal``), then every kind of damage once (``damage``)."""
    seeded = seed_journal(state_dir, json.loads(EXAMPLE_RECORD.read_text()), count, seed)
    damage(seeded, seed + 1)
    return seeded


def spoil(state_dir: Path, *updates: str) -> None:
    """Run ``updates`` (SQL) on the journal in ``state_dir`` behind its reader's back, as a hand edit would."""
    db = sqlite3.connect(state_dir / "journal.sqlite3")
    try:
        with db:
            for update in updates:
                db.execute(update)
    finally:
        db.close()
