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

from helpers.repository import EXAMPLE_RECORD
from helpers.sim_processes import stop
from monoguide.daemon.service import CycleEntry, Journal
from monoguide.solver.errors import HoleNotFound
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


def _draw_hole(path: Path, width: int, height: int, centre: tuple[float, float]) -> None:
    """A grey frame with a dark disc centred on ``centre`` (sub-pixel: drawn with 8 fractional bits)."""
    image = np.full((height, width), 170, np.uint8)
    shift = 8
    cv2.circle(image, (round(centre[0] * 2**shift), round(centre[1] * 2**shift)), round(HOLE_RADIUS_PX * 2**shift),
               30, thickness=-1, lineType=cv2.LINE_AA, shift=shift)
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, 1])


def journal_json(answer: Answer) -> Any:
    return json.loads(answer.body)
