"""The serial tracker adapter against the simulated tracker process, over a real pseudo-terminal."""

from __future__ import annotations

import logging
import re
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import serial
from helpers.sim_processes import start_sim_tracker

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.errors import (
    DeviceBusy,
    DeviceDisconnected,
    DeviceFault,
    DeviceNotFound,
    DeviceProtocolError,
    DeviceRequestInvalid,
    DeviceTimeout,
)
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.tracker import LaserTracker, SerialLaserTracker, SerialLineChannel

SIM_CELL = Path(__file__).parents[2] / "config" / "sim-cell.toml"
NOISE_3D_MM = 0.025


@dataclass
class SimTracker:
    port: str
    process: subprocess.Popen[str]
    cell: SimCell
    targets_file: Path


def stop(process: subprocess.Popen[str]) -> None:
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(5)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5)
    if process.stdout is not None:
        process.stdout.close()


@pytest.fixture
def sim_tracker(tmp_path: Path) -> Iterator[SimTracker]:
    cell = build_sim_cell(load_cell_config(SIM_CELL))
    targets = cell.write_tracker_targets(tmp_path / "targets.json", beam_on="B1")
    process, port = start_sim_tracker(targets)
    try:
        yield SimTracker(port, process, cell, targets)
    finally:
        stop(process)


@pytest.fixture
def tracker(sim_tracker: SimTracker) -> Iterator[SerialLaserTracker]:
    t = SerialLaserTracker(sim_tracker.port, timeout_s=1.0)
    t.open()
    try:
        yield t
    finally:
        t.close()


def inject(port: str, *words: str) -> None:
    """Send the simulator-only ``SIM:FAULT`` request on its own connection and wait for the answer."""
    with serial.Serial(port, 115200, timeout=2.0) as raw:
        raw.write(f"999 SIM:FAULT {' '.join(words)}\n".encode())
        assert raw.readline().startswith(b"999 OK"), "simulator did not accept the fault"


def test_identity_and_port_protocol(tracker: SerialLaserTracker) -> None:
    assert isinstance(tracker, LaserTracker)
    assert tracker.identity is not None and tracker.identity.model == "SimTracker"


def test_measured_points_match_the_truth_within_tracker_noise(sim_tracker: SimTracker,
                                                              tracker: SerialLaserTracker) -> None:
    truth = sim_tracker.cell.tracker_targets()
    for nest in ("B1", "B2", "B3", "T1.3", "P2", "TCP"):
        m = tracker.measure_point(nest)
        assert np.linalg.norm(m.point_mm - truth[nest]) < 6 * NOISE_3D_MM, nest
        assert 0 < m.rms_mm < 0.5
    # tracker frame -> cell frame gives the cell's own benchmark coordinates back
    m = tracker.measure_point("B2")
    T = sim_tracker.cell.spec.T_cf_tracker
    np.testing.assert_allclose(T[:3, :3] @ m.point_mm + T[:3, 3], [1500.0, 0.0, 0.0], atol=6 * NOISE_3D_MM)


def test_noise_has_the_tracker_spec(tracker: SerialLaserTracker, sim_tracker: SimTracker) -> None:
    truth = sim_tracker.cell.tracker_targets()["B3"]
    errors = np.array([tracker.measure_point("B3").point_mm - truth for _ in range(60)])
    rms_3d = float(np.sqrt(np.mean(np.sum(errors**2, axis=1))))
    assert 0.6 * NOISE_3D_MM < rms_3d < 1.5 * NOISE_3D_MM
    numbers = [tracker.measure_point().measurement_number for _ in range(3)]
    assert numbers == sorted(numbers) and len(set(numbers)) == 3


def test_the_truth_moves_with_the_cell(sim_tracker: SimTracker, tracker: SerialLaserTracker) -> None:
    before = tracker.measure_point("P1").point_mm
    sim_tracker.cell.new_part()
    sim_tracker.cell.write_tracker_targets(sim_tracker.targets_file)
    time.sleep(0.5)  # the simulator polls its targets file
    after = tracker.measure_point("P1").point_mm
    expected = sim_tracker.cell.tracker_targets()["P1"]
    assert np.linalg.norm(after - expected) < 6 * NOISE_3D_MM
    assert np.linalg.norm(after - before) > 1.0


