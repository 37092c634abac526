"""systemd/monoguide-plant.service: the plant's own unit, hardened as the service's, and systemd's own verifier
finds nothing to say. The hardening keys it shares with systemd/monoguide.service are held equal to those."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

SYSTEMD = Path(__file__).parents[3] / "systemd"
UNIT = SYSTEMD / "monoguide-plant.service"
ANALYZE = shutil.which("systemd-analyze")
SHARED = ("User", "DynamicUser", "ProtectSystem", "ProtectHome", "PrivateTmp", "NoNewPrivileges",
          "CapabilityBoundingSet", "AmbientCapabilities", "RestrictSUIDSGID", "LockPersonality", "RestrictRealtime",
          "RestrictNamespaces", "RemoveIPC", "ProtectKernelTunables", "ProtectKernelModules", "ProtectKernelLogs",
          "ProtectControlGroups", "ProtectClock", "ProtectHostname", "ProtectProc", "SystemCallArchitectures",
          "SystemCallFilter", "SystemCallErrorNumber", "DevicePolicy", "ConfigurationDirectory")


def _keys(path: Path) -> dict[str, list[str]]:
    keys: dict[str, list[str]] = {}
    for line in path.read_text().splitlines():
        line = line.strip()
        if line and not line.startswith(("#", ";", "[")):
            key, _, value = line.partition("=")
            keys.setdefault(key.strip(), []).append(value.strip())
    return keys


def test_the_plant_unit_is_hardened_as_the_service() -> None:
    plant, service = _keys(UNIT), _keys(SYSTEMD / "monoguide.service")
    for key in SHARED:
        assert plant.get(key) == service.get(key), key
    assert plant["ExecStart"] == ["/usr/bin/env monoguide plant --config /etc/monoguide/cell.toml "
                                  "--plant-config /etc/monoguide/plant.toml"]
    assert plant["PrivateDevices"] == ["yes"] and "DeviceAllow" not in plant and "SupplementaryGroups" not in plant
    assert plant["RestrictAddressFamilies"] == ["AF_UNIX AF_INET AF_INET6"]


@pytest.mark.skipif(ANALYZE is None, reason="systemd-analyze not installed")
def test_systemd_analyze_verify_is_silent() -> None:
    done = subprocess.run([ANALYZE, "verify", str(UNIT)], capture_output=True, text=True, timeout=30)
    assert (done.returncode, done.stderr, done.stdout) == (0, "", "")


@pytest.mark.parametrize("unit", ["monoguide-plant.service", "monoguide-web.service"])
def test_the_listening_units_raise_the_open_file_limit(unit: str) -> None:
    """systemd's default soft limit (1024) is what a flood of idle connections exhausted; both listening units raise
    it well past what their connection limits hold (test_wire_security.py runs the plant under this value)."""
    assert [int(v) for v in _keys(SYSTEMD / unit).get("LimitNOFILE", ["1024"])] == [8192]
