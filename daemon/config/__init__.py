"""The cell config: each section's dataclass beside its reader, and the loader of the whole file
(docs/cell-config.md).

The only way in for the rest of the code: ``_cell`` loads the file and checks what spans sections; ``_camera``,
``_part``, ``_devices``, ``_service``, ``_sim``, ``_layout`` and ``_calibration`` each hold their sections'
dataclasses and readers; ``_bounds`` the documented ranges; ``_reader`` the typed getters they read with; ``_file``
the one way a config file is read (a regular file of at most 4 MiB), which every command's file options go through.
"""

from __future__ import annotations

from monoguide.daemon.config._bounds import BOUNDS
from monoguide.daemon.config._calibration import (
    CALIBRATION_STEPS,
    CELL_STEPS,
    PART_STEPS,
    CalibrationTarget,
    CalibrationTargetConfig,
    CellFrameConfig,
)
from monoguide.daemon.config._camera import INTRINSICS_KEYS, CameraConfig
from monoguide.daemon.config._cell import (
    OPTIONAL_SECTIONS,
    PARTS_SECTIONS,
    REQUIRED_SECTIONS,
    CellConfig,
    load_cell_config,
    require_sections,
)
from monoguide.daemon.config._devices import PlcConfig, RobotConfig, TrackerConfig
from monoguide.daemon.config._file import MAX_CONFIG_BYTES, read_config_bytes, read_config_text, read_config_toml
from monoguide.daemon.config._layout import LayoutConfig
from monoguide.daemon.config._part import MeasuringPose, PartConfig, ReferenceConfig
from monoguide.daemon.config._parts import MAX_JOB, PartType
from monoguide.daemon.config._service import ChecksConfig, ServiceConfig
from monoguide.daemon.config._sim import SimConfig, default_sim_state_file

__all__ = [
    "BOUNDS", "CALIBRATION_STEPS", "CELL_STEPS", "INTRINSICS_KEYS", "MAX_CONFIG_BYTES", "MAX_JOB", "OPTIONAL_SECTIONS",
    "PARTS_SECTIONS", "PART_STEPS", "REQUIRED_SECTIONS",
    "CalibrationTarget", "CalibrationTargetConfig", "CameraConfig", "CellConfig", "CellFrameConfig", "ChecksConfig",
    "LayoutConfig", "MeasuringPose", "PartConfig", "PartType", "PlcConfig", "ReferenceConfig", "RobotConfig",
    "ServiceConfig", "SimConfig", "TrackerConfig", "default_sim_state_file", "load_cell_config", "read_config_bytes",
    "read_config_text", "read_config_toml", "require_sections",
]
