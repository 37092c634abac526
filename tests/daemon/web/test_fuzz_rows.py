"""No journal row makes the operator page answer 5xx: a few hundred seeded rows written into a real journal with
sqlite3 — good rows, failed rows as the service journals them and rows of before, each changed at random (keys
missing, values of the wrong type, NaN and huge numbers, holes, points and views that do not match the config's
part, image paths outside the state directory or to files that are gone or are no PNG, JSON the journal cannot
decode, a damaged offset row) — asked for over every route by a real ``monoguide web`` process, with and without
the cell config. Every answer is below 500; every row is listed or named as unreadable; a cycle's page says what
of its row it could not show."""

from __future__ import annotations

import copy
import json
import os
import random
import re
import sqlite3
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from helpers.repository import EXAMPLE_RECORD
from helpers.web_pages import request, web_with_and_without_config

from monoguide.daemon.service import JOURNAL_FILE, Journal
from monoguide.solver.record import solve_record

pytestmark = pytest.mark.timeout(900)

HOST, PORT, BARE_PORT = "127.0.26.2", 8263, 8264
SEED, ROWS = 20261204, 300
MAX_NUMBER = 2**63 - 1
WEIRD: list[Any] = [None, True, False, 0, -1, 3.5, 1e308, -1e308, float("nan"), float("inf"), float("-inf"), 10**30,
                    10**400, "", "x" * 5000, "<script>alert(1)</script>", [], {}, [1, 2], [[1, 2, 3, 4]] * 4,
                    {"a": 1}, [[[[[[[[1]]]]]]]], [[0] * 4] * 3, [float("nan")] * 2, [1e300, -1e300]]
DAMAGED_JSON: list[str | bytes] = ['{"a": ', "not json", "[" * 5000 + "]" * 5000, "1" * 5000, "{'single': 'quotes'}",
                                   b"\xff\xfe{}"]
NOT_NULL = ("started_at", "finished_at", "status", "plc_code")
PATHS = ["/etc/passwd", "../../../etc/passwd", "images/../../outside.png", "images/gone/S1.png", "images/not-a-png.png",
         "images/a-folder.png", "images/link-out.png", "images/tiny.png", "images/big.png", "images/rgba.png",
         "images/deep16.png", "images/empty.png", "", "images/bad\u0000name.png", "images/" + "x" * 5000 + ".png"]


@dataclass
class Written:
    state_dir: Path
    numbers: list[int] = field(default_factory=list)
    undecodable: set[int] = field(default_factory=set)  # rows with JSON the journal cannot decode
    status: dict[int, str] = field(default_factory=dict)


def _images(state_dir: Path) -> None:
    images = state_dir / "images"
    (images / "a-folder.png").mkdir(parents=True)
    cv2.imwrite(str(images / "tiny.png"), np.full((48, 64), 90, np.uint8))
    cv2.imwrite(str(images / "big.png"), np.full((2058, 2456), 170, np.uint8))
    cv2.imwrite(str(images / "rgba.png"), np.full((100, 120, 4), 200, np.uint8))
    cv2.imwrite(str(images / "deep16.png"), np.full((100, 120), 40000, np.uint16))
    (images / "not-a-png.png").write_bytes(b"GIF89a" + os.urandom(200))
    (images / "empty.png").write_bytes(b"")
    outside = state_dir.parent / "outside.png"
    cv2.imwrite(str(outside), np.zeros((10, 10), np.uint8))
    (images / "link-out.png").symlink_to(outside)


