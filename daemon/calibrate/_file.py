"""Write the wizard's calibrated values into the cell config, in place, keeping everything else.

:func:`write_calibration` edits the parsed document (``tomlkit``, which keeps a TOML file's comments, order and
layout), not a re-serialised TOML: only the values of the calibrated keys change (``[camera.intrinsics]``,
``[camera] T_f_c``, ``[reference] T_cf_b`` and ``T_cf_w0``, each ``[[measuring_poses]] T_cf_si``, each
``[[reference_marks]] position_cf``); every comment, every other key, the order and the layout stay as they were,
whether a table is written with a header or inline. A calibrated key the file lacks (``T_cf_si`` of a pose given
by ``T_b_f``) is added after the last value of its table. The ``[calibration]`` section (provenance: date,
session, wizard version, devices, a residual summary per step and ``previous``) is replaced as a whole.

Safety: the new text goes to a temporary file beside the config, is loaded with
:func:`~monoguide.daemon.config._cell.load_cell_config` and checked to hold exactly the calibrated values; only then is
the config copied to ``<stem>.<UTC timestamp>.previous.toml`` (the previous calibration, named in
``[calibration] previous``) and the temporary file renamed over it
(:func:`~monoguide.drivers.atomic_file.write_atomic`: atomic, and synced to disk). If the new file does not load,
nothing is replaced or copied and :class:`CalibrationFileRefused` says why. docs/calibration.md,
"The calibration file".
"""

from __future__ import annotations

import math
import os
import shutil
import stat
import tomllib
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import tomlkit
import tomlkit.exceptions
from tomlkit.items import InlineTable, Item, Table

from monoguide.daemon.calibrate._summary import step_summary
from monoguide.daemon.config import (
    CALIBRATION_STEPS,
    INTRINSICS_KEYS,
    CellConfig,
    load_cell_config,
    read_config_bytes,
)
from monoguide.daemon.errors import (
    CalibrationFileError,
    CalibrationFileRefused,
    CalibrationFileUneditable,
    CalibrationValueInvalid,
    ConfigError,
)
from monoguide.drivers.atomic_file import write_atomic
from monoguide.drivers.toml_format import (
    MATRIX_DECIMALS,
    add_after_last_value,
    commented,
    inline_table,
    matrix,
    numbers,
    opening_comment,
    replace_section,
)
from monoguide.solver.errors import MonoguideError
from monoguide.solver.frames import check_transform, make_T, orthonormalize

__all__ = [
    "MATRIX_DECIMALS",
    "PROVENANCE_KEYS",
    "CalibrationFileError",
    "CalibrationFileRefused",
    "CalibrationFileUneditable",
    "CalibrationValueInvalid",
    "read_calibration_provenance",
    "write_calibration",
]

ROUND_TRIP_TOL = 1e-9  # what loads back must equal what was calibrated to this (MATRIX_DECIMALS: ~1e-12)
MARK_DECIMALS = 4  # a surveyed mark's position_cf, mm: 0.1 um, far below the tracker's 0.025 mm
# what the caller may give in ``provenance`` (``previous`` is the writer's own)
PROVENANCE_KEYS = ("date", "session", "wizard_version", "sim", "devices")
_TABLES = {"camera.intrinsics": ("camera", "intrinsics"), "camera": ("camera",), "reference": ("reference",),
           "measuring_poses": ("measuring_poses",), "parts": ("parts",), "reference_marks": ("reference_marks",)}


# --- public --------------------------------------------------------------------------------------


