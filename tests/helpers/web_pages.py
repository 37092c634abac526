"""The operator page in a test: ``monoguide web`` started as its own process on the test's loopback address and
stopped after it, plain HTTP requests to it, and a prepared state directory written by the real ``Journal``
with images whose holes lie where the journal says (the seeded truth the pages are checked against)."""

from __future__ import annotations

import http.client
import json
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from helpers.repository import EXAMPLE_RECORD, SIM_CELL
from helpers.sim_processes import stop
from monoguide.daemon.errors import CycleError
from monoguide.daemon.service import CycleEntry, Journal
from monoguide.solver.errors import HoleNotFound, InconsistentMeasurement, MarkNotFound, MonoguideError
from monoguide.solver.record import solve_record

START_S = 30.0
T0 = 1_790_000_000.0  # the prepared cycles' start times: T0 + 60 s * number
HOLE_RADIUS_PX = 28.0


@dataclass
class Answer:
    status: int
    headers: dict[str, str]
    body: bytes

    @property
    def text(self) -> str:
        return self.body.decode("utf-8", "replace")


@dataclass
class Prepared:
    """What was written: the ground truth the pages must show."""

    state_dir: Path
    ok: list[int] = field(default_factory=list)
    failed: dict[int, str] = field(default_factory=dict)  # number -> error code
    jobs: dict[int, int] = field(default_factory=dict)
    centres: dict[tuple[int, int], tuple[float, float]] = field(default_factory=dict)  # (cycle, view) -> px
    escaped: int = 0  # the cycle whose error message carries markup
    outside: int = 0  # the cycle whose journal row names a file outside the images folder
    pruned: int = 0  # the cycle whose images were pruned


def request(host: str, port: int, path: str, method: str = "GET", headers: dict[str, str] | None = None,
            timeout_s: float = 10.0) -> Answer:
    connection = http.client.HTTPConnection(host, port, timeout=timeout_s)
    try:
        connection.request(method, path, headers=headers or {})
        answer = connection.getresponse()
        return Answer(answer.status, {k.lower(): v for k, v in answer.getheaders()}, answer.read())
    finally:
        connection.close()


@contextmanager
def web_process(state_dir: Path, host: str, port: int, *options: str) -> Iterator[subprocess.Popen[str]]:
    """``monoguide web --state-dir state_dir --bind host:port *options``, answering, until the block ends."""
    process = subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "web", "--state-dir", str(state_dir),
                                "--bind", f"{host}:{port}", *options], stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + START_S
        while True:
            if process.poll() is not None:
                raise AssertionError(f"monoguide web ended ({process.returncode}): {process.stderr.read()}")
            try:
                request(host, port, "/static/style.css", timeout_s=2.0)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise AssertionError("monoguide web does not answer") from None
                time.sleep(0.1)
        yield process
    finally:
        stop(process)


@contextmanager
def web_with_and_without_config(state_dir: Path, host: str, port: int, bare_port: int) -> Iterator[None]:
    """Two ``monoguide web`` processes on ``state_dir``: on ``port`` with the simulated cell's config, on
    ``bare_port`` without a config."""
    with web_process(state_dir, host, port, "--config", str(SIM_CELL)), web_process(state_dir, host, bare_port):
        yield


def prepare_state(state_dir: Path, cycles: int = 12) -> Prepared:
    """A journal of ``cycles`` cycles by the real :class:`Journal`: good ones solved from the example record by
    the real solver, with one 5 MP image per view, a dark hole drawn at the record's pixel; every fourth a
    ``HOLE_NOT_FOUND``, of job 2 every second time (the good ones are job 1: the example record is the roof's)."""
    record = json.loads(EXAMPLE_RECORD.read_text())
    result, _ = solve_record(record)
    assert result["status"] == "ok", result
    prepared = Prepared(Path(state_dir))
    camera = record["camera"]
    with Journal(state_dir) as journal:
        for n in range(1, cycles + 1):
            job = 2 if n % 8 == 0 else 1
            started = T0 + 60.0 * n
            if n % 4 == 0:
                message = "S2, P2: no hole within 90 px" + (" <script>alert('x')</script> & <b>" if n == 4 else "")
                entry = CycleEntry(started, started + 5.0, job, n, error=HoleNotFound(message),
                                   timings_s={"robot_motion": 3.0, "cycle": 5.0})
                prepared.failed[n] = HoleNotFound.code
                if n == 4:
                    prepared.escaped = n
            else:
                paths = []
                for view, observation in enumerate(record["observations"]):
                    u, v = observation["pixel"]
                    path = journal.images_dir / f"cycle-{n}" / f"S{view + 1}.png"
                    _draw_hole(path, camera["width"], camera["height"], (u, v))
                    paths.append(str(path))
                    prepared.centres[(n, view)] = (u, v)
                if n == 2:  # a row that names a file outside the images folder: nothing may be served for it
                    paths[0] = "/etc/passwd"
                    prepared.outside = n
                entry = CycleEntry(started, started + 5.0, job, n, record={**record, "id": f"cycle-{n}"},
                                   result=result, timings_s={"robot_motion": 3.0, "solve": 0.09, "cycle": 5.0},
                                   poses_at_capture=[np.eye(4).tolist()] * 4, image_paths=paths)
                prepared.ok.append(n)
            prepared.jobs[n] = job
            journal.commit_cycle(entry)
        # cycle 1's images pruned by the age limit, as the service prunes them (cycle 1 finished at T0 + 65 s)
        report = journal.prune_images(10**12, 30.0, now=T0 + 100.0)
    assert report.cycles == 1, report
    prepared.pruned = 1
    return prepared