def _templates() -> list[dict[str, Any]]:
    """Rows as the service writes them: a good roof cycle, a hood cycle failed measuring, a roof cycle failed
    solving, a row of before."""
    record = json.loads(EXAMPLE_RECORD.read_text())
    result, _ = solve_record(record)
    good = {"job": 1, "status": "ok", "error_code": None, "plc_code": 0, "error_message": None, "record": record,
            "result": result, "timings": {"cycle": 4.0, "solve": 0.1}, "poses": [np.eye(4).tolist()] * 4,
            "images": ["images/big.png"] * 4}
    view = {"view": 1, "pose": "S6", "image": "images/big.png", "T_b_f": np.eye(4).tolist(),
            "holes": [{"point": 2, "name": "H3", "pixel": [900.5, 700.25]}],
            "marks": [{"mark": 0, "name": "M1", "pixel": [300.0, 200.0]}],
            "expected": [{"point": 2, "name": "H3", "pixel": [903.0, 698.0], "radius_px": 24.0},
                         {"point": 3, "name": "H4", "pixel": [1500.0, 1100.0], "radius_px": 24.0}]}
    failure = {"stage": "measuring", "exception": "HoleNotFound", "unexpected": False, "view": "S6", "point": "H4",
               "expected_px": [1500.0, 1100.0]}
    hood = {"job": 2, "status": "error", "error_code": "HOLE_NOT_FOUND", "plc_code": 201,
            "error_message": "S6, H4: hole expected at (1500.0, 1100.0) r=24.0 px: no hole within 72 px",
            "record": None, "result": {"status": "error", "failure": failure, "views": [{**view, "view": 0,
                                                                                       "pose": "S5"}, view]},
            "timings": {"cycle": 3.0}, "poses": [np.eye(4).tolist()] * 2, "images": ["images/big.png"] * 2}
    solving = {**good, "status": "error", "error_code": "INCONSISTENT_MEASUREMENT", "plc_code": 205,
               "error_message": "chi-square 93 > 14", "result": {"status": "error", "failure": {
                   **failure, "stage": "solving", "exception": "InconsistentMeasurement", "view": None, "point": None,
                   "expected_px": None}, "views": [{**view, "view": k, "pose": f"S{k + 1}"} for k in range(4)],
                   "camera_deviation": [{"view": 0, "mm": [0.1, 0.2, 0.3]}]}}
    old = {**hood, "job": 1, "result": None, "images": [],
           "error_message": "S2, P2: hole expected at (812.4, 603.1) r=14.2 px: no hole within 43 px"}
    return [good, hood, solving, old]


def _mutate(value: Any, rng: random.Random, depth: int = 0) -> Any:
    """``value`` with one thing changed somewhere inside it."""
    if depth > 6 or not isinstance(value, dict | list) or not value or rng.random() < 0.25:
        return copy.deepcopy(rng.choice(WEIRD))
    value = copy.copy(value)
    if isinstance(value, dict):
        key = rng.choice(list(value))
        if rng.random() < 0.3:
            del value[key]
        else:
            value[key] = _mutate(value[key], rng, depth + 1)
        return value
    k = rng.randrange(len(value))
    choice = rng.random()
    if choice < 0.2:
        return value[:k]  # fewer points, views, observations than the config's part
    if choice < 0.35:
        return value + [copy.deepcopy(value[k])] * rng.randint(1, 8)  # more of them
    value[k] = _mutate(value[k], rng, depth + 1)
    return value


def _row(rng: random.Random, templates: list[dict[str, Any]]) -> tuple[dict[str, Any], dict[str, str | bytes]]:
    """A row's columns (values) and the JSON columns given as raw text (damaged)."""
    row = copy.deepcopy(rng.choice(templates))
    raw: dict[str, str | bytes] = {}
    for _ in range(rng.randint(0, 4)):
        what = rng.random()
        column = rng.choice(["record", "result", "timings", "poses", "images"])
        if what < 0.45:
            row[column] = _mutate(row[column], rng)
        elif what < 0.55:
            raw[column] = rng.choice(DAMAGED_JSON)
        elif what < 0.7:
            row["images"] = [rng.choice(PATHS) for _ in range(rng.randint(0, 6))]
        elif what < 0.8:
            row["job"] = rng.choice([1, 2, 3, 0, -5, "two", 2**40, None])
        elif what < 0.9:
            key = rng.choice(["started_at", "finished_at", "part_tag", "plc_code", "error_code", "error_message",
                              "images_pruned_at", "status"])
            row[key] = rng.choice([*WEIRD, "yesterday", b"\xff\x00", "BAD code", 10**30, "weird"])
        else:
            row["images_pruned_at"] = rng.choice([None, 1.0])
    return row, raw


