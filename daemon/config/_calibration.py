"""``[cell_frame]``, ``[calibration_target]`` and ``[calibration]``: what the calibration wizard measures the cell
with, and the provenance ``monoguide calibrate`` writes (docs/calibration.md); also a calibration target as the
simulated cell places it (``[[sim.targets]]``)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np

from monoguide.daemon.config._bounds import bounded_integer
from monoguide.daemon.config._reader import ConfigTable
from monoguide.drivers.errors import ConfigError
from monoguide.solver.calibration.target import TargetMarks, grid_marks

CELL_FRAME_METHODS = ("best-fit", "3-2-1")
# the wizard's steps, in order (daemon/calibrate/ takes them from here), the keys of [calibration.steps]
CALIBRATION_STEPS = ("intrinsics", "cell", "marks", "base", "part", "sfi", "verify", "accuracy")
CELL_STEPS = ("intrinsics", "cell", "base")  # done once for the cell; every part type's calibration is made with them
# "marks" is the cell's too (done in the cell's session), but only on a cell with [[reference_marks]] (its fixed marks
# surveyed: cell_calibration_gap); no part type's calibration depends on it (both are in CF): not among CELL_STEPS
PART_STEPS = ("part", "sfi", "verify", "accuracy")
PART_REQUIRED_STEPS = ("part", "sfi")  # without these a part type's jobs are refused (PART_NOT_CALIBRATED)


@dataclass(frozen=True)
class CalibrationTarget:
    name: str
    T_cf_t: np.ndarray
    points_t: np.ndarray  # (m, 3) tracker-measurable points (nests in its featured holes), target frame


@dataclass(frozen=True)
class CellFrameConfig:
    """``[cell_frame]``: the benchmark SMR nests that define the cell frame CF (docs/calibration.md)."""

    method: str  # "best-fit" (all benchmarks) or "3-2-1" (origin at the first, x to the second, xy through the third)
    benchmarks: dict[str, np.ndarray]  # nest name -> nominal coordinates in CF, mm (file order kept)


def read_cell_frame(t: ConfigTable) -> CellFrameConfig:
    method = t.choice("method", CELL_FRAME_METHODS, "best-fit")
    bench = t.table("benchmarks")
    benchmarks = read_nests(bench)
    bench.done()
    if len(benchmarks) < 3:
        raise ConfigError(f"{t.where}.benchmarks: {len(benchmarks)} nests ({sorted(benchmarks)}); the cell frame "
                          f"needs at least 3")
    t.done()
    return CellFrameConfig(method, benchmarks)


@dataclass(frozen=True)
class CalibrationTargetConfig:
    """``[calibration_target]``: the target with circular marks the measuring poses are calibrated with."""

    nests_t: np.ndarray  # (m, 3) its SMR nests in its own frame TF, mm (tracker names T<i>.<k>, k 1-based)
    marks: TargetMarks  # marks_cols x marks_rows marks at marks_pitch_mm from marks_origin_t


def read_calibration_target(t: ConfigTable) -> CalibrationTargetConfig:
    nests = t.points("nests_t")
    if len(nests) < 3:
        raise ConfigError(f"{t.where}.nests_t: {len(nests)} nests; the target's frame needs at least 3")
    cols, rows = bounded_integer(t, "marks_cols"), bounded_integer(t, "marks_rows")
    pitch = t.number("marks_pitch_mm", positive=True)
    radius = t.number("marks_radius_mm", positive=True)
    if radius >= pitch / 2:
        raise ConfigError(f"{t.where}.marks_radius_mm = {radius:g}: marks of this radius touch at a pitch of "
                          f"{pitch:g} mm (must be below {pitch / 2:g})")
    origin = t.vector("marks_origin_t", 3)
    t.done()
    grid = grid_marks(cols, rows, pitch, radius, (float(origin[0]), float(origin[1])))
    centres = grid.centers_t.copy()
    centres[:, 2] = origin[2]
    return CalibrationTargetConfig(nests, TargetMarks(centres, radius))


def read_calibration(t: ConfigTable) -> dict[str, Any]:
    """Provenance, read loosely but typed: the wizard's keys are known (a misspelt one is refused), the devices
    and the per-step summaries take any names (steps: one of CALIBRATION_STEPS)."""
    out: dict[str, Any] = {}
    if isinstance(t.raw.get("date"), datetime):  # an unquoted TOML date-time is as good as its text
        t.raw["date"] = t.raw["date"].isoformat()
    date = t.text("date", None)
    if date is not None:
        try:
            datetime.fromisoformat(date)
        except ValueError as exc:
            raise ConfigError(f"{t.where}.date = {date!r}: expected an ISO 8601 date-time") from exc
        out["date"] = date
    for key in ("session", "wizard_version", "previous"):
        if (value := t.text(key, None)) is not None:
            out[key] = value
    if (sim := t.boolean("sim", None)) is not None:
        out["sim"] = sim
    devices = t.optional_table("devices")
    out["devices"] = {k: devices.text(k) for k in list(devices.raw)}  # named by the cell: camera, tracker, ...
    devices.done()
    out["steps"] = _read_step_summaries(t.optional_table("steps"), CALIBRATION_STEPS)
    parts = t.optional_table("parts")
    out["parts"] = {}
    for key in list(parts.raw):  # [calibration.parts.<job>]: a part type calibrated by `calibrate ... --job N`
        if not key.isdigit():
            raise ConfigError(f"{parts.where} {key!r}: expected a part type's job number as the key "
                              "(e.g. [calibration.parts.2])")
        entry = parts.table(key)
        record: dict[str, Any] = {k: v for k in ("name", "date", "session", "wizard_version")
                                  if (v := entry.text(k, None)) is not None}
        cell = entry.optional_table("cell_steps")  # the cell-wide steps it was calibrated with: their "done" times
        record["cell_steps"] = {k: cell.text(k) for k in CELL_STEPS if cell.has(k)}
        cell.done()
        record["steps"] = _read_step_summaries(entry.optional_table("steps"), PART_STEPS)
        entry.done()
        out["parts"][int(key)] = record
    parts.done()
    t.done()
    return out


def part_calibration_gap(calibration: dict[str, Any] | None, job: int, jobs: tuple[int, ...]) -> str | None:
    """Why part type ``job`` of a cell of part types ``jobs`` cannot be used with this calibration (the missing
    steps, or a cell recalibrated since), or ``None``. No gap in a cell without a wizard's provenance (hand-entered
    values) or of one part type (the wizard writes only a whole calibration); the first part type is calibrated
    with the cell (``[calibration.steps]``), every other by ``[calibration.parts.<job>]``."""
    if calibration is None or len(jobs) < 2:
        return None
    first_job = jobs[0]
    steps = calibration.get("steps") or {}
    if job == first_job:
        entry: dict[str, Any] | None = {"steps": steps, "cell_steps": {}}
    else:
        entry = (calibration.get("parts") or {}).get(job)
    if entry is None:
        return f"never calibrated: steps {', '.join(PART_REQUIRED_STEPS)} missing"
    if missing := [s for s in PART_REQUIRED_STEPS if s not in entry.get("steps", {})]:
        return f"step(s) {', '.join(missing)} missing"
    redone = {s: steps[s]["done"] for s, done in entry.get("cell_steps", {}).items()
              if (steps.get(s) or {}).get("done") not in (None, done)}
    if redone:
        when = ", ".join(f"{s} on {done}" for s, done in redone.items())
        return (f"calibrated before the cell-wide step(s) were redone ({when}): steps "
                f"{', '.join(PART_REQUIRED_STEPS)} must be redone")
    return None


def cell_calibration_gap(calibration: dict[str, Any] | None, has_marks: bool) -> str | None:
    """Why the cell's own calibration as the wizard wrote it (``[calibration.steps]``) is incomplete, or ``None``:
    a cell with ``[[reference_marks]]`` (``has_marks``) needs its ``marks`` step, done after its ``cell`` step (the
    marks' ``position_cf`` are in that cell frame; surveyed before it was redone they are in another). A cell
    without marks needs none; a cell without a wizard's provenance (hand-entered values) has no gap."""
    if calibration is None or not has_marks:
        return None
    steps = calibration.get("steps") or {}
    if "marks" not in steps:
        return ("step marks missing: the [[reference_marks]] position_cf are nominal, never surveyed with the "
                "tracker (monoguide calibrate marks)")
    marks_done, cell_done = (steps["marks"] or {}).get("done"), (steps.get("cell") or {}).get("done")
    if isinstance(marks_done, str) and isinstance(cell_done, str) and _when(marks_done) < _when(cell_done):
        return (f"the reference marks were surveyed ({marks_done}) before the cell frame was redone ({cell_done}): "
                "step marks must be redone")
    return None


def _when(iso: str) -> datetime:
    when = datetime.fromisoformat(iso)
    return when if when.tzinfo is not None else when.replace(tzinfo=UTC)


def _read_step_summaries(steps: ConfigTable, names: tuple[str, ...]) -> dict[str, dict[str, Any]]:
    out = {}
    for name in [k for k in names if steps.has(k)]:
        step = steps.table(name)
        out[name] = {k: _provenance_value(step, k) for k in list(step.raw)}
        step.done()
    steps.done()
    return out


def read_nests(t: ConfigTable) -> dict[str, np.ndarray]:
    """A table of SMR nests named by the cell, every key a nest: name -> [x, y, z] (file order kept)."""
    nests = {k: t.vector(k, 3) for k in list(t.raw)}
    if any(not name.strip() for name in nests):
        raise ConfigError(f"{t.where}: a nest with an empty name ({sorted(nests)})")
    return nests


def _provenance_value(t: ConfigTable, key: str) -> Any:
    value = t.raw.get(key)
    if isinstance(value, str | bool):
        return t.boolean(key) if isinstance(value, bool) else t.text(key)
    if isinstance(value, list):
        return [float(v) for v in t.vector(key, len(value))]
    if isinstance(value, int):
        return t.integer(key)
    if isinstance(value, float):
        return t.number(key)
    raise ConfigError(f"{t.where}.{key} = {value!r}: expected a number, string, true/false or a list of numbers")