def write_calibration(config_path: Path, steps: dict[str, dict[str, Any]], provenance: dict[str, Any],
                      part: dict[str, Any] | None = None) -> Path:
    """Rewrite ``config_path`` in place with the calibrated values of the ``steps`` present (results as the
    wizard stores them, docs/calibration.md) and a ``[calibration]`` provenance section; keep the previous file
    as ``<stem>.<UTC timestamp>.previous.toml`` beside it. Returns ``config_path``.

    ``provenance``: ``session`` (str), ``devices`` ({name: "vendor model serial"}), ``sim`` (bool), optionally
    ``date`` (ISO; default now, UTC) and ``wizard_version`` (default the installed monoguide's). Steps absent
    from ``steps`` leave their values and their earlier provenance summary untouched.

    ``part``: a part type's calibration (``calibrate --job N``): ``job``, ``name`` and ``cell_steps`` (the
    cell-wide steps' "done" times it was made with); its values are written (its ``T_cf_w0``, its poses'
    ``T_cf_si``, not the camera's mounting, which is the cell's) and its provenance goes into
    ``[calibration.parts.<job>]``, the rest of ``[calibration]`` kept."""
    config_path = Path(config_path)
    original = read_config_bytes(config_path, "cell config")  # a regular file of at most 4 MiB, else ConfigError
    try:
        mode = stat.S_IMODE(config_path.stat().st_mode)
    except OSError as exc:
        raise CalibrationFileError(f"{config_path}: cannot read the cell config: {exc}") from exc
    try:
        text = original.decode("utf-8")
        raw = tomllib.loads(text)
        doc = tomlkit.parse(text)
    except (UnicodeDecodeError, tomllib.TOMLDecodeError, tomlkit.exceptions.TOMLKitError) as exc:
        raise CalibrationFileUneditable(f"{config_path}: not valid TOML, nothing written: {exc}") from exc
    now = datetime.now(UTC)
    previous = _previous_path(config_path, now)
    values = _calibrated_values(steps, raw, config_path, mounting=part is None)
    record = (_provenance(steps, provenance, raw, previous.name, now) if part is None
              else _part_provenance(steps, provenance, raw, part, previous.name, now))

    for (table, index, key), (kind, value) in values.items():
        doc = _set(doc, _calibrated_table(doc, table, index, config_path), key, kind, value)
    replace_section(doc, "calibration", _provenance_table(record))

    def check_then_keep_previous(written: Path) -> None:
        _check_written(written, values, config_path)
        write_atomic(previous, original, mode=mode)
        shutil.copystat(config_path, previous)

    try:
        write_atomic(config_path, doc.as_string(), mode=mode, durable=True, before_replace=check_then_keep_previous)
    except OSError as exc:
        raise CalibrationFileError(f"{config_path}: cannot write the calibration (nothing replaced): {exc}") from exc
    return config_path


def read_calibration_provenance(config: CellConfig | str | os.PathLike[str]) -> dict[str, Any] | None:
    """The ``[calibration]`` section of a cell config (loaded, or a path to load) as a dict, or ``None`` when the
    file has none (never calibrated by the wizard). Keys: date, session, wizard_version, previous, sim,
    devices {name: str}, steps {step: {key: value}}."""
    if not isinstance(config, CellConfig):
        config = load_cell_config(config)
    return config.calibration


# --- the calibrated values -------------------------------------------------------------------------