def _write(state_dir: Path) -> Written:
    with Journal(state_dir):  # the schema, as the service makes it
        pass
    _images(state_dir)
    rng = random.Random(SEED)
    templates = _templates()
    written = Written(state_dir)
    db = sqlite3.connect(state_dir / JOURNAL_FILE)
    db.execute("PRAGMA ignore_check_constraints = ON")  # a status neither ok nor error, as a damaged file may hold
    numbers = [*range(1, ROWS - 1), ROWS + 40, MAX_NUMBER]  # a gap, and the last number SQLite has
    for number in numbers:
        row, raw = _row(rng, templates)
        started = 1_790_000_000.0 + 60.0 * (number % 10**6)
        values = {"started_at": started, "finished_at": started + 4.0, "part_tag": number % 65536,
                  "images_pruned_at": None, **row}
        columns = {f"{c}_json": raw.get(c, _json(values.pop(c))) for c in ("record", "result", "timings", "poses",
                                                                           "images")}
        if columns["timings_json"] is None:
            columns["timings_json"] = "null"
        for name in ("poses_json", "images_json"):
            columns[name] = columns[name] or "null"
        cells = {key: _sql(values[key]) for key in ("started_at", "finished_at", "job", "part_tag", "status",
                                                       "error_code", "plc_code", "error_message", "images_pruned_at")}
        for key in NOT_NULL:
            cells[key] = "missing" if cells[key] is None else cells[key]
        db.execute("INSERT INTO cycle (number, started_at, finished_at, job, part_tag, status, error_code, plc_code, "
                   "error_message, record_json, result_json, timings_json, poses_json, images_json, images_pruned_at) "
                   "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                   (number, cells["started_at"], cells["finished_at"], cells["job"], cells["part_tag"], cells["status"],
                    cells["error_code"], cells["plc_code"], cells["error_message"], columns["record_json"],
                    columns["result_json"], columns["timings_json"], columns["poses_json"], columns["images_json"],
                    cells["images_pruned_at"]))
        if number % 7 == 0:
            db.execute("INSERT INTO offset_intent (cycle, sequence, offset_json, intended_at, outcome) VALUES "
                       "(?, ?, ?, ?, ?)", (number, number, rng.choice(['{"registers": [1, 2]}', "{", "[]",
                                                                        '{"D_b": 1}']), started, "acknowledged"))
        written.numbers.append(number)
        if raw:
            written.undecodable.add(number)
        written.status[number] = cells["status"] if isinstance(cells["status"], str) else "?"
    db.commit()
    db.close()
    return written


def _json(value: Any) -> str | None:
    return None if value is None else json.dumps(value, allow_nan=True)


def _sql(value: Any) -> Any:
    """A value SQLite can bind (the rest as text, as a damaged row may hold it)."""
    if isinstance(value, int) and not isinstance(value, bool) and not -(2**63) <= value < 2**63:
        return str(value)
    return value if value is None or isinstance(value, int | float | str | bytes) else json.dumps(value)


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Written]:
    state = _write(tmp_path_factory.mktemp("fuzz") / "state")
    with web_with_and_without_config(state.state_dir, HOST, PORT, BARE_PORT):
        yield state


def _get(path: str, port: int = PORT) -> tuple[int, str]:
    answer = request(HOST, port, path, timeout_s=120.0)
    assert answer.status < 500, (path, answer.status, answer.text[:500])
    return answer.status, answer.text


