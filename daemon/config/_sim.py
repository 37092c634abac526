"""``[sim]``: the simulated cell's truth — how the part deviates, how the robot repeats, where the tracker, its
nests and the calibration targets stand — and where ``monoguide sim-cell`` says where its devices listen."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from monoguide.daemon.config._bounds import bounded_number
from monoguide.daemon.config._calibration import CalibrationTarget, read_nests
from monoguide.daemon.config._reader import ConfigTable
from monoguide.drivers.errors import ConfigError


@dataclass(frozen=True)
class SimConfig:
    seed: int = 0
    state_file: Path | None = None
    T_f_c: np.ndarray = field(default_factory=lambda: np.eye(4))  # true camera mounting
    T_cf_tracker: np.ndarray = field(default_factory=lambda: np.eye(4))
    deviation_translation_mm: tuple[float, float, float] = (50.0, 50.0, 5.0)
    deviation_rotation_deg: tuple[float, float, float] = (0.5, 0.5, 2.0)
    repeatability_mm: float = 0.05
    repeatability_deg: float = 0.01
    reported_repeatability_fraction: float = 1.0  # share of a stop's deviation the robot's report sees
    truth_config: Path | None = None  # the simulated devices' cell (monoguide simulate --calibration)
    tracker_noise_mm: float = 0.025
    exposure_us_nominal: float = 8000.0
    benchmarks: dict[str, np.ndarray] = field(default_factory=dict)  # SMR nests in the cell frame
    tool_smr_f: np.ndarray | None = None  # SMR on the flange tool, in the flange frame
    targets: tuple[CalibrationTarget, ...] = ()
    focus_distance_mm: float | None = None  # where the simulated lens is sharp; None: no defocus
    aperture_mm: float = 0.0  # the simulated lens's entrance pupil (focal length / f-number); 0: no defocus


def read_sim(t: ConfigTable) -> SimConfig:
    dev = t.optional_table("deviation")
    benchmarks = read_nests(t.optional_table("benchmarks"))
    targets: list[CalibrationTarget] = []
    for tt in t.tables("targets"):
        name = tt.text("name", nonempty=True)
        if name in [target.name for target in targets]:
            raise ConfigError(f"{tt.where}.name = {name!r}: another [[sim.targets]] has this name already")
        targets.append(CalibrationTarget(name, tt.matrix("T_cf_t"), tt.points("points_t")))
        tt.done()
    out = SimConfig(
        seed=t.integer("seed", 0, minimum=0),
        state_file=t.path("state_file", None),
        T_f_c=t.matrix("T_f_c", np.eye(4)),
        T_cf_tracker=t.matrix("T_cf_tracker", np.eye(4)),
        deviation_translation_mm=tuple(dev.vector("translation_mm", 3, (50.0, 50.0, 5.0))),
        deviation_rotation_deg=tuple(dev.vector("rotation_deg", 3, (0.5, 0.5, 2.0))),
        repeatability_mm=t.number("repeatability_mm", 0.05, nonnegative=True),
        repeatability_deg=t.number("repeatability_deg", 0.01, nonnegative=True),
        reported_repeatability_fraction=t.number("reported_repeatability_fraction", 1.0, nonnegative=True),
        truth_config=t.path("truth_config", None),
        tracker_noise_mm=t.number("tracker_noise_mm", 0.025, nonnegative=True),
        exposure_us_nominal=bounded_number(t, "exposure_us_nominal", 8000.0),
        benchmarks=benchmarks,
        tool_smr_f=t.vector("tool_smr_f", 3, None),
        targets=tuple(targets),
        focus_distance_mm=t.number("focus_distance_mm", None, positive=True),
        aperture_mm=t.number("aperture_mm", 0.0, nonnegative=True),
    )
    if out.reported_repeatability_fraction > 1.0:
        raise ConfigError(f"{t.where}.reported_repeatability_fraction = {out.reported_repeatability_fraction}: "
                          "expected 0 (the report sees none of a stop's deviation) .. 1 (all of it)")
    if out.aperture_mm > 0 and out.focus_distance_mm is None:
        raise ConfigError(f"{t.where}.aperture_mm = {out.aperture_mm}: a defocused lens needs focus_distance_mm")
    dev.done()
    t.done()
    return out


def default_sim_state_file() -> Path:
    """Where ``monoguide sim-cell`` says where its devices listen, unless ``[sim] state_file`` says otherwise."""
    run_dir = os.environ.get("XDG_RUNTIME_DIR") or f"/tmp/monoguide-{os.getuid()}"
    return Path(run_dir) / "monoguide-sim-cell.json"