def _calibrated_values(steps: dict[str, dict[str, Any]], raw: dict[str, Any], path: Path, mounting: bool = True
                       ) -> dict[tuple[str, int, str], tuple[str, Any]]:
    """(table, array index or -1, key) -> ("matrix" | "number" | "integer" | "vector", value) for every calibrated key;
    ``mounting``: sfi's ``T_f_c`` too (a part type's session leaves the camera's mounting to the cell's)."""
    if unknown := sorted(set(steps) - set(CALIBRATION_STEPS)):
        raise CalibrationValueInvalid(f"{path}: unknown calibration steps {unknown}; steps are "
                                      f"{list(CALIBRATION_STEPS)}")
    out: dict[tuple[str, int, str], tuple[str, Any]] = {}
    if "intrinsics" in steps:
        camera = steps["intrinsics"].get("camera")
        if not isinstance(camera, dict) or (missing := [k for k in INTRINSICS_KEYS if k not in camera]):
            lacks = missing if isinstance(camera, dict) else list(INTRINSICS_KEYS)
            raise CalibrationValueInvalid(f"intrinsics: the result's camera lacks {lacks}")
        for key in INTRINSICS_KEYS:
            value = camera[key]
            if key in ("width", "height"):
                if isinstance(value, bool) or not isinstance(value, int | float) or value != int(value) or value < 1:
                    raise CalibrationValueInvalid(f"intrinsics: camera {key} = {value!r}: expected a positive integer")
                out[("camera.intrinsics", -1, key)] = ("integer", int(value))
            else:
                out[("camera.intrinsics", -1, key)] = ("number", _finite(value, f"intrinsics: camera {key}"))
    if "marks" in steps:
        entries = raw.get("reference_marks") or []
        names = [e.get("name") if isinstance(e, dict) else None for e in entries]
        for mark in steps["marks"].get("marks") or []:
            name = mark.get("name") if isinstance(mark, dict) else None
            if name not in names:
                raise CalibrationValueInvalid(f"marks: reference mark {name!r} is not in {path} (its "
                                              f"[[reference_marks]]: {names})")
            out[("reference_marks", names.index(name), "position_cf")] = (
                "vector", _point(mark.get("position_cf"), f"marks: {name} position_cf"))
    if "base" in steps:
        out[("reference", -1, "T_cf_b")] = ("matrix", _rigid(steps["base"].get("T_cf_b"), "base: T_cf_b"))
    if "part" in steps:
        T_cf_w0 = ("matrix", _rigid(steps["part"].get("T_cf_w0"), "part: T_cf_w0"))
        if raw.get("parts"):  # a cell of part types: the reference is the measured part type's ([[parts]] job)
            jobs = [e.get("job") if isinstance(e, dict) else None for e in raw["parts"]]
            job = steps["part"].get("job", jobs[0])
            if job not in jobs:
                raise CalibrationValueInvalid(f"part: job {job!r} is not a part type of {path} (its jobs: {jobs})")
            out[("parts", jobs.index(job), "T_cf_w0")] = T_cf_w0
        else:
            out[("reference", -1, "T_cf_w0")] = T_cf_w0
    if "sfi" in steps:
        sfi = steps["sfi"]
        if mounting:
            out[("camera", -1, "T_f_c")] = ("matrix", _rigid(sfi.get("T_f_c"), "sfi: T_f_c"))
        entries = raw.get("measuring_poses") or []
        names = [e.get("name", f"S{i + 1}") if isinstance(e, dict) else "" for i, e in enumerate(entries)]
        for pose in sfi.get("poses") or []:
            name = pose.get("name")
            if name not in names:
                raise CalibrationValueInvalid(f"sfi: measuring pose {name!r} is not in {path} (it has {names})")
            out[("measuring_poses", names.index(name), "T_cf_si")] = (
                "matrix", _rigid(pose.get("T_cf_si"), f"sfi: {name} T_cf_si"))
    return out


def _rigid(value: Any, name: str) -> np.ndarray:
    try:
        T = check_transform(np.asarray(value, dtype=float), name)
    except (MonoguideError, TypeError, ValueError) as exc:
        raise CalibrationValueInvalid(f"{name}: not a rigid 4x4 transform: {exc}") from exc
    return make_T(orthonormalize(T[:3, :3]), T[:3, 3])  # written exactly as it will load


def _point(value: Any, name: str) -> np.ndarray:
    """A point (3,) mm, rounded as it is written (so that what loads back is exactly it)."""
    try:
        p = np.asarray(value, dtype=float).reshape(3)
    except (TypeError, ValueError) as exc:
        raise CalibrationValueInvalid(f"{name} = {value!r}: expected [x, y, z] (mm)") from exc
    if not np.all(np.isfinite(p)):
        raise CalibrationValueInvalid(f"{name} = {value!r}: expected finite numbers")
    return np.round(p, MARK_DECIMALS)


