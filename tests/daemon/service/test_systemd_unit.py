"""systemd/monoguide.service: the keys the service needs, and systemd's own verifier finds nothing to say."""

from __future__ import annotations

import re
import shutil
import subprocess
from collections import defaultdict
from pathlib import Path

import pytest

UNIT = Path(__file__).parents[3] / "systemd" / "monoguide.service"
ANALYZE = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(ANALYZE is None, reason="systemd-analyze not installed")


def _parse(text: str) -> dict[str, dict[str, list[str]]]:
    """Sections of key -> every value (systemd keys repeat, e.g. DeviceAllow=); no configparser, which
    refuses repeated keys and would lower-case them."""
    sections: dict[str, dict[str, list[str]]] = defaultdict(lambda: defaultdict(list))
    section = ""
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            section = line.strip("[]")
            continue
        key, _, value = line.partition("=")
        sections[section][key.strip()].append(value.strip())
    return sections


UNIT_KEYS = _parse(UNIT.read_text())
SERVICE = UNIT_KEYS["Service"]


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("Type", "notify"),
        ("ExecStart", "/usr/bin/env monoguide run --config /etc/monoguide/cell.toml"),
        ("ExecStopPost", "/usr/bin/env monoguide run --config /etc/monoguide/cell.toml --clear-status"),
        ("User", "monoguide"),
        ("DynamicUser", "no"),
        ("SupplementaryGroups", "dialout"),
        ("StateDirectory", "monoguide"),
        ("ConfigurationDirectory", "monoguide"),
        ("ProtectSystem", "strict"),
        ("NoNewPrivileges", "yes"),
        ("PrivateTmp", "yes"),
        ("DevicePolicy", "closed"),
        ("PrivateDevices", "no"),  # yes would hide the tracker's serial line
    ],
)
def test_the_required_keys(key: str, value: str) -> None:
    assert SERVICE[key] == [value]


def test_watchdog_and_serial_devices_and_network() -> None:
    assert re.fullmatch(r"\d+s", SERVICE["WatchdogSec"][0])
    assert set(SERVICE["DeviceAllow"]) == {"char-ttyUSB rw", "char-ttyS rw", "char-ttyACM rw"}
    families = set(SERVICE["RestrictAddressFamilies"][0].split())
    assert {"AF_INET", "AF_INET6", "AF_UNIX", "AF_NETLINK"} <= families  # TCP/UDP devices, sd_notify, GigE discovery
    assert "IPAddressDeny" not in SERVICE and "PrivateNetwork" not in SERVICE


@needs_analyze
def test_systemd_analyze_verify_is_silent() -> None:
    done = subprocess.run([ANALYZE, "verify", str(UNIT)], capture_output=True, text=True, timeout=30)
    assert (done.returncode, done.stderr, done.stdout) == (0, "", "")


@needs_analyze
def test_verify_would_see_a_misspelt_key(tmp_path: Path) -> None:
    broken = tmp_path / "monoguide.service"
    broken.write_text(UNIT.read_text().replace("ProtectHome=yes", "ProtectHomee=yes"))
    done = subprocess.run([ANALYZE, "verify", str(broken)], capture_output=True, text=True, timeout=30)
    assert "Unknown key 'ProtectHomee'" in done.stderr
