"""The plant interfaces' own file (``monoguide plant --plant-config PLANT.toml``, docs/opcua.md): its ``[plant]``
table, typed and checked when it is read.

It is a file of its own, not a section of the cell config: it holds the OPC UA users' password hashes and the trust
list, which belong to whoever runs the plant interfaces (mode 0640), not to the cell config that `monoguide
calibrate` rewrites and that is copied from cell to cell. Without the file every default holds: OPC UA on
127.0.0.1:4840, metrics on 127.0.0.1:9840, no users, no anonymous session — nobody can log in until a user or a
trusted client certificate is configured.
"""

from __future__ import annotations

import difflib
import ipaddress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from monoguide.daemon.config import read_config_toml
from monoguide.daemon.errors import ConfigMissingKey, ConfigUnknownKey
from monoguide.daemon.plant._passwords import hash_problem
from monoguide.drivers.errors import ConfigError

PKI_DIR = "plant"  # under the service's state directory, unless [plant] pki_dir says otherwise
DEFAULT_OPCUA_PORT = 4840  # IANA's port of OPC UA TCP
DEFAULT_METRICS_PORT = 9840
_KEYS = ("opcua_host", "opcua_port", "metrics_host", "metrics_port", "last_results", "poll_s", "anonymous",
         "pki_dir", "trusted_certificates", "users")


@dataclass(frozen=True)
class PlantUser:
    name: str
    password_hash: str  # _passwords.hash_password's form


@dataclass(frozen=True)
class PlantSettings:
    """``[plant]``; ``pki_dir`` None: ``<state dir>/plant``; ``trusted_certificates`` None: ``<pki_dir>/trusted``."""

    opcua_host: str = "127.0.0.1"
    opcua_port: int = DEFAULT_OPCUA_PORT
    metrics_host: str = "127.0.0.1"
    metrics_port: int = DEFAULT_METRICS_PORT
    last_results: int = 10  # N: the newest results as variables under ResultManagement/Results
    poll_s: float = 0.1  # how often the journal's counter and the status file are looked at
    anonymous: bool = False  # an anonymous identity (on top of a trusted, encrypted channel): loopback hosts only
    pki_dir: Path | None = None
    trusted_certificates: Path | None = None
    users: tuple[PlantUser, ...] = ()

    def pki(self, state_dir: Path) -> Path:
        return self.pki_dir if self.pki_dir is not None else state_dir / PKI_DIR

    def trust_dir(self, state_dir: Path) -> Path:
        return self.trusted_certificates if self.trusted_certificates is not None else self.pki(state_dir) / "trusted"


def load_plant_settings(path: Path | None) -> PlantSettings:
    """The settings of ``path`` (its ``[plant]`` table); the defaults when ``path`` is None. Raises a
    :class:`ConfigError` naming the key, the value and why."""
    if path is None:
        return PlantSettings()
    raw = read_config_toml(path, "plant file")  # a regular file of at most 4 MiB, else refused unread
    _reject_unknown(f"{path}", raw, ("plant",))
    if "plant" not in raw:
        raise ConfigMissingKey(f"{path}: [plant]: missing (the plant file holds one [plant] table)")
    return _read(path, raw["plant"])


def is_loopback(host: str) -> bool:
    return ipaddress.ip_address(host).is_loopback


# --- private ------------------------------------------------------------------------------------


def _read(path: Path, t: Any) -> PlantSettings:
    where = f"{path}: [plant]"
    if not isinstance(t, dict):
        raise ConfigError(f"{where}: expected a table")
    _reject_unknown(where, t, _KEYS)
    d = PlantSettings()
    opcua_host = _host(where, t, "opcua_host", d.opcua_host)
    out = PlantSettings(
        opcua_host=opcua_host,
        opcua_port=_integer(where, t, "opcua_port", d.opcua_port, 1, 65535),
        metrics_host=_host(where, t, "metrics_host", d.metrics_host),
        metrics_port=_integer(where, t, "metrics_port", d.metrics_port, 1, 65535),
        last_results=_integer(where, t, "last_results", d.last_results, 1, 100),
        poll_s=_number(where, t, "poll_s", d.poll_s, 0.02, 5.0),
        anonymous=_boolean(where, t, "anonymous", d.anonymous),
        pki_dir=_path(path, where, t, "pki_dir"),
        trusted_certificates=_path(path, where, t, "trusted_certificates"),
        users=_users(where, t.get("users", [])),
    )
    if out.anonymous and not is_loopback(opcua_host):
        raise ConfigError(f"{where}.anonymous = true with opcua_host = {opcua_host!r}: an anonymous identity is "
                          "allowed on a loopback address only (127.0.0.0/8, ::1); a plant network needs users or "
                          "client certificates")
    return out


def _users(where: str, raw: Any) -> tuple[PlantUser, ...]:
    if not isinstance(raw, list):
        raise ConfigError(f"{where}.users: expected [[plant.users]] tables, got {raw!r}")
    users, names = [], set()
    for i, entry in enumerate(raw):
        at = f"{where}.users[{i}]"
        if not isinstance(entry, dict):
            raise ConfigError(f"{at}: expected a table with name and password_hash")
        _reject_unknown(at, entry, ("name", "password_hash"))
        for key in ("name", "password_hash"):
            if key not in entry:
                raise ConfigMissingKey(f"{at}.{key}: missing")
            if not isinstance(entry[key], str) or not entry[key].strip():
                raise ConfigError(f"{at}.{key} = {entry[key]!r}: expected a non-empty string")
        if entry["name"] in names:
            raise ConfigError(f"{at}.name = {entry['name']!r}: a second user of that name")
        if problem := hash_problem(entry["password_hash"]):
            raise ConfigError(f"{at}.password_hash: {problem}")
        names.add(entry["name"])
        users.append(PlantUser(entry["name"], entry["password_hash"]))
    return tuple(users)


def _reject_unknown(where: str, table: dict[str, Any], known: tuple[str, ...]) -> None:
    for key in table:
        if key not in known:
            close = difflib.get_close_matches(key, known, n=1)
            hint = f"did you mean {close[0]}?" if close else f"known: {', '.join(known)}"
            raise ConfigUnknownKey(f"{where}.{key}: unknown key; {hint}")


def _host(where: str, t: dict[str, Any], key: str, default: str) -> str:
    value = t.get(key, default)
    try:
        ipaddress.ip_address(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}.{key} = {value!r}: expected an IP address to listen on (127.0.0.1, 0.0.0.0, "
                          "the cell PC's plant-network address)") from None
    return str(value)


def _integer(where: str, t: dict[str, Any], key: str, default: int, low: int, high: int) -> int:
    value = t.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ConfigError(f"{where}.{key} = {value!r}: expected a whole number {low} to {high}")
    return value


def _number(where: str, t: dict[str, Any], key: str, default: float, low: float, high: float) -> float:
    value = t.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
        raise ConfigError(f"{where}.{key} = {value!r}: expected a number {low:g} to {high:g} s")
    return float(value)


def _boolean(where: str, t: dict[str, Any], key: str, default: bool) -> bool:
    value = t.get(key, default)
    if not isinstance(value, bool):
        raise ConfigError(f"{where}.{key} = {value!r}: expected true or false")
    return value


def _path(path: Path, where: str, t: dict[str, Any], key: str) -> Path | None:
    if key not in t:
        return None
    value = t[key]
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{where}.{key} = {value!r}: expected a directory")
    found = Path(value)
    return found if found.is_absolute() else path.parent / found