def test_no_reply_is_a_timeout(sim_tracker: SimTracker, tracker: SerialLaserTracker) -> None:
    inject(sim_tracker.port, "NOREPLY", "1")
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match="MEAS:POINT"):
        tracker.measure_point("B1", timeout_s=0.3)
    assert time.monotonic() - t0 < 1.0
    assert tracker.measure_point("B1").measurement_number >= 1  # and it recovers


def test_garbage_is_a_protocol_error(sim_tracker: SimTracker, tracker: SerialLaserTracker) -> None:
    inject(sim_tracker.port, "GARBAGE", "1")
    with pytest.raises(DeviceProtocolError):
        tracker.measure_point("B1")


def test_broken_beam_is_a_device_fault_with_its_code(sim_tracker: SimTracker, tracker: SerialLaserTracker) -> None:
    inject(sim_tracker.port, "BEAM", "1")
    with pytest.raises(DeviceFault, match="E200"):
        tracker.measure_point("B1")


def test_unknown_nest_is_a_device_fault(tracker: SerialLaserTracker) -> None:
    with pytest.raises(DeviceFault, match="E201"):
        tracker.measure_point("NOWHERE")


def test_a_late_reply_is_never_taken_for_the_next_answer(sim_tracker: SimTracker, tracker: SerialLaserTracker,
                                                          caplog: pytest.LogCaptureFixture) -> None:
    inject(sim_tracker.port, "LATE", "1", "0.6")
    with pytest.raises(DeviceTimeout):
        tracker.measure_point("B1", timeout_s=0.3)
    time.sleep(0.5)  # the late B1 answer arrives while nobody waits
    with caplog.at_level(logging.WARNING, logger="monoguide.drivers.tracker"):
        m = tracker.measure_point("B2")
    truth = sim_tracker.cell.tracker_targets()
    assert np.linalg.norm(m.point_mm - truth["B2"]) < 6 * NOISE_3D_MM  # B2, not the stale B1
    assert np.linalg.norm(truth["B2"] - truth["B1"]) > 100.0  # so taking B1 would have failed above
    assert len(_dropped(caplog)) == 1, "the late B1 reply must have arrived and been dropped"


def test_a_late_reply_arriving_during_the_next_wait_is_dropped(sim_tracker: SimTracker, tracker: SerialLaserTracker,
                                                               caplog: pytest.LogCaptureFixture) -> None:
    # both requests are answered 0.6 s late: the stale B1 reply lands while the client waits for B3's
    inject(sim_tracker.port, "LATE", "2", "0.6")
    with pytest.raises(DeviceTimeout):
        tracker.measure_point("B1", timeout_s=0.3)
    with caplog.at_level(logging.WARNING, logger="monoguide.drivers.tracker"):
        t0 = time.monotonic()
        m = tracker.measure_point("B3", timeout_s=2.0)
        waited = time.monotonic() - t0
    truth = sim_tracker.cell.tracker_targets()
    assert np.linalg.norm(m.point_mm - truth["B3"]) < 6 * NOISE_3D_MM
    assert 0.45 < waited < 1.5  # it waited past the stale reply (due ~0.3 s in) for its own (~0.6 s)
    assert len(_dropped(caplog)) == 1
    assert tracker.measure_point("B2").nest == "B2"  # and the exchange is in step again


def test_a_client_that_stops_reading_does_not_hang_the_simulator(sim_tracker: SimTracker) -> None:
    with serial.Serial(sim_tracker.port, 115200, timeout=0.1, write_timeout=5.0) as raw:
        for k in range(1, 3001):  # ~120 kB of replies, far more than the pty buffers
            raw.write(f"{k} *IDN?\n".encode())
        time.sleep(0.5)
        sim_tracker.process.terminate()
        assert sim_tracker.process.wait(3) == 0, "the simulator did not stop on SIGTERM"


