"""Write the wizard's calibrated values into the cell config, in place, keeping everything else.

:func:`write_calibration` edits the file's TEXT, not a re-serialised TOML: only the values of the calibrated keys
change (``[camera.intrinsics]``, ``[camera] T_f_c``, ``[reference] T_cf_b`` and ``T_cf_w0``, each
``[[measuring_poses]] T_cf_si``); every comment, every other key, the order and the layout stay as they were. A
calibrated key the file lacks (``T_cf_si`` of a pose given by ``T_b_f``) is added at the end of its table. The
``[calibration]`` section (provenance: date, session, wizard version, devices, a residual summary per step and
``previous``) is replaced as a whole.

Safety: the new text goes to a temporary file beside the config, is loaded with
:func:`~monoguide.daemon.config.load_cell_config` and checked to hold exactly the calibrated values; only then is
the config copied to ``<stem>.<UTC timestamp>.previous.toml`` (the previous calibration, named in
``[calibration] previous``) and the temporary file renamed over it (``os.replace``: atomic). If the new file does
not load, nothing is replaced or copied and :class:`CalibrationFileRefused` says why. docs/calibration.md,
"The calibration file".
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tomllib
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.daemon.config import CALIBRATION_STEPS, INTRINSICS_KEYS, CellConfig, ConfigError, load_cell_config
from monoguide.solver.calibration.errors import CalibrationError
from monoguide.solver.errors import MonoguideError
from monoguide.solver.frames import check_transform, make_T, orthonormalize

__all__ = [
    "PROVENANCE_KEYS",
    "CalibrationFileError",
    "CalibrationFileRefused",
    "CalibrationFileUneditable",
    "CalibrationValueInvalid",
    "read_calibration_provenance",
    "step_summary",
    "write_calibration",
]

MATRIX_DECIMALS = 12  # a round trip through the file is exact to ~1e-12 (mm and rotation entries)
ROUND_TRIP_TOL = 1e-9
# what the caller may give in ``provenance`` (``previous`` is the writer's own)
PROVENANCE_KEYS = ("date", "session", "wizard_version", "sim", "devices")


class CalibrationFileError(CalibrationError):
    """The cell config could not be read, copied or written (the message has the OS's reason)."""

    code = "CALIBRATION_FILE_FAILED"
    plc_code = 725


class CalibrationFileRefused(CalibrationFileError):
    """The rewritten config would not load (or not hold the calibrated values): nothing was replaced."""

    code = "CALIBRATION_FILE_REFUSED"
    plc_code = 726


class CalibrationValueInvalid(CalibrationFileError):
    """A step's result or the provenance cannot be written: not a rigid 4x4, a missing coefficient, a measuring
    pose the config does not have, an unknown provenance key."""

    code = "CALIBRATION_VALUE_INVALID"
    plc_code = 727


class CalibrationFileUneditable(CalibrationFileError):
    """The config's text does not hold a calibrated key's table as a ``[table]`` the writer can edit (e.g. an
    inline table); the message names it."""

    code = "CALIBRATION_FILE_UNEDITABLE"
    plc_code = 728


# --- public --------------------------------------------------------------------------------------


def write_calibration(config_path: Path, steps: dict[str, dict[str, Any]], provenance: dict[str, Any]) -> Path:
    """Rewrite ``config_path`` in place with the calibrated values of the ``steps`` present (results as the
    wizard stores them, docs/calibration.md) and a ``[calibration]`` provenance section; keep the previous file
    as ``<stem>.<UTC timestamp>.previous.toml`` beside it. Returns ``config_path``.

    ``provenance``: ``session`` (str), ``devices`` ({name: "vendor model serial"}), ``sim`` (bool), optionally
    ``date`` (ISO; default now, UTC) and ``wizard_version`` (default the installed monoguide's). Steps absent
    from ``steps`` leave their values and their earlier provenance summary untouched."""
    config_path = Path(config_path)
    try:
        text = config_path.read_text()
    except OSError as exc:
        raise CalibrationFileError(f"{config_path}: cannot read the cell config: {exc}") from exc
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CalibrationFileUneditable(f"{config_path}: not valid TOML, nothing written: {exc}") from exc
    now = datetime.now(UTC)
    previous = _previous_path(config_path, now)
    values = _calibrated_values(steps, raw, config_path)
    block = _provenance_block(steps, provenance, raw, previous.name, now)

    doc = _Document(text, config_path)
    for (table, index, key), (kind, value) in values.items():
        doc.set(table, index, key, _format(kind, value))
    doc.replace_tables("calibration", block)
    new_text = doc.text

    tmp = config_path.with_name(f".{config_path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(new_text)
        shutil.copymode(config_path, tmp)
        _check_written(tmp, values, config_path)
        shutil.copy2(config_path, previous)
        os.replace(tmp, config_path)
    except OSError as exc:
        raise CalibrationFileError(f"{config_path}: cannot write the calibration (nothing replaced): {exc}") from exc
    finally:
        tmp.unlink(missing_ok=True)
    return config_path


def read_calibration_provenance(config: CellConfig | str | os.PathLike[str]) -> dict[str, Any] | None:
    """The ``[calibration]`` section of a cell config (loaded, or a path to load) as a dict, or ``None`` when the
    file has none (never calibrated by the wizard). Keys: date, session, wizard_version, previous, sim,
    devices {name: str}, steps {step: {key: value}}."""
    if not isinstance(config, CellConfig):
        config = load_cell_config(config)
    return config.calibration


def step_summary(step: str, result: dict[str, Any]) -> dict[str, Any]:
    """The residual summary of one step's result written to ``[calibration.steps]`` (numbers, strings, booleans,
    lists of numbers; non-finite numbers left out). In --sim the step's ``truth_error`` keys as ``truth_<key>``."""
    r = result
    out: dict[str, Any] = {}
    if isinstance(r.get("done"), str):
        out["done"] = r["done"]
    if step == "intrinsics":
        out |= {"rms_px": r.get("rms_px"), "images": r.get("images"), "rejected": len(r.get("rejected") or {})}
    elif step in ("cell", "part"):
        res = list((r.get("residuals_mm") or {}).values())
        out |= {"method": r.get("method"), "rms_mm": r.get("rms_mm"), "max_mm": max(res) if res else None}
    elif step == "base":
        res = list(r.get("residuals_mm") or [])
        out |= {"rms_mm": r.get("rms_mm"), "max_mm": max(res) if res else None, "poses": len(res),
                "sigma_mm": r.get("sigma_mm"), "sigma_deg": r.get("sigma_deg")}
    elif step == "sfi":
        poses = r.get("poses") or []
        out |= {"spread_mm_max": max((p.get("spread_mm", 0.0) for p in poses), default=None),
                "spread_deg_max": max((p.get("spread_deg", 0.0) for p in poses), default=None),
                "visits": sum(int(p.get("visits", 0)) for p in poses), "poses": len(poses),
                "hand_eye_spread_mm": r.get("T_f_c_spread_mm"), "hand_eye_spread_deg": r.get("T_f_c_spread_deg")}
    elif step == "verify":
        out |= {k: r.get(k) for k in ("max_mm", "max_deg", "n", "sigma_mm", "sigma_deg", "predicted_sigma_mm",
                                      "predicted_sigma_deg")}
    elif step == "accuracy":
        out |= {"rms_dR_deg": r.get("rms_dR_deg"), "rms_dT_mm": r.get("rms_dT_mm"), "passed": r.get("passed"),
                "poses": len(r.get("rows") or [])}
    for key, value in (r.get("truth_error") or {}).items():
        out[f"truth_{key}"] = value
    return {k: v for k, v in ((k, _plain(v)) for k, v in out.items()) if v is not None}


# --- the calibrated values -------------------------------------------------------------------------


def _calibrated_values(steps: dict[str, dict[str, Any]], raw: dict[str, Any], path: Path
                       ) -> dict[tuple[str, int, str], tuple[str, Any]]:
    """(table, array index or -1, key) -> ("matrix" | "number" | "integer", value) for every calibrated key."""
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
    if "base" in steps:
        out[("reference", -1, "T_cf_b")] = ("matrix", _rigid(steps["base"].get("T_cf_b"), "base: T_cf_b"))
    if "part" in steps:
        out[("reference", -1, "T_cf_w0")] = ("matrix", _rigid(steps["part"].get("T_cf_w0"), "part: T_cf_w0"))
    if "sfi" in steps:
        sfi = steps["sfi"]
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
        else:
            got = config.measuring_poses[index].T_cf_si
        if got is None or not np.allclose(np.asarray(got, dtype=float), value, rtol=0.0, atol=ROUND_TRIP_TOL):
            raise CalibrationFileRefused(f"{path}: [{table}] {key}: the rewritten file loads {got!r}, not the "
                                         f"calibrated value; nothing replaced")


# --- provenance ----------------------------------------------------------------------------------


def _provenance_block(steps: dict[str, dict[str, Any]], provenance: dict[str, Any], raw: dict[str, Any],
                      previous: str, now: datetime) -> str:
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
    lines = ["[calibration]  # written by `monoguide calibrate` (docs/calibration.md, \"The calibration file\")",
             f"date = {_string(str(date))}"]
    if provenance.get("session") is not None:
        lines.append(f"session = {_string(str(provenance['session']))}")
    lines.append(f"wizard_version = {_string(str(provenance.get('wizard_version') or _version()))}")
    lines.append(f"previous = {_string(previous)}  # this file before the calibration; roll back by copying it here")
    if provenance.get("sim") is not None:
        lines.append(f"sim = {_value(bool(provenance['sim']))}")
    if devices:
        lines += ["", "[calibration.devices]"] + [f"{_key(k)} = {_string(str(v))}" for k, v in devices.items()]
    if summaries:
        lines += ["", "[calibration.steps]  # per step: when, and its residual summary"]
        for name in (s for s in CALIBRATION_STEPS if s in summaries):
            items = ", ".join(f"{_key(k)} = {_value(v)}" for k, v in summaries[name].items())
            lines.append(f"{name} = {{ {items} }}" if items else f"{name} = {{}}")
    return "\n".join(lines) + "\n"


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


# --- TOML text -----------------------------------------------------------------------------------


def _plain(value: Any) -> Any:
    """A JSON-ish value as the provenance can hold it (None: leave it out)."""
    if isinstance(value, bool | str):
        return value
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, list | tuple | np.ndarray):
        numbers = [_plain(v) for v in value]
        return numbers if all(isinstance(v, int | float) and not isinstance(v, bool) for v in numbers) else None
    return None


def _value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return _string(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    return "[" + ", ".join(_value(float(v)) for v in value) + "]"


def _string(value: str) -> str:
    return json.dumps(value, ensure_ascii=False)  # JSON's escapes are TOML's basic-string escapes


def _key(key: str) -> str:
    bare = key and all(c.isascii() and (c.isalnum() or c in "_-") for c in key)
    return key if bare else _string(key)


def _format(kind: str, value: Any) -> str:
    if kind == "integer":
        return str(value)
    if kind == "number":
        return repr(float(value))
    rows = ",\n    ".join("[" + ", ".join(f"{v:.{MATRIX_DECIMALS}f}" for v in row) + "]" for row in value)
    return "[\n    " + rows + ",\n]"


@dataclass
class _Header:
    name: str
    index: int  # the entry of an array of tables ([[name]]), -1 for a table
    start: int  # offset of its line
    end: int  # offset after its line


@dataclass
class _Entry:
    table: str
    index: int
    key: str  # as written, dotted keys joined by "."
    value_start: int
    value_end: int
    line_end: int  # offset after the line the value ends on


class _Document:
    """A TOML text scanned into headers and key/value entries, edited by offsets."""

    def __init__(self, text: str, path: Path) -> None:
        self.text, self.path = text, path
        self._scan()

    def set(self, table: str, index: int, key: str, value: str) -> None:
        entry = next((e for e in self.entries if e.table == table and e.index == index and e.key == key), None)
        if entry is not None:
            old = self.text[entry.value_start:entry.value_end]
            if "\n" in value and old.startswith("[") and "\n" in old:  # keep a comment after the opening bracket
                first = old.split("\n", 1)[0]
                if "#" in first:
                    value = "[  " + first[first.index("#"):].rstrip() + value[1:]
            self._splice(entry.value_start, entry.value_end, value)
            return
        header = next((h for h in self.headers if h.name == table and h.index == index), None)
        if header is None:
            where = f"[[{table}]] #{index + 1}" if index >= 0 else f"[{table}]"
            raise CalibrationFileUneditable(f"{self.path}: {where} is not written as a table header the calibration "
                                            f"can edit ({key} cannot be set); write it as {where}")
        last = [e for e in self.entries if e.table == table and e.index == index]
        at = last[-1].line_end if last else header.end
        line = f"{key} = {value}\n"
        if at > 0 and self.text[at - 1] != "\n":
            line = "\n" + line
        self._splice(at, at, line)

    def replace_tables(self, name: str, block: str) -> None:
        """Remove every ``[name]`` / ``[name.*]`` table and put ``block`` where the first was (else at the end)."""
        spans = []
        for i, h in enumerate(self.headers):
            if h.name == name or h.name.startswith(name + "."):
                end = self._attached_start(self.headers[i + 1].start) if i + 1 < len(self.headers) else len(self.text)
                spans.append((h.start, max(end, h.end)))
        if not spans:
            self.text = self.text.rstrip("\n") + "\n\n" + block
        else:
            for start, end in reversed(spans[1:]):
                self._splice(start, end, "")
            start, end = spans[0]
            rest = self.text[end:]
            self._splice(start, end, block + ("\n" if rest.strip() else ""))
        self._scan()

    # --- private -------------------------------------------------------------------------------

    def _splice(self, start: int, end: int, new: str) -> None:
        self.text = self.text[:start] + new + self.text[end:]
        self._scan()

    def _attached_start(self, offset: int) -> int:
        """Where the comment lines directly above the line at ``offset`` begin (they belong to it)."""
        start = offset
        while start > 0:
            prev = self.text.rfind("\n", 0, start - 1) + 1
            if not self.text[prev:start].strip().startswith("#"):
                break
            start = prev
        return start

    def _scan(self) -> None:
        text, n = self.text, len(self.text)
        self.headers: list[_Header] = []
        self.entries: list[_Entry] = []
        table, index, counts = "", -1, {}
        i = 0
        while i < n:
            j = i
            while j < n and text[j] in " \t":
                j += 1
            if j >= n or text[j] in "\r\n#":
                i = _eol(text, j)
                continue
            if text[j] == "[":
                array = text.startswith("[[", j)
                close = text.find("]]" if array else "]", j)
                if close < 0:
                    raise CalibrationFileUneditable(f"{self.path}: a table header without its closing bracket")
                table = ".".join(p.strip().strip('"') for p in text[j + (2 if array else 1):close].split("."))
                index = counts.get(table, 0) if array else -1
                if array:
                    counts[table] = index + 1
                end = _eol(text, close)
                self.headers.append(_Header(table, index, i, end))
                i = end
                continue
            eq = _key_end(text, j)
            key = ".".join(p.strip().strip('"') for p in text[j:eq].split("."))
            start = eq + 1
            while start < n and text[start] in " \t":
                start += 1
            stop = _value_end(text, start)
            self.entries.append(_Entry(table, index, key, start, stop, _eol(text, stop)))
            i = _eol(text, stop)


def _eol(text: str, i: int) -> int:
    """Offset after the newline that ends the line holding offset ``i``."""
    k = text.find("\n", i)
    return len(text) if k < 0 else k + 1


def _key_end(text: str, i: int) -> int:
    while i < len(text) and text[i] != "=":
        if text[i] in "\"'":
            i = text.find(text[i], i + 1)
            if i < 0:
                break
        if text[i] == "\n":
            break
        i += 1
    if i >= len(text) or i < 0 or text[i] != "=":
        raise CalibrationFileUneditable("a line is neither a table header nor key = value")
    return i


def _string_end(text: str, i: int) -> int:
    """Offset after the string starting at ``i``."""
    for quote in ('"""', "'''"):
        if text.startswith(quote, i):
            k = i + 3
            while True:
                k = text.find(quote, k)
                if k < 0:
                    return len(text)
                if quote == "'''" or text[k - 1] != "\\":
                    while text.startswith(quote[0], k + 3):  # up to two quotes may close the content
                        k += 1
                    return k + 3
                k += 1
    quote, k = text[i], i + 1
    while k < len(text) and text[k] != quote and text[k] != "\n":
        k += 2 if quote == '"' and text[k] == "\\" else 1
    return k + 1


def _value_end(text: str, i: int) -> int:
    """Offset after the value starting at ``i`` (arrays and inline tables may span lines)."""
    n = len(text)
    if i < n and text[i] in "\"'":
        return _string_end(text, i)
    if i < n and text[i] in "[{":
        depth = 0
        while i < n:
            c = text[i]
            if c in "\"'":
                i = _string_end(text, i)
                continue
            if c == "#":
                i = _eol(text, i)
                continue
            if c in "[{":
                depth += 1
            elif c in "]}":
                depth -= 1
                if depth == 0:
                    return i + 1
            i += 1
        return n
    k = i
    while k < n and text[k] not in "#\r\n":
        k += 1
    while k > i and text[k - 1] in " \t":
        k -= 1
    return k
