"""The Prometheus metrics of ``monoguide plant`` (docs/metrics.md), in a registry of their own that
``_metrics_http`` serves on their own port (``[plant] metrics_host``, loopback unless configured otherwise).

Every metric has one unit, Prometheus' base unit, in its name (``_metres``, ``_radians``, ``_seconds``, ``_bytes``;
``_pixels`` where there is none): the base offset is two metrics, its translation in metres and its rotation in
radians. No ``_created`` series (prometheus_client's are switched off). The cycle counters start from the journal's
totals when the plant starts (one count by outcome) and count on with every cycle it reads, so that they equal the
journal's; the histograms observe the cycles finished while it runs.
"""

from __future__ import annotations

import math
import time
from collections import Counter as Tally

from prometheus_client import (
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    ProcessCollector,
    disable_created_metrics,
)

from monoguide.daemon.plant._cell_view import CellReading, health_level
from monoguide.daemon.plant._results import OFFSET_AXES, CycleResult
from monoguide.daemon.service import STATUS_FILE

CYCLE_BUCKETS_S = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 7.5, 10.0, 15.0, 30.0, 60.0)
OVERHEAD_BUCKETS_S = (0.01, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 1.0, 2.0, 5.0)
NO_ERROR = "none"  # the error_code label of a good cycle
STATES = ("not running", "starting", "idle", "measuring", "solving", "checking", "writing", "reporting",
          "awaiting_ack", "fault", "stopped")


TRANSLATION_AXES, ROTATION_AXES = OFFSET_AXES[:3], OFFSET_AXES[3:]  # x y z (mm in the journal), a b c (deg)
MM, DEG = 1e-3, math.pi / 180.0


