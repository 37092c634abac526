"""Typed, strict access to one TOML table of the cell config: every value named by its key.

:class:`ConfigTable` is what the section readers (``read_camera``, ``read_robot``, ...) read with. Each getter
takes its key out of the table and remembers it as known; :meth:`ConfigTable.done` then refuses whatever
is left, suggesting the closest known key (``sigma_pix`` -> ``sigma_px``). A key without a default is
required: missing, it raises :class:`ConfigMissingKey`, never a zero. A number with a documented range
(:class:`Bounds`) is refused outside it, the message naming the key, the value and the range
(``[plc].ack_timeout_s = 1e+308: must be 0.05 to 600 s``); a name must not be empty; a host must be an IP
address or an RFC 1123 host name (:func:`host_problem`).
"""

from __future__ import annotations

import difflib
import ipaddress
import math
import os
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.daemon.errors import ConfigMissingKey, ConfigUnknownKey, ConfigUnknownSection
from monoguide.drivers.errors import ConfigError
from monoguide.solver.frames import orthonormalize

MATRIX_TOL = 2e-3  # printed calibration matrices are rounded to 4 decimals; re-orthonormalised on load


# The default of a required key. A getter given any other default gets that very object back from _pop when
# the key is absent (`value is default`) and returns it as given, unchecked; a value from the file never is
# _MISSING, so `is default` alone tells the two apart.
_MISSING = object()
_HOST_LABEL = re.compile(r"[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?")  # RFC 1123: 1-63 characters


@dataclass(frozen=True)
class Bounds:
    """The documented range of a number or an integer: ``low`` to ``high``, both included, in ``unit``."""

    low: float
    high: float
    unit: str = ""

    def __str__(self) -> str:
        return f"{_plain(self.low)} to {_plain(self.high)}{f' {self.unit}' if self.unit else ''}"

    def admits(self, value: float) -> bool:
        return self.low <= value <= self.high  # False for NaN


def host_problem(host: str) -> str | None:
    """Why ``host`` is neither an IPv4/IPv6 address nor an RFC 1123 host name; None when it is one.

    A name whose last label is all digits (``256.1.1.1``, ``10.0.1``) is meant as an IPv4 address, never a
    name (RFC 1123 2.1, RFC 3696 2: no top-level domain is all-numeric)."""
    if not host.strip():
        return "empty: expected an IP address or a host name"
    try:
        ipaddress.ip_address(host)
        return None
    except ValueError as exc:
        reason = str(exc)
    if host.startswith("["):
        return "not an IPv6 address: write it without the brackets"
    if re.fullmatch(r"[^:]+:[0-9]+", host):
        return "a host with a port: give the port in its own key, port"
    if ":" in host:
        return f"not an IPv6 address ({reason})"
    name = host.removesuffix(".")
    labels = name.split(".")
    if labels[-1].isdigit():
        try:
            ipaddress.IPv4Address(host)
        except ValueError as exc:
            return f"not an IPv4 address ({exc})"
    if len(name) > 253:
        return f"a host name of {len(name)} characters (at most 253)"
    if bad := [label for label in labels if not _HOST_LABEL.fullmatch(label)]:
        return (f"not a host name: label {bad[0]!r} (each label 1 to 63 letters, digits or hyphens, not beginning "
                "or ending with a hyphen)")
    return None