def test_every_cycle_and_its_images_answer_below_500(written: Written) -> None:
    for number in written.numbers:
        status, html = _get(f"/cycles/{number}")
        assert status == 200, number
        if number in written.undecodable:
            assert 'id="not-shown"' in html, number  # the page says what it could not show
        _get(f"/cycles/{number}/record.json")
        squares = set(re.findall(rf"/cycles/{number}/views/(\d+)/holes/(\d+)\.png", html))
        views = {int(v) for v in re.findall(rf"/cycles/{number}/views/(\d+)/preview\.jpg", html)}
        for view in sorted(views | {1, 7})[:5]:
            for kind in ("image.png", "preview.jpg"):
                _get(f"/cycles/{number}/views/{view}/{kind}")
        for view, point in [*sorted(squares)[:4], ("1", "0"), ("2", "99")]:
            _get(f"/cycles/{number}/views/{view}/holes/{point}.png")


def test_without_the_config_every_cycle_answers_below_500(written: Written) -> None:
    for number in written.numbers[::3]:
        status, html = _get(f"/cycles/{number}", BARE_PORT)
        assert status == 200, number
        for view in sorted({int(v) for v in re.findall(rf"/cycles/{number}/views/(\d+)/holes/", html)})[:2]:
            _get(f"/cycles/{number}/views/{view}/preview.jpg", BARE_PORT)


@pytest.mark.parametrize("query", ["", "status=error", "status=ok", "job=2", "code=HOLE_NOT_FOUND", "limit=500"])
def test_every_row_is_listed_or_named_unreadable(written: Written, query: str) -> None:
    listed: list[int] = []
    named: set[int] = set()  # rows named as unreadable
    up_to: set[int] = set()  # rows above a named one the page says cannot be read either (when in this list)
    path = f"/cycles?{query}"
    while True:
        status, html = _get(path)
        assert status == 200, path
        listed += [int(n) for n in re.findall(r'data-cycle="(\d+)"', html)]
        for low, high in re.findall(r"cycle (\d+): its row cannot be read(?:, nor can any other row of this list "
                                    r"above it up to cycle (\d+))?", html):
            named.add(int(low))
            up_to |= {n for n in written.numbers if int(low) < n <= int(high or low)}
        assert "the rows further down are not listed" not in html
        older = re.search(r'id="older" href="([^"]+)"', html)
        if older is None:
            break
        path = older.group(1).replace("&amp;", "&")
    assert len(listed) == len(set(listed)) and not set(listed) & named
    assert listed == sorted(listed, reverse=True)
    assert named <= written.undecodable and not up_to & set(listed)
    if not query or query == "limit=500":  # the unfiltered list: every row listed, or said to be unreadable
        assert set(listed) | named | up_to == set(written.numbers)
        assert up_to <= written.undecodable
        assert set(written.numbers) - written.undecodable <= set(listed)
    if query == "status=error":
        expected = {n for n, s in written.status.items() if s == "error"}
        assert expected - written.undecodable <= set(listed) <= expected


def test_now_trends_and_calibration_answer_below_500(written: Written) -> None:
    for port in (PORT, BARE_PORT):
        assert _get("/", port)[0] == 200
        facts = json.loads(request(HOST, port, "/now.json").body)  # strict JSON: no NaN crosses
        assert facts["journal"]["cycle_counter"] == MAX_NUMBER and facts["journal"]["last"]["number"] == MAX_NUMBER
        if MAX_NUMBER in written.undecodable:
            assert "cannot be read" in facts["journal"]["last"]["unreadable"][0]
        assert _get("/calibration", port)[0] == 200
    assert _get("/trends?last=5000")[0] == 200
    for chart in ("offset", "quality", "errors"):
        answer = request(HOST, PORT, f"/trends/{chart}.png?last=5000", timeout_s=120.0)
        assert answer.status == 200 and answer.body[:8] == b"\x89PNG\r\n\x1a\n", chart
