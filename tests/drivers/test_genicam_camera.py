"""The harvesters adapter on the real GenTL producer ``viky.cti`` from the ``genicam`` wheel."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import genicam
import numpy as np
import pytest

from monoguide.drivers.camera import Camera, CameraSettings
from monoguide.drivers.errors import DeviceDisconnected, DeviceNotFound, DeviceSettingRejected, DeviceTimeout
from monoguide.drivers.genicam_camera import GenICamCamera
from monoguide.drivers.genicam_nodes import device_errors, set_number

VIKY = Path(genicam.__file__).parent / "viky.cti"


def test_viky_producer_is_installed() -> None:
    assert VIKY.is_file(), f"{VIKY} missing: the genicam wheel must ship viky.cti"


@pytest.fixture
def camera() -> Iterator[GenICamCamera]:
    cam = GenICamCamera(VIKY, serial="1")
    cam.open()
    try:
        yield cam
    finally:
        cam.close()


def test_identity_of_the_chosen_device(camera: GenICamCamera) -> None:
    assert isinstance(camera, Camera)
    assert camera.identity is not None
    assert (camera.identity.model, camera.identity.serial) == ("Viky", "1")


@pytest.mark.parametrize("size", [(640, 480), (100, 100), (800, 800)])
def test_grabs_mono8_frames_of_the_configured_size(camera: GenICamCamera, size: tuple[int, int]) -> None:
    # viky lacks exposure, gain, offsets and trigger: logged and skipped, not fatal
    camera.configure(CameraSettings("Mono8", exposure_us=5000.0, gain_db=3.0, region=(0, 0, *size)))
    assert not camera.software_trigger
    frame = camera.grab(3.0)
    assert frame.image.shape == (size[1], size[0]) and frame.image.dtype == np.uint8
    assert frame.pixel_format == "Mono8" and frame.frame_number == 1


def test_buffers_are_requeued(camera: GenICamCamera) -> None:
    camera.configure(CameraSettings(region=(0, 0, 200, 200)))
    camera.node_map.AcquisitionFrameRate.value = 200.0  # each grab skips the frames in flight: keep it quick
    numbers = [camera.grab(3.0).frame_number for _ in range(3 * 16)]
    assert numbers[-1] == 48


def test_settings_out_of_range_are_rejected(camera: GenICamCamera) -> None:
    with pytest.raises(DeviceSettingRejected, match="Width"):
        camera.configure(CameraSettings(region=(0, 0, 900, 480)))
    with pytest.raises(DeviceSettingRejected, match="Mono8"):
        camera.configure(CameraSettings(pixel_format="RGB8"))
    with pytest.raises(DeviceSettingRejected, match="Mono12"):
        camera.configure(CameraSettings(pixel_format="Mono12"))  # a mono format viky does not offer
    with pytest.raises(DeviceSettingRejected, match="OffsetX"):
        camera.configure(CameraSettings(region=(10, 0, 200, 200)))  # no offsets on viky


def test_no_frame_in_time_is_a_timeout(camera: GenICamCamera) -> None:
    camera.configure(CameraSettings(region=(0, 0, 200, 200)))
    camera.node_map.AcquisitionFrameRate.value = 1.0  # one frame a second
    with pytest.raises(DeviceTimeout, match=r"0\.2 s"):
        camera.grab(0.2)


def test_unplugged_camera_is_a_disconnect(camera: GenICamCamera) -> None:
    camera.configure(CameraSettings(region=(0, 0, 200, 200)))
    camera.grab(3.0)
    camera._acquirer.destroy()  # what unplugging leaves behind: a dead device handle
    with pytest.raises(DeviceDisconnected):
        camera.grab(1.0)


def test_absent_device_or_producer_is_not_found(tmp_path: Path) -> None:
    with pytest.raises(DeviceNotFound, match="serial '7'"):
        GenICamCamera(VIKY, serial="7").open()
    with pytest.raises(DeviceNotFound, match="exactly one"):
        GenICamCamera(VIKY).open()  # three devices and nothing to choose by
    with pytest.raises(DeviceNotFound, match="does not exist"):
        GenICamCamera(tmp_path / "absent.cti").open()
    not_a_producer = tmp_path / "fake.cti"
    not_a_producer.write_bytes(b"not a shared library")
    with pytest.raises(DeviceNotFound, match="offers no camera"):
        GenICamCamera(not_a_producer, serial="0").open()


# --- fresh frames, typed errors and the lock on the real producer (issue 7, items 9 and 10) -------------


def test_each_frame_carries_its_id_and_times_and_is_past_the_frames_in_flight(camera: GenICamCamera) -> None:
    camera.configure(CameraSettings(region=(0, 0, 200, 200)))
    first = camera.grab(3.0)
    time.sleep(0.3)  # frames pile up in the producer while the robot moves (viky: 20 frames a second)
    second = camera.grab(3.0)
    assert isinstance(first.frame_id, int) and isinstance(second.frame_id, int)
    # the queued frames are flushed and the two frames that may be in flight skipped
    assert second.frame_id >= first.frame_id + 3
    for frame in (first, second):
        assert frame.requested_time_s is not None and frame.requested_time_s <= frame.host_time_s
    assert second.requested_time_s > first.host_time_s


def test_genicam_exceptions_are_translated_naming_the_node(camera: GenICamCamera) -> None:
    with (pytest.raises(DeviceSettingRejected, match=r"Width = 100000.*Max = 800") as info,
          device_errors("camera 1", "Width = 100000")):
        camera.node_map.Width.value = 100000  # the library's own OutOfRangeException
    assert isinstance(info.value.__cause__, genicam.genapi.OutOfRangeException)
    with pytest.raises(DeviceSettingRejected, match=r"PayloadSize = 64: not accessible"):
        set_number(camera.node_map, "camera 1", "PayloadSize", 64, required=True)  # read-only: AccessException
    with pytest.raises(DeviceSettingRejected, match="whole numbers"):
        camera.configure(CameraSettings(region=(0, 0, 640.5, 480)))  # type: ignore[arg-type]


def test_grabs_from_threads_take_turns(camera: GenICamCamera) -> None:
    camera.configure(CameraSettings(region=(0, 0, 200, 200)))
    camera.node_map.AcquisitionFrameRate.value = 200.0
    frames, errors = [], []

    def grab() -> None:
        for _ in range(4):
            try:
                frames.append(camera.grab(3.0))
            except Exception as exc:
                errors.append(repr(exc))

    threads = [threading.Thread(target=grab) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert not errors, errors
    assert sorted(f.frame_number for f in frames) == list(range(1, 13))
    assert len({f.frame_id for f in frames}) == 12
