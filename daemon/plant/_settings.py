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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from monoguide.daemon.config import read_config_toml
from monoguide.daemon.errors import ConfigMissingKey, ConfigUnknownKey, PlantMetricsAuthRequired
from monoguide.daemon.plant._metrics_access import MetricsAccess, read_metrics_access
from monoguide.daemon.plant._passwords import hash_problem
from monoguide.drivers.errors import ConfigError

PKI_DIR = "plant"  # under the service's state directory, unless [plant] pki_dir says otherwise
DEFAULT_OPCUA_PORT = 4840  # IANA's port of OPC UA TCP
DEFAULT_METRICS_PORT = 9840
_KEYS = ("opcua_host", "opcua_port", "metrics_host", "metrics_port", "last_results", "poll_s", "anonymous",
         "pki_dir", "trusted_certificates", "users", "metrics_web", "max_connections", "max_connections_per_client",
         "max_sessions", "max_sessions_per_client", "max_subscriptions", "max_subscriptions_per_client",
         "hello_timeout_s", "activation_timeout_s", "session_timeout_s", "login_failures", "login_window_s",
         "metrics_max_connections", "metrics_max_connections_per_client", "metrics_timeout_s", "refusal_log_s",
         "machine_vision_nodeset")


@dataclass(frozen=True)
class PlantLimits:
    """What one client (an IP address) and all of them together may hold, and how long a stranger may wait.

    Counts per client are per source address: a SCADA server's sessions all come from one. The defaults hold a cell's
    few plant clients with room to spare and keep the process far from its file descriptor limit (``LimitNOFILE``
    of systemd/monoguide-plant.service): each OPC UA connection costs three descriptors (docs/opcua.md)."""

    connections: int = 64  # OPC UA TCP connections at once, all clients
    connections_per_client: int = 8
    sessions: int = 64  # OPC UA sessions (created or activated, until closed or timed out)
    sessions_per_client: int = 10
    subscriptions: int = 128
    subscriptions_per_client: int = 20
    hello_timeout_s: float = 5.0  # a new connection's Hello, then its OpenSecureChannel, each within this
    activation_timeout_s: float = 10.0  # a connection without an activated session is closed after this
    session_timeout_s: float = 120.0  # the longest session timeout granted (a client asks for its own)
    login_failures: int = 5  # failed logins of one client within login_window_s before it must wait
    login_window_s: float = 60.0
    metrics_connections: int = 16
    metrics_connections_per_client: int = 4
    metrics_timeout_s: float = 5.0  # a scrape's request (TLS handshake, headers) must arrive within this
    refusal_log_s: float = 60.0  # what was refused is logged at most once per this interval


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
    limits: PlantLimits = PlantLimits()
    metrics_access: MetricsAccess = field(default_factory=MetricsAccess)
    machine_vision_nodeset: Path | None = None  # Opc.Ua.MachineVision.NodeSet2.xml as published: needed to serve

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
        limits=_limits(where, t),
        metrics_access=read_metrics_access(path, where, t.get("metrics_web", {})),
        machine_vision_nodeset=_path(path, where, t, "machine_vision_nodeset", "a file"),
    )
    if out.anonymous and not is_loopback(opcua_host):
        raise ConfigError(f"{where}.anonymous = true with opcua_host = {opcua_host!r}: an anonymous identity is "
                          "allowed on a loopback address only (127.0.0.0/8, ::1); a plant network needs users or "
                          "client certificates")
    if not is_loopback(out.metrics_host) and not out.metrics_access.complete:
        raise PlantMetricsAuthRequired(
            f"{where}.metrics_host = {out.metrics_host!r} without [plant.metrics_web] tls_server_config and "
            "basic_auth_users: the metrics leave loopback only over TLS with basic authentication (docs/metrics.md)")
    return out


def _limits(where: str, t: dict[str, Any]) -> PlantLimits:
    d = PlantLimits()
    out = PlantLimits(
        connections=_integer(where, t, "max_connections", d.connections, 1, 10_000),
        connections_per_client=_integer(where, t, "max_connections_per_client", d.connections_per_client, 1, 10_000),
        sessions=_integer(where, t, "max_sessions", d.sessions, 1, 10_000),
        sessions_per_client=_integer(where, t, "max_sessions_per_client", d.sessions_per_client, 1, 10_000),
        subscriptions=_integer(where, t, "max_subscriptions", d.subscriptions, 1, 100_000),
        subscriptions_per_client=_integer(where, t, "max_subscriptions_per_client", d.subscriptions_per_client, 1,
                                          100_000),
        hello_timeout_s=_number(where, t, "hello_timeout_s", d.hello_timeout_s, 0.1, 60.0),
        activation_timeout_s=_number(where, t, "activation_timeout_s", d.activation_timeout_s, 0.5, 600.0),
        session_timeout_s=_number(where, t, "session_timeout_s", d.session_timeout_s, 10.0, 3600.0),
        login_failures=_integer(where, t, "login_failures", d.login_failures, 1, 1000),
        login_window_s=_number(where, t, "login_window_s", d.login_window_s, 1.0, 3600.0),
        metrics_connections=_integer(where, t, "metrics_max_connections", d.metrics_connections, 1, 1000),
        metrics_connections_per_client=_integer(where, t, "metrics_max_connections_per_client",
                                                d.metrics_connections_per_client, 1, 1000),
        metrics_timeout_s=_number(where, t, "metrics_timeout_s", d.metrics_timeout_s, 0.1, 60.0),
        refusal_log_s=_number(where, t, "refusal_log_s", d.refusal_log_s, 0.1, 3600.0),
    )
    for total, each, names in ((out.connections, out.connections_per_client, "max_connections"),
                               (out.sessions, out.sessions_per_client, "max_sessions"),
                               (out.subscriptions, out.subscriptions_per_client, "max_subscriptions"),
                               (out.metrics_connections, out.metrics_connections_per_client,
                                "metrics_max_connections")):
        if each > total:
            raise ConfigError(f"{where}.{names}_per_client = {each}: more than {names} = {total}, the total of all "
                              "clients")
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


def _path(path: Path, where: str, t: dict[str, Any], key: str, what: str = "a directory") -> Path | None:
    if key not in t:
        return None
    value = t[key]
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{where}.{key} = {value!r}: expected {what}")
    found = Path(value)
    return found if found.is_absolute() else path.parent / found
