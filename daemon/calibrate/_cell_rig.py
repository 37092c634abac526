"""``monoguide calibrate`` on a real cell: the rig of the devices the cell config names.

:func:`open_cell_rig` opens the laser tracker, the robot and the camera (``daemon.assembly``) and closes each it
opened on leaving, however it is left; ``--sim`` has its own (:func:`~monoguide.daemon.calibrate._sim.open_sim_rig`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from pathlib import Path

from monoguide.daemon.assembly import build_camera, build_robot, build_tracker, camera_settings
from monoguide.daemon.calibrate._rig import CalibrationOptions, CalibrationRig, Operator
from monoguide.daemon.config import CellConfig


@contextlib.contextmanager
def open_cell_rig(config: CellConfig, config_path: Path, options: CalibrationOptions, operator: Operator,
                  progress: Callable[[str], None]) -> Iterator[CalibrationRig]:
    """The rig of ``config``'s cell: its devices opened (the camera configured), ``operator`` the person at the
    cell, ``progress`` the sink of the steps' progress lines."""
    with contextlib.ExitStack() as stack:
        tracker = build_tracker(config)
        tracker.open()
        stack.callback(tracker.close)
        robot = build_robot(config)
        robot.open()
        stack.callback(robot.close)
        camera = build_camera(config)
        camera.open()
        stack.callback(camera.close)
        camera.configure(camera_settings(config))
        yield CalibrationRig(config, config_path, tracker, robot, camera, operator, options, progress)