class PlantMetrics:
    def __init__(self, calibration_date: float | None) -> None:
        disable_created_metrics()  # a *_created series per counter and histogram says nothing the plant knows
        self.registry = r = CollectorRegistry(auto_describe=True)
        ProcessCollector(registry=r)  # process_resident_memory_bytes & co. of the plant itself
        self.cycles = Counter("monoguide_cycles", "Finished cycles by status and error code (the journal's rows).",
                              ["status", "error_code"], registry=r)
        self.cycle_time = Histogram("monoguide_cycle_seconds", "Trigger to DONE of each cycle.",
                                    buckets=CYCLE_BUCKETS_S, registry=r)
        self.overhead = Histogram("monoguide_cycle_overhead_seconds",
                                  "The last frame in hand to the offset acknowledged by the robot (good cycles).",
                                  buckets=OVERHEAD_BUCKETS_S, registry=r)
        self.translation = Gauge("monoguide_base_offset_translation", "The last good cycle's base offset: x, y, z.",
                                 ["axis"], unit="metres", registry=r)
        self.rotation = Gauge("monoguide_base_offset_rotation",
                              "The last good cycle's base offset: A, B, C (KUKA Z-Y'-X'').", ["axis"], unit="radians",
                              registry=r)
        self.rms = Gauge("monoguide_reprojection_rms", "The last solved cycle's reprojection RMS.", unit="pixels",
                         registry=r)
        self.sigma_position = Gauge("monoguide_sigma_position", "The last solved cycle's predicted sigma at the grasp "
                                    "point.", unit="metres", registry=r)
        self.sigma_rotation = Gauge("monoguide_sigma_rotation", "The last solved cycle's predicted sigma of the "
                                    "rotation.", unit="radians", registry=r)
        self.last_cycle = Gauge("monoguide_last_cycle", "The number of the last finished cycle.", registry=r)
        self.last_cycle_time = Gauge("monoguide_last_cycle_timestamp_seconds",
                                     "When the last cycle was committed (Unix s).", registry=r)
        self.running = Gauge("monoguide_service_running", f"1 while the service runs ({STATUS_FILE} fresh).",
                             registry=r)
        self.state = Gauge("monoguide_service_state", "1 for the service's current state, 0 for the others.",
                           ["state"], registry=r)
        self.devices = Gauge("monoguide_device_connected", "1 while the service holds the device's connection.",
                             ["device"], registry=r)
        self.journal_bytes = Gauge("monoguide_journal_bytes", "The journal's size on disk (with its WAL).",
                                   registry=r)
        self.disk_free = Gauge("monoguide_journal_filesystem_avail_bytes", "Free space of the journal's file system "
                               "(to the service's user).", registry=r)
        self.disk_size = Gauge("monoguide_journal_filesystem_size_bytes", "Size of the journal's file system.",
                               registry=r)
        self.journal_cycles = Gauge("monoguide_journal_cycle_counter", "The journal's cycle counter.", registry=r)
        self.calibration_age = Gauge("monoguide_calibration_age_seconds",
                                     "Since [calibration] date of the cell config (NaN: no date).", registry=r)
        self.health = Gauge("monoguide_calibration_health_level",
                            "The calibration's health: 0 ok, 1 warning, 2 alarm latched (NaN: no service running).",
                            registry=r)
        self.refusals = Counter("monoguide_plant_refusals", "What the plant's interfaces refused, by interface "
                                "(opcua, metrics) and reason (docs/opcua.md, docs/metrics.md).",
                                ["interface", "reason"], registry=r)
        self.calibration_date = calibration_date
        for axis in TRANSLATION_AXES:
            self.translation.labels(axis=axis).set(math.nan)
        for axis in ROTATION_AXES:
            self.rotation.labels(axis=axis).set(math.nan)
        for gauge in (self.rms, self.sigma_position, self.sigma_rotation, self.health):
            gauge.set(math.nan)
        self._refused: Tally[tuple[str, str]] = Tally()

    def seed(self, counts: dict[tuple[str, str | None], int], newest_first: list[CycleResult], counter: int) -> None:
        """The journal's totals and cycle counter at start, and the gauges of its newest cycles (a scrape before the
        first poll already shows the journal as it is)."""
        self.journal_cycles.set(counter)
        for (status, code), n in counts.items():
            self.cycles.labels(status=status, error_code=code or NO_ERROR).inc(n)
        for result in reversed(newest_first):
            self._gauges(result)

    def show(self, reading: CellReading) -> None:
        for result in reading.results:
            self.cycles.labels(status=result.status, error_code=result.error_code or NO_ERROR).inc()
            if result.cycle_s is not None:
                self.cycle_time.observe(result.cycle_s)
            if result.ok and result.overhead_s is not None:
                self.overhead.observe(result.overhead_s)
            self._gauges(result)
        status = reading.status
        self.running.set(1 if reading.running else 0)
        current = status.state if status and reading.running else "not running"
        for state in STATES:
            self.state.labels(state=state).set(1 if state == current else 0)
        for name, device in (status.devices if status else {}).items():
            self.devices.labels(device=name).set(1 if device.connected and reading.running else 0)
        self.journal_bytes.set(reading.journal_bytes)
        self.disk_free.set(math.nan if reading.disk_free_bytes is None else reading.disk_free_bytes)
        self.disk_size.set(math.nan if reading.disk_size_bytes is None else reading.disk_size_bytes)
        if reading.counter is not None:
            self.journal_cycles.set(reading.counter)
        date = self.calibration_date
        self.calibration_age.set(math.nan if date is None else time.time() - date)
        level = health_level(reading)
        self.health.set(math.nan if level is None else level)

    def count_refusals(self, total: Tally[tuple[str, str]]) -> None:
        """Bring the refusal counters to ``total`` (``Refusals.total``: every refusal since the start)."""
        for key, n in total.items():
            if n > self._refused[key]:
                self.refusals.labels(interface=key[0], reason=key[1]).inc(n - self._refused[key])
                self._refused[key] = n

    def _gauges(self, result: CycleResult) -> None:
        self.last_cycle.set(result.cycle)
        self.last_cycle_time.set(result.committed_at)
        if result.base_offset is not None:
            for axis, value in zip(TRANSLATION_AXES, result.base_offset[:3], strict=True):
                self.translation.labels(axis=axis).set(value * MM)
            for axis, value in zip(ROTATION_AXES, result.base_offset[3:], strict=True):
                self.rotation.labels(axis=axis).set(value * DEG)
        for gauge, value, scale in ((self.rms, result.rms_px, 1.0), (self.sigma_position, result.sigma_mm, MM),
                                    (self.sigma_rotation, result.sigma_deg, DEG)):
            if value is not None:
                gauge.set(value * scale)
