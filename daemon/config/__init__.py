"""The cell config: each section's dataclass beside its reader, and the loader of the whole file
(docs/cell-config.md).
"""

from __future__ import annotations

from monoguide.daemon.config._cell import (
    BOUNDS,
    CALIBRATION_STEPS,
    INTRINSICS_KEYS,
    OPTIONAL_SECTIONS,
    REQUIRED_SECTIONS,
    CellConfig,
    CellFrameConfig,
    ChecksConfig,
    LayoutConfig,
    ServiceConfig,
    default_sim_state_file,
    load_cell_config,
    require_sections,
)

__all__ = [
    "BOUNDS", "CALIBRATION_STEPS", "INTRINSICS_KEYS", "OPTIONAL_SECTIONS", "REQUIRED_SECTIONS", "CellConfig",
    "CellFrameConfig", "ChecksConfig", "LayoutConfig", "ServiceConfig", "default_sim_state_file",
    "load_cell_config", "require_sections",
]