class ConfigTable:
    """One TOML table being read. ``where`` is ``"<file>: [section]"``; messages append ``.key``."""

    def __init__(self, raw: Any, path: Path, name: str = "", label: str | None = None) -> None:
        self.file = path  # the config file; relative paths in it are relative to its folder
        self.name = name  # dotted TOML name ("camera.intrinsics"); "" for the file itself
        self.where = f"{path}: {label or f'[{name}]'}" if name else str(path)
        if not isinstance(raw, dict):
            raise ConfigError(f"{self.where}: expected a table, got {raw!r}")
        self.raw = dict(raw)
        self.known: set[str] = set()

    @property
    def base(self) -> Path:
        return self.file.parent

    # --- structure -------------------------------------------------------------------------------

    def has(self, key: str) -> bool:
        self.known.add(key)
        return key in self.raw

    def table(self, key: str) -> ConfigTable:
        """A required sub-table (``[camera.intrinsics]``; on the file, a section ``[camera]``)."""
        if key not in self.raw:
            self.known.add(key)
            raise self._missing(key, table=True)
        return self._child(key, self._pop(key, _MISSING))

    def optional_table(self, key: str) -> ConfigTable:
        """A sub-table that may be absent (read as empty, so its getters give their defaults)."""
        return self._child(key, self._pop(key, {}))

    def tables(self, key: str, required: bool = False) -> list[ConfigTable]:
        """An array of tables (``[[measuring_poses]]``); an empty list when absent and not ``required``."""
        name = f"{self.name}.{key}" if self.name else key
        value = self._pop(key, _MISSING if required else [])
        if not isinstance(value, list) or (required and not value):
            raise ConfigError(f"{self.file}: [[{name}]]: expected one or more [[{name}]] tables, got {value!r}")
        return [ConfigTable(entry, self.file, name, f"[[{name}]] #{i + 1}") for i, entry in enumerate(value)]

    def done(self) -> None:
        """Refuse every key no getter asked for, suggesting the closest known one."""
        self.reject_unknown(self.known)

    def reject_unknown(self, known: Iterable[str]) -> None:
        known = sorted(known)
        for key in sorted(set(self.raw) - set(known)):
            close = difflib.get_close_matches(key, known, n=1)
            if self.name:
                hint = f"did you mean '{close[0]}'?" if close else f"known keys: {known}"
                raise ConfigUnknownKey(f"{self.where}.{key}: unknown key; {hint}")
            if not isinstance(self.raw[key], dict | list):
                raise ConfigUnknownKey(f"{self.where}: {key} = {self.raw[key]!r}: a key outside any section; "
                                       f"sections are {[f'[{k}]' for k in known]}")
            hint = f"did you mean [{close[0]}]?" if close else f"known sections: {[f'[{k}]' for k in known]}"
            raise ConfigUnknownSection(f"{self.where}: unknown section [{key}]; {hint}")

    # --- values ----------------------------------------------------------------------------------

    def text(self, key: str, default: Any = _MISSING, nonempty: bool = False) -> Any:
        """A string; ``nonempty``: a name, which must not be empty or only blanks."""
        if (value := self._pop(key, default)) is default:
            return value
        if not isinstance(value, str):
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected a string")
        if nonempty and not value.strip():
            raise ConfigError(f"{self.where}.{key} = {value!r}: must not be empty")
        return value

    def host(self, key: str, default: Any = _MISSING) -> Any:
        """An IPv4 or IPv6 address, or an RFC 1123 host name (resolved only when the device is opened)."""
        if (value := self.text(key, default)) is default:
            return value
        if (problem := host_problem(value)) is not None:
            raise ConfigError(f"{self.where}.{key} = {value!r}: {problem}")
        return value

    def texts(self, key: str, default: Any = _MISSING) -> Any:
        if (value := self._pop(key, default)) is default:
            return value
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected a list of strings")
        return tuple(value)

    def choice(self, key: str, options: tuple[str, ...], default: Any = _MISSING) -> Any:
        if (value := self.text(key, default)) is default:
            return value
        if value not in options:
            close = difflib.get_close_matches(value, options, n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise ConfigError(f"{self.where}.{key} = {value!r}: must be one of {list(options)}{hint}")
        return value

    def boolean(self, key: str, default: Any = _MISSING) -> Any:
        if (value := self._pop(key, default)) is default:
            return value
        if not isinstance(value, bool):
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected true or false")
        return value

    def path(self, key: str, default: Any = _MISSING) -> Any:
        if (value := self.text(key, default)) is default:
            return value
        p = Path(os.path.expandvars(os.path.expanduser(value)))
        return p if p.is_absolute() else self.base / p

    def number(self, key: str, default: Any = _MISSING, positive: bool = False, nonnegative: bool = False,
               bounds: Bounds | None = None) -> Any:
        """A finite number; ``bounds``: within its documented range (NaN and infinities are outside every range)."""
        if (value := self._pop(key, default)) is default:
            return value
        if isinstance(value, bool) or not isinstance(value, int | float):
            within = f" ({bounds})" if bounds else ""
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected a finite number{within}")
        if bounds is not None and not bounds.admits(value):
            raise ConfigError(f"{self.where}.{key} = {value!r}: must be {bounds}")
        if not math.isfinite(value):
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected a finite number")
        if positive and value <= 0:
            raise ConfigError(f"{self.where}.{key} = {value!r}: must be positive")
        if nonnegative and value < 0:
            raise ConfigError(f"{self.where}.{key} = {value!r}: must not be negative")
        return float(value)

    def integer(self, key: str, default: Any = _MISSING, minimum: int | None = None,
                bounds: Bounds | None = None) -> Any:
        """An integer; ``bounds``: within its documented range."""
        if (value := self._pop(key, default)) is default:
            return value
        if isinstance(value, bool) or not isinstance(value, int):
            within = f" ({bounds})" if bounds else ""
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected an integer{within}")
        if bounds is not None and not bounds.admits(value):
            raise ConfigError(f"{self.where}.{key} = {value!r}: must be {bounds}")
        if minimum is not None and value < minimum:
            raise ConfigError(f"{self.where}.{key} = {value!r}: must be at least {minimum}")
        return value

    def ints(self, key: str, length: int | None, default: Any = _MISSING) -> Any:
        if (value := self._pop(key, default)) is default:
            return value
        ok = isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool) for v in value)
        if not ok or (length is not None and len(value) != length):
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected a list of {length or 'n'} integers")
        return tuple(value)

    def vector(self, key: str, length: int, default: Any = _MISSING) -> Any:
        if (value := self._pop(key, default)) is default:
            return value if value is None else np.asarray(value, dtype=float)
        arr = self._array(key, value)
        if arr.shape != (length,):
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected {length} numbers")
        return arr

    def points(self, key: str) -> np.ndarray:
        value = self._pop(key, _MISSING)
        arr = self._array(key, value)
        if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) == 0:
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected a list of [x, y, z] points (mm)")
        return arr

    def matrix(self, key: str, default: Any = _MISSING) -> Any:
        """A 4x4 rigid transform, row-major; its rotation re-orthonormalised within :data:`MATRIX_TOL`."""
        if (value := self._pop(key, default)) is default:
            return value
        T = self._array(key, value)
        if T.shape != (4, 4):
            raise ConfigError(f"{self.where}.{key}: expected a 4x4 matrix (4 rows of 4), got shape {T.shape}")
        if not np.allclose(T[3], [0, 0, 0, 1]):
            raise ConfigError(f"{self.where}.{key}: last row must be [0, 0, 0, 1], got {T[3].tolist()}")
        R = T[:3, :3]
        defect = float(np.max(np.abs(R.T @ R - np.eye(3))))
        if defect > MATRIX_TOL or np.linalg.det(R) < 0:
            raise ConfigError(f"{self.where}.{key}: rotation part is not a rotation (|R^T R - I| = {defect:.2g}, "
                              f"det = {np.linalg.det(R):.4f})")
        T = T.copy()
        T[:3, :3] = orthonormalize(R)
        return T

    # --- private -----------------------------------------------------------------------------------

    def _missing(self, key: str, table: bool = False) -> ConfigMissingKey:
        close = difflib.get_close_matches(key, [k for k in self.raw if k not in self.known], n=1)
        hint = f" ({close[0]!r} is there: a misspelling?)" if close else ""
        if not self.name:
            return ConfigMissingKey(f"{self.where}: [{key}]: missing, a required section{hint}")
        if table:
            return ConfigMissingKey(f"{self.file}: [{self.name}.{key}]: missing, a required table{hint}")
        return ConfigMissingKey(f"{self.where}.{key}: missing{hint}")

    def _child(self, key: str, value: Any) -> ConfigTable:
        return ConfigTable(value, self.file, f"{self.name}.{key}" if self.name else key)

    def _array(self, key: str, value: Any) -> np.ndarray:
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{self.where}.{key} = {value!r}: expected numbers") from exc
        if not np.all(np.isfinite(arr)):
            raise ConfigError(f"{self.where}.{key} = {value!r}: numbers must be finite")
        return arr

    def _pop(self, key: str, default: Any) -> Any:
        self.known.add(key)
        if key in self.raw:
            return self.raw.pop(key)
        if default is _MISSING:
            raise self._missing(key)
        return default


def _plain(value: float) -> str:
    """A bound as people write it: ``600``, ``0.05``, ``4000000`` (never ``4e+06``)."""
    if float(value).is_integer():
        return str(int(value))
    return f"{value:g}"