def test_simulator_gone_is_a_disconnect(sim_tracker: SimTracker, tracker: SerialLaserTracker) -> None:
    stop(sim_tracker.process)
    with pytest.raises((DeviceDisconnected, DeviceTimeout)) as info:
        tracker.measure_point("B1", timeout_s=1.0)
    assert isinstance(info.value, DeviceDisconnected), info.value


def test_absent_port_is_not_found(tmp_path: Path) -> None:
    with pytest.raises(DeviceNotFound, match="no-such-tty"):
        SerialLaserTracker(str(tmp_path / "no-such-tty")).open()


def _dropped(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if "dropping late reply" in r.getMessage()]


# --- one client per port, one exchange at a time, every wait bounded (issue 7, item 10) -----------------


def test_a_second_client_on_the_same_port_is_refused_as_busy(sim_tracker: SimTracker,
                                                               tracker: SerialLaserTracker) -> None:
    second = SerialLaserTracker(sim_tracker.port, timeout_s=1.0)
    with pytest.raises(DeviceBusy, match=re.escape(sim_tracker.port)) as info:
        second.open()
    assert info.value.code == "DEVICE_BUSY"
    # the first client's exchange is untouched: its replies are neither stolen nor garbled
    truth = sim_tracker.cell.tracker_targets()
    for nest in ("B1", "B2"):
        assert np.linalg.norm(tracker.measure_point(nest).point_mm - truth[nest]) < 6 * NOISE_3D_MM
    tracker.close()
    second.open()  # once the first client let go, the port is free
    second.close()


@pytest.mark.parametrize("nest", ["B 1", "", "Bä", "B1\n2 *IDN?"])
def test_a_nest_name_the_protocol_cannot_carry_is_a_typed_error(tracker: SerialLaserTracker, nest: str) -> None:
    with pytest.raises(DeviceRequestInvalid, match=re.escape(repr(nest))):
        tracker.measure_point(nest)
    assert tracker.measure_point("B1").nest == "B1"  # nothing was sent: the exchange stays in step


@pytest.mark.parametrize("timeout_s", [0.0, -1.0, float("nan")])
def test_a_timeout_that_is_not_a_positive_number_is_refused(tracker: SerialLaserTracker, timeout_s: float) -> None:
    with pytest.raises(DeviceRequestInvalid, match="timeout"):
        tracker.measure_point("B1", timeout_s=timeout_s)


def test_calls_from_threads_do_not_interleave(sim_tracker: SimTracker, tracker: SerialLaserTracker) -> None:
    truth = sim_tracker.cell.tracker_targets()
    nests = ("B1", "B2", "B3", "P1")
    errors: list[str] = []

    def measure(nest: str) -> None:
        for _ in range(8):
            try:
                m = tracker.measure_point(nest)
            except Exception as exc:
                errors.append(f"{nest}: {exc!r}")
                return
            if m.nest != nest or np.linalg.norm(m.point_mm - truth[nest]) > 6 * NOISE_3D_MM:
                errors.append(f"{nest}: got {m.point_mm} (another thread's reply?)")

    threads = [threading.Thread(target=measure, args=(n,)) for n in nests]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert not errors, errors


class _OutputNeverDrains:
    """A serial port whose output queue never empties (hardware flow control held off by the far end).
    A pty always drains at once, so this cannot be made with a real port here."""

    def __init__(self) -> None:
        self.write_timeout: float | None = None
        self.written = b""
        self.reset = False

    def write(self, data: bytes) -> int:
        self.written += data
        return len(data)

    @property
    def out_waiting(self) -> int:
        return 0 if self.reset else len(self.written)

    def reset_output_buffer(self) -> None:
        self.reset = True


def test_a_line_that_never_leaves_the_port_times_out_at_the_deadline() -> None:
    port = _OutputNeverDrains()
    channel = SerialLineChannel(port, "tracker on fake")  # type: ignore[arg-type]
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match="did not leave the output buffer"):
        channel.write_line(b"1 *IDN?\n", t0 + 0.3)
    assert 0.25 < time.monotonic() - t0 < 1.0 and port.reset  # bounded, and the stuck line was discarded
