"""Every grab returns a frame exposed after the request (issue 7, item 9), and no library exception leaves
the camera untyped (item 10).

``viky.cti`` cannot deliver a late trigger answer, an early frame or a frame in flight on demand (it has
no trigger and no timestamps), so :class:`GenTLTimeline` plays a GenTL stream on the wall clock with the
part of harvesters' ``ImageAcquirer`` the driver uses. Each shot records when its exposure started: that
is the ground truth a returned frame is checked against. The real producer is tested in
``test_genicam_camera.py``.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from genicam import genapi, gentl

from monoguide.drivers.camera import CameraIdentity
from monoguide.drivers.errors import (
    DeviceDisconnected,
    DeviceProtocolError,
    DeviceRequestInvalid,
    DeviceSettingRejected,
    DeviceTimeout,
)
from monoguide.drivers.genicam_camera import GenICamCamera
from monoguide.drivers.genicam_frames import FreshFrames
from monoguide.drivers.genicam_nodes import set_number

WIDTH, HEIGHT = 8, 6


@dataclass
class Shot:
    frame_id: int
    exposure_start: float  # time.monotonic()
    deliver_at: float


class _Buffer:
    def __init__(self, shot: Shot, with_ids: bool) -> None:
        self._shot = shot
        self._with_ids = with_ids
        image = np.full(WIDTH * HEIGHT, shot.frame_id % 256, dtype=np.uint8)
        component = type("Component", (), {"data_format": "Mono8", "width": WIDTH, "height": HEIGHT, "data": image})
        self.payload = type("Payload", (), {"components": [component]})
        self.queued = False

    @property
    def module(self) -> Any:
        if not self._with_ids:
            return type("Module", (), {"frame_id": property(_not_available)})()
        return type("Module", (), {"frame_id": self._shot.frame_id})()

    def queue(self) -> None:
        self.queued = True

    def __enter__(self) -> _Buffer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.queue()


def _not_available(_self: object) -> int:
    raise gentl.NotAvailableException("frame id not available")


class GenTLTimeline:
    """A GenTL stream on the wall clock. Free-running (``period_s``): shot k starts exposing at
    ``t0 + k * period_s``. Triggered (``period_s=None``): :meth:`trigger` starts a shot ``latency_s`` later.
    A shot is delivered ``exposure_s + transfer_s`` after its start (plus ``late_s[k]`` for trigger k), in
    order, like a real stream. :meth:`stop` discards the queue, as a producer does."""

    def __init__(self, period_s: float | None = None, exposure_s: float = 0.02, transfer_s: float = 0.01,
                 with_ids: bool = True, latency_s: float = 0.002) -> None:
        self.period_s, self.exposure_s, self.transfer_s = period_s, exposure_s, transfer_s
        self.with_ids, self.latency_s = with_ids, latency_s
        self.late_s: dict[int, float] = {}
        self.lost: set[int] = set()  # triggers whose shot never arrives
        self.shots: dict[int, Shot] = {}
        self.stops = 0
        self.inside = 0
        self.max_inside = 0
        self._acquiring = False
        self._queue: list[Shot] = []
        self._next_id = 1
        self._triggers = 0
        self._t0 = 0.0
        self._generated = 0

    # the ImageAcquirer part
    def is_acquiring(self) -> bool:
        return self._acquiring

    def start(self) -> None:
        self._acquiring, self._t0, self._generated, self._next_id = True, time.monotonic(), 0, 1
        self._queue.clear()

    def stop(self) -> None:
        self._acquiring = False
        self._queue.clear()
        self.stops += 1

    def destroy(self) -> None:
        self._acquiring = False

    def try_fetch(self, *, timeout: float) -> _Buffer | None:
        self.inside += 1
        self.max_inside = max(self.max_inside, self.inside)
        try:
            end = time.monotonic() + timeout
            self._generate(end)
            if self._queue and self._queue[0].deliver_at <= end:
                shot = self._queue.pop(0)
                time.sleep(max(0.0, shot.deliver_at - time.monotonic()))
                return _Buffer(shot, self.with_ids)
            time.sleep(max(0.0, end - time.monotonic()))
            return None
        finally:
            self.inside -= 1

    # the camera's side
    def trigger(self) -> None:
        self._triggers += 1
        if self._triggers in self.lost:
            return
        start = time.monotonic() + self.latency_s
        self._add(start, self.late_s.get(self._triggers, 0.0))

    def deliver_stale(self, count: int) -> None:
        """``count`` frames exposed earlier (a double trigger at the previous pose) already in the queue."""
        now = time.monotonic()
        for _ in range(count):
            shot = self._add(now - 0.5, 0.0)
            shot.deliver_at = now

    def exposure_start_of(self, image: np.ndarray) -> float:
        return next(s.exposure_start for s in self.shots.values() if s.frame_id % 256 == int(image[0, 0]))

    def _generate(self, until: float) -> None:
        if self.period_s is None or not self._acquiring:
            return
        while self._t0 + self._generated * self.period_s + self.exposure_s + self.transfer_s <= until:
            self._add(self._t0 + self._generated * self.period_s, 0.0)
            self._generated += 1

    def _add(self, start: float, extra_s: float) -> Shot:
        deliver = start + self.exposure_s + self.transfer_s + extra_s
        if self._queue:
            deliver = max(deliver, self._queue[-1].deliver_at)  # a stream delivers in order
        shot = Shot(self._next_id, start, deliver)
        self._next_id += 1
        self.shots[shot.frame_id] = shot
        self._queue.append(shot)
        return shot


def _triggered(**kwargs: Any) -> tuple[GenTLTimeline, FreshFrames]:
    source = GenTLTimeline(**kwargs)
    return source, FreshFrames(source, "camera T1", trigger=source.trigger)


# --- software trigger -------------------------------------------------------------------------------


def test_a_late_answer_to_a_timed_out_trigger_is_never_this_grabs_frame() -> None:
    source, frames = _triggered()
    source.late_s[1] = 0.5  # the first trigger's frame comes 0.5 s late
    with pytest.raises(DeviceTimeout, match=r"0\.2 s"):
        frames.grab(0.2)
    requested = time.monotonic()
    frame = frames.grab(2.0)  # the late frame arrives while this grab waits
    assert frame.frame_id == 2 and frame.dropped == 1
    assert source.shots[2].exposure_start >= requested > source.shots[1].exposure_start
    assert int(frame.image[0, 0]) == 2  # the image is the frame the id names
    frame = frames.grab(1.0)  # and the exchange is in step again
    assert frame.frame_id == 3 and frame.dropped == 0


def test_late_answers_are_recognised_by_count_where_the_producer_has_no_frame_ids() -> None:
    source, frames = _triggered(with_ids=False)
    source.late_s[1] = 0.5
    with pytest.raises(DeviceTimeout):
        frames.grab(0.2)
    requested = time.monotonic()
    frame = frames.grab(2.0)
    assert frame.frame_id is None
    assert source.exposure_start_of(frame.image) >= requested


def test_frames_queued_before_the_request_are_flushed() -> None:
    source, frames = _triggered()
    frames.grab(1.0)
    source.deliver_stale(2)  # frames of the previous pose wait in the queue
    requested = time.monotonic()
    frame = frames.grab(1.0)
    assert frame.dropped == 2 and source.exposure_start_of(frame.image) >= requested


def test_a_lost_trigger_costs_a_grab_and_never_gives_a_wrong_frame() -> None:
    source, frames = _triggered()
    source.lost.add(1)  # the first trigger's frame never comes; the second's must not be taken for it
    with pytest.raises(DeviceTimeout):
        frames.grab(0.2)
    with pytest.raises(DeviceTimeout):
        frames.grab(0.3)  # its frame is counted as the lost one's late answer: refused, then re-armed
    assert source.stops == 1
    requested = time.monotonic()
    frame = frames.grab(1.0)
    assert source.exposure_start_of(frame.image) >= requested


# --- free-running -----------------------------------------------------------------------------------


@pytest.mark.parametrize("with_ids", [True, False])
@pytest.mark.parametrize(("exposure_s", "transfer_s", "in_flight"), [
    (0.03, 0.01, 2),  # one frame in flight at most: the default is on the safe side
    (0.03, 0.04, 2),  # readout overlaps the next exposure: two in flight, the default
    (0.03, 0.06, 3),  # a slow link: up to ceil(0.09 / 0.04) = 3 in flight, configured
])
def test_free_running_frames_in_flight_at_the_request_are_skipped(with_ids: bool, exposure_s: float,
                                                                   transfer_s: float, in_flight: int) -> None:
    source = GenTLTimeline(period_s=0.04, exposure_s=exposure_s, transfer_s=transfer_s, with_ids=with_ids)
    frames = FreshFrames(source, "camera T1", in_flight=in_flight)
    frames.grab(1.0)
    rng = np.random.default_rng(5)
    for _ in range(12):
        time.sleep(float(rng.uniform(0.0, 0.08)))  # the robot moves; frames pile up and fly
        requested = time.monotonic()
        frame = frames.grab(1.0)
        assert source.exposure_start_of(frame.image) >= requested, "a frame exposed before the request"
        assert frame.requested_time_s <= frame.received_time_s


def test_the_old_way_returns_frames_exposed_before_the_request() -> None:
    """The same stream read the pre-issue-7 way (drop the queue, take the next frame): the check above
    would have caught it."""
    source = GenTLTimeline(period_s=0.04, exposure_s=0.03, transfer_s=0.01)
    source.start()
    stale = 0
    for k in range(12):
        time.sleep(0.013 * (k % 4))
        requested = time.monotonic()
        while (b := source.try_fetch(timeout=0.0001)) is not None:
            b.queue()
        buffer = source.try_fetch(timeout=1.0)
        assert buffer is not None
        stale += source.shots[buffer.module.frame_id].exposure_start < requested
    assert stale > 0


# --- the camera driver on the timeline: one lock, typed errors --------------------------------------


class CameraOnTimeline(GenICamCamera):
    def __init__(self, source: GenTLTimeline) -> None:
        super().__init__("timeline.cti", serial="T1")
        self.source = source

    def _connect(self) -> tuple[Any, CameraIdentity]:
        return self.source, CameraIdentity("test", "Timeline", "T1")


def test_grabs_from_threads_hold_the_camera_lock_and_each_gets_its_own_fresh_frame() -> None:
    source = GenTLTimeline(period_s=0.01, exposure_s=0.005, transfer_s=0.005)
    camera = CameraOnTimeline(source)
    camera.open()
    got: list[tuple[int, float, float]] = []
    errors: list[str] = []

    def grab() -> None:
        for _ in range(5):
            try:
                requested = time.monotonic()
                frame = camera.grab(2.0)
                got.append((frame.frame_number, requested, source.exposure_start_of(frame.image)))
            except Exception as exc:
                errors.append(repr(exc))

    threads = [threading.Thread(target=grab) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    camera.close()
    assert not errors, errors
    assert source.max_inside == 1, "two threads were inside the stream at once"
    assert sorted(n for n, _, _ in got) == list(range(1, 21))
    assert all(start >= requested for _, requested, start in got)


def test_stream_failures_leave_the_driver_typed() -> None:
    source = GenTLTimeline(period_s=None)
    camera = CameraOnTimeline(source)
    camera.open()
    source.trigger = _raise(gentl.IoException("link down"))  # type: ignore[method-assign]
    camera._frames_source = FreshFrames(source, "camera T1", trigger=source.trigger)
    with pytest.raises(DeviceDisconnected, match="link down"):
        camera.grab(0.5)
    camera._frames_source = FreshFrames(source, "camera T1", trigger=_raise(genapi.LogicalErrorException("bad")))
    with pytest.raises(DeviceProtocolError, match="LogicalErrorException"):
        camera.grab(0.5)
    camera._frames_source = FreshFrames(source, "camera T1", trigger=_raise(KeyError("surprise")))
    with pytest.raises(Exception) as info:
        camera.grab(0.5)
    assert info.value.code == "DEVICE_ERROR"  # type: ignore[attr-defined]


def _raise(exc: Exception) -> Any:
    def fire() -> None:
        raise exc

    return fire


# --- integer nodes and their increment --------------------------------------------------------------


class _IntegerNode:
    """A Width node of a camera that steps by 4 (viky steps by 1, so this one cannot be made with it)."""

    def __init__(self) -> None:
        self.min, self.max, self.inc, self.value = 16, 2448, 4, 640


class _Nodes:
    def __init__(self, **nodes: Any) -> None:
        self._nodes = nodes

    def has_node(self, name: str) -> bool:
        return name in self._nodes

    def get_node(self, name: str) -> Any:
        return self._nodes[name]


@pytest.mark.parametrize(("value", "message"), [(641, "steps by 4 from 16; nearest valid: 640 or 644"),
                                                (2449, r"outside \[16, 2448\]"), (640.5, "whole numbers"),
                                                (float("nan"), "whole numbers"), (True, "whole numbers")])
def test_an_integer_off_the_cameras_increment_is_refused_with_the_valid_neighbours(value: float,
                                                                                    message: str) -> None:
    width = _IntegerNode()
    with pytest.raises(DeviceSettingRejected, match=message):
        set_number(_Nodes(Width=width), "camera T1", "Width", value, required=True)
    assert width.value == 640  # nothing was written


def test_an_integer_on_the_increment_is_written() -> None:
    width = _IntegerNode()
    assert set_number(_Nodes(Width=width), "camera T1", "Width", 644, required=True)
    assert width.value == 644 and isinstance(width.value, int)


@pytest.mark.parametrize("timeout_s", [0.0, -1.0, float("nan"), float("inf")])
def test_a_grab_timeout_that_is_not_a_positive_number_is_refused(timeout_s: float) -> None:
    camera = CameraOnTimeline(GenTLTimeline(period_s=0.01))
    camera.open()
    with pytest.raises(DeviceRequestInvalid, match="grab timeout"):
        camera.grab(timeout_s)


@pytest.mark.parametrize("in_flight", [0, -1, 1.5])
def test_frames_in_flight_must_be_a_whole_number_of_at_least_one(in_flight: float) -> None:
    with pytest.raises(DeviceSettingRejected, match="in_flight_frames"):
        FreshFrames(GenTLTimeline(period_s=0.01), "camera T1", in_flight=in_flight)  # type: ignore[arg-type]
