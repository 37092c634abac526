"""The serial tracker adapter against the simulated tracker process, over a real pseudo-terminal."""

from __future__ import annotations

import logging
import select
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import serial

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.errors import DeviceDisconnected, DeviceFault, DeviceNotFound, DeviceProtocolError, DeviceTimeout
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.tracker import LaserTracker, SerialLaserTracker

SIM_CELL = Path(__file__).parents[2] / "config" / "sim-cell.toml"
NOISE_3D_MM = 0.025


@dataclass
class SimTracker:
    port: str
    process: subprocess.Popen[str]
    cell: SimCell
    targets_file: Path


def start_sim_tracker(targets_file: Path, seed: int = 7) -> tuple[subprocess.Popen[str], str]:
    """Start ``python -m monoguide.drivers.sim.tracker`` and read the pty path it listens on."""
    process = subprocess.Popen([sys.executable, "-m", "monoguide.drivers.sim.tracker", "--targets",
                                str(targets_file), "--seed", str(seed)], stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], 15.0)
    words = process.stdout.readline().split() if ready else []
    if words[:2] != ["LISTEN", "tracker"]:
        process.kill()
        process.wait(5)
        pytest.fail(f"simulated tracker did not start: {words}")
    return process, words[2]


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