def _draw_hole(path: Path, width: int, height: int, *centres: tuple[float, float]) -> None:
    """A grey frame with a dark disc centred on each of ``centres`` (sub-pixel: drawn with 8 fractional bits)."""
    image = np.full((height, width), 170, np.uint8)
    shift = 8
    for centre in centres:
        cv2.circle(image, (round(centre[0] * 2**shift), round(centre[1] * 2**shift)),
                   round(HOLE_RADIUS_PX * 2**shift), 30, thickness=-1, lineType=cv2.LINE_AA, shift=shift)
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, 1])


@dataclass
class FailedCycles:
    """Failed cycles as the service journals them (each visited view's image, what was found, where each hole was
    sought, the failure) and two rows of before (the message alone): the truth their pages must show."""

    state_dir: Path
    hood: int = 0  # job 2, failed measuring at S6: H4 sought, not found
    solving: int = 0  # job 1, failed solving: a record, every view's holes found
    unexpected: int = 0  # an error monoguide did not expect, while writing
    old_hole: int = 0  # a row of before: only its message says where the hole was expected
    old_mark: int = 0  # the same for a reference mark
    ok: int = 0  # a good cycle beside them
    mismatched: int = 0  # a good cycle of the roof's record (4 holes) journaled as job 2 (the hood's 6 holes), with
    # the images of ``solving``
    found: dict[tuple[int, int], dict[int, tuple[float, float]]] = field(default_factory=dict)  # (cycle, view) ->
    expected: dict[tuple[int, int], dict[int, tuple[float, float]]] = field(default_factory=dict)  # point -> px
    missing: dict[int, tuple[int, int | None, tuple[float, float]]] = field(default_factory=dict)  # cycle -> (view,
    # point or None for a mark, px): what was not found, where it was expected
    marks: dict[tuple[int, int], tuple[str, tuple[float, float]]] = field(default_factory=dict)  # a mark found
    images: dict[tuple[int, int], Path] = field(default_factory=dict)  # (cycle, view) -> the image written