def _finite(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise CalibrationValueInvalid(f"{name} = {value!r}: expected a finite number")
    return float(value)


def _check_written(tmp: Path, values: dict[tuple[str, int, str], tuple[str, Any]], path: Path) -> None:
    """The new text loads, and holds exactly what was meant (a wrong edit would load with the old values)."""
    try:
        config = load_cell_config(tmp)
    except ConfigError as exc:
        message = str(exc).replace(str(tmp), str(path))
        raise CalibrationFileRefused(f"{path}: the calibrated file would not load, nothing replaced: "
                                     f"{message}") from exc
    for (table, index, key), (_kind, value) in values.items():
        if table == "camera.intrinsics":
            got: Any = getattr(config.camera.intrinsics, key)
        elif table == "camera":
            got = config.camera.T_f_c
        elif table == "reference":
            got = getattr(config.reference, key)
        elif table == "parts":
            got = config.parts[index].T_cf_w0
        elif table == "reference_marks":
            got = config.reference_marks[index].position_cf
        else:
            got = config.cell_poses[index].T_cf_si
        if got is None or not np.allclose(np.asarray(got, dtype=float), value, rtol=0.0, atol=ROUND_TRIP_TOL):
            raise CalibrationFileRefused(f"{path}: [{table}] {key}: the rewritten file loads {got!r}, not the "
                                         f"calibrated value; nothing replaced")


# --- provenance ----------------------------------------------------------------------------------


def _provenance(steps: dict[str, dict[str, Any]], provenance: dict[str, Any], raw: dict[str, Any],
                previous: str, now: datetime) -> dict[str, Any]:
    """The ``[calibration]`` section to write, as plain data in the order written (docs/calibration.md)."""
    if unknown := sorted(set(provenance) - set(PROVENANCE_KEYS)):
        raise CalibrationValueInvalid(f"provenance: unknown keys {unknown}; known: {list(PROVENANCE_KEYS)}")
    date = provenance.get("date") or now.isoformat(timespec="seconds")
    try:
        datetime.fromisoformat(str(date))
    except ValueError as exc:
        raise CalibrationValueInvalid(f"provenance: date = {date!r}: expected an ISO 8601 date-time") from exc
    devices = provenance.get("devices") or {}
    if not isinstance(devices, dict):
        raise CalibrationValueInvalid(f"provenance: devices = {devices!r}: expected {{name: 'vendor model serial'}}")
    old = raw.get("calibration") if isinstance(raw.get("calibration"), dict) else {}
    summaries = {k: v for k, v in (old.get("steps") or {}).items() if k in CALIBRATION_STEPS and k not in steps}
    summaries |= {name: step_summary(name, result) for name, result in steps.items()}
    record: dict[str, Any] = {"date": str(date)}
    if provenance.get("session") is not None:
        record["session"] = str(provenance["session"])
    record["wizard_version"] = str(provenance.get("wizard_version") or _version())
    record["previous"] = previous
    if provenance.get("sim") is not None:
        record["sim"] = bool(provenance["sim"])
    if devices:
        record["devices"] = {str(k): str(v) for k, v in devices.items()}
    if summaries:
        record["steps"] = {name: summaries[name] for name in CALIBRATION_STEPS if name in summaries}
    if old.get("parts"):  # the other part types' calibrations stay (each says which cell steps it was made with)
        record["parts"] = old["parts"]
    return record


def _part_provenance(steps: dict[str, dict[str, Any]], provenance: dict[str, Any], raw: dict[str, Any],
                     part: dict[str, Any], previous: str, now: datetime) -> dict[str, Any]:
    """``[calibration]`` as it was (or new), with part type ``part["job"]``'s entry in ``parts`` (re)written."""
    own = _provenance(steps, provenance, {}, previous, now)
    old = raw.get("calibration") if isinstance(raw.get("calibration"), dict) else {}
    record = {k: v for k, v in old.items() if k != "parts"} or {k: own[k] for k in ("date", "wizard_version")}
    record["previous"] = previous
    entry = {"name": str(part["name"]), "date": own["date"]}
    if "session" in own:
        entry["session"] = own["session"]
    entry["wizard_version"] = own["wizard_version"]
    entry["cell_steps"] = {str(k): str(v) for k, v in (part.get("cell_steps") or {}).items()}
    entry["steps"] = own.get("steps", {})
    record["parts"] = {**(old.get("parts") or {}), str(int(part["job"])): entry}
    return record


def _provenance_table(record: dict[str, Any]) -> Table:
    """``[calibration]`` with its comments; a step's summary on one line (an inline table)."""
    table = commented(tomlkit.table(), 'written by `monoguide calibrate` (docs/calibration.md, "The calibration '
                                       'file")')
    for key, value in record.items():
        if key == "previous":
            table[key] = commented(tomlkit.item(value), "this file before the calibration; roll back by copying "
                                                        "it here")
        elif key == "devices":
            table[key] = tomlkit.table()
            table[key].update(value)
        elif key == "steps":
            table[key] = _steps_table(value)
        elif key == "parts":
            table[key] = commented(tomlkit.table(), "the other part types, each calibrated by `monoguide calibrate "
                                                    "--job N` with the cell steps of cell_steps")
            for job, entry in value.items():
                sub = tomlkit.table()
                for k, v in entry.items():
                    if k == "steps":
                        sub[k] = _steps_table(v)
                    elif isinstance(v, dict):
                        sub[k] = inline_table(v)
                    else:
                        sub[k] = v
                table[key][str(job)] = sub
        else:
            table[key] = value
    return table


def _steps_table(summaries: dict[str, dict[str, Any]]) -> Table:
    table = commented(tomlkit.table(), "per step: when, and its residual summary")
    table.update({name: inline_table(summary) for name, summary in summaries.items()})
    return table


def _version() -> str:
    try:
        return metadata.version("monoguide")
    except metadata.PackageNotFoundError:
        return "unknown"


def _previous_path(config_path: Path, now: datetime) -> Path:
    stamp = now.strftime("%Y%m%dT%H%M%SZ")
    for k in range(1, 1000):
        path = config_path.with_name(f"{config_path.stem}.{stamp}{'' if k == 1 else f'-{k}'}.previous.toml")
        if not path.exists():
            return path
    raise CalibrationFileError(f"{config_path}: too many previous copies stamped {stamp}")


# --- editing the document ------------------------------------------------------------------------


def _calibrated_table(doc: tomlkit.TOMLDocument, table: str, index: int, path: Path) -> Table | InlineTable:
    """The table of ``doc`` a calibrated key of ``table`` (``[[measuring_poses]]`` entry ``index``) goes into."""
    node: Any = doc
    where = ""
    for part in _TABLES[table]:
        where = f"{where}.{part}" if where else part
        node = node.get(part) if isinstance(node, dict) else None
        if node is None:
            raise CalibrationFileUneditable(f"{path}: there is no [{where}] to write the calibration into")
    if index >= 0:
        where = f"[[{where}]] #{index + 1}"
        node = node[index] if isinstance(node, list) and index < len(node) else None
    else:
        where = f"[{where}]"
    if not isinstance(node, dict):
        raise CalibrationFileUneditable(f"{path}: {where} is not a table, the calibration cannot be written into it")
    return node


def _set(doc: tomlkit.TOMLDocument, table: Table | InlineTable, key: str, kind: str, value: Any
         ) -> tomlkit.TOMLDocument:
    """Set a calibrated value in ``table`` of ``doc``; its comments (after it, after a matrix's opening bracket)
    stay. Returns the document holding it (a new one where a key was added: :func:`add_after_last_value`)."""
    if kind == "integer":
        item: Item = tomlkit.item(int(value))
    elif kind == "number":
        item = tomlkit.item(float(value))
    elif kind == "vector":  # on one line, its comment after it kept
        item = numbers(value, MARK_DECIMALS)
        old = table.get(key)
        if isinstance(old, Item) and old.trivia.comment:
            commented(item, old.trivia.comment.removeprefix("#").strip())
    else:  # one row per line; inside an inline table too (TOML allows newlines inside an array value)
        item = matrix(value, comment=opening_comment(table[key]) if key in table else None)
    if key in table:
        table[key] = item
        return doc
    return add_after_last_value(doc, table, key, item)