def prepare_failed_cycles(state_dir: Path, seed: int = 7) -> FailedCycles:
    """The failed cycles of :class:`FailedCycles` in a journal of the real :class:`Journal` (views 1-based), with
    seeded hole positions and images whose dark discs lie where the rows say the holes were found."""
    rng = np.random.default_rng(seed)
    record = json.loads(EXAMPLE_RECORD.read_text())
    result, _ = solve_record(record)
    width, height = record["camera"]["width"], record["camera"]["height"]
    truth = FailedCycles(Path(state_dir))

    def spot() -> tuple[float, float]:
        return (round(float(rng.uniform(200, width - 200)), 3), round(float(rng.uniform(200, height - 200)), 3))

    def near(at: tuple[float, float]) -> tuple[float, float]:  # where a found hole was sought: a few px off
        return (round(at[0] + float(rng.normal(0, 4)), 3), round(at[1] + float(rng.normal(0, 4)), 3))

    with Journal(state_dir) as journal:
        number = journal.next_number()
        views, paths = [], []
        for view, (pose, points) in enumerate((("S5", (0, 1)), ("S6", (2, 3)))):
            found = {j: spot() for j in points if (pose, j) != ("S6", 3)}
            expected = {j: near(found[j]) if j in found else spot() for j in points}
            path = journal.images_dir / f"cycle-{number}" / f"{pose}.png"
            _draw_hole(path, width, height, *found.values())
            mark = ("M1", spot()) if pose == "S5" else None
            views.append({"view": view, "pose": pose, "image": str(path.relative_to(state_dir)),
                          "T_b_f": np.eye(4).tolist(),
                          "holes": [{"point": j, "name": f"H{j + 1}", "pixel": list(p)} for j, p in found.items()],
                          "marks": [] if mark is None else [{"mark": 0, "name": mark[0], "pixel": list(mark[1])}],
                          "expected": [{"point": j, "name": f"H{j + 1}", "pixel": list(p), "radius_px": 24.0}
                                       for j, p in expected.items()]})
            paths.append(str(path))
            truth.found[(number, view + 1)], truth.expected[(number, view + 1)] = found, expected
            truth.images[(number, view + 1)] = path
            if mark is not None:
                truth.marks[(number, view + 1)] = mark
        lost = truth.expected[(number, 2)][3]
        truth.missing[number] = (2, 3, lost)
        failure = {"stage": "measuring", "exception": "HoleNotFound", "unexpected": False, "view": "S6", "point": "H4",
                   "expected_px": list(lost)}
        message = f"S6, H4: hole expected at ({lost[0]:.1f}, {lost[1]:.1f}) r=24.0 px: no hole within 72 px"
        truth.hood = _commit(journal, 2, HoleNotFound(message), {"status": "error", "failure": failure, "views": views},
                             image_paths=paths)

        number = journal.next_number()
        views, paths = [], []
        for view, observation in enumerate(record["observations"]):
            u, v = observation["pixel"]
            path = journal.images_dir / f"cycle-{number}" / f"S{view + 1}.png"
            _draw_hole(path, width, height, (u, v))
            paths.append(str(path))
            truth.found[(number, view + 1)] = {observation["point"]: (u, v)}
            truth.images[(number, view + 1)] = path
            views.append({"view": view, "pose": f"S{view + 1}", "image": str(path.relative_to(state_dir)),
                          "T_b_f": None, "holes": [{"point": observation["point"], "name": f"P{view + 1}",
                                                    "pixel": [u, v]}], "marks": [], "expected": []})
        failure = {"stage": "solving", "exception": "InconsistentMeasurement", "unexpected": False, "view": None,
                   "point": None, "expected_px": None}
        roof_paths = paths
        truth.solving = _commit(journal, 1, InconsistentMeasurement("chi-square 93.1 > 13.8 with 2 dof"),
                                {"status": "error", "failure": failure, "views": views}, record=record,
                                image_paths=paths)
        failure = {"stage": "writing", "exception": "KeyError", "unexpected": True, "view": None, "point": None,
                   "expected_px": None}
        truth.unexpected = _commit(journal, 1, CycleError("unexpected KeyError: 'registers'"),
                                   {"status": "error", "failure": failure, "views": []})
        hole = spot()
        truth.old_hole = _commit(journal, 1, HoleNotFound(
            f"S2, P2: hole expected at ({hole[0]:.1f}, {hole[1]:.1f}) r=14.2 px: no hole within 43 px and 25 % of the "
            "radius; nothing dark of that size in the search region"))
        truth.missing[truth.old_hole] = (2, 1, (round(hole[0], 1), round(hole[1], 1)))
        mark = (round(spot()[0]), round(spot()[1]))
        truth.old_mark = _commit(journal, 1, MarkNotFound(
            f"S3, mark M2: not found within 40 px of where the calibration puts it ({mark[0]:.0f}, {mark[1]:.0f}) px: "
            "HOLE_NOT_FOUND: no hole (the finder's px are of its window at (0, 0)); is something hiding it?"))
        truth.missing[truth.old_mark] = (3, None, (float(mark[0]), float(mark[1])))
        truth.ok = _commit(journal, 1, None, result, record=record)
        truth.mismatched = _commit(journal, 2, None, result, record=record, image_paths=roof_paths)
    return truth


def _commit(journal: Journal, job: int, error: MonoguideError | None, result: dict[str, Any] | None = None,
            record: dict[str, Any] | None = None, image_paths: list[str] | None = None) -> int:
    number = journal.next_number()
    started = T0 + 60.0 * number
    journal.commit_cycle(CycleEntry(started, started + 4.0, job, number, record=record, result=result, error=error,
                                    timings_s={"cycle": 4.0}, image_paths=image_paths or []))
    return number


def journal_json(answer: Answer) -> Any:
    return json.loads(answer.body)
