"""The metrics endpoint scraped over HTTP and read with Prometheus' own parser: the cycle counters equal the seeded
journal's rows by status and error code, before and after cycles are committed while it runs; every value in
Prometheus' base unit (the journal's mm and deg converted), one unit a metric, no ``_created`` series, and the
metrics exactly those docs/metrics.md lists; beyond loopback only over TLS with basic authentication."""

from __future__ import annotations

import base64
import math
import re
import ssl
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections import Counter
from pathlib import Path

import bcrypt
import pytest
from helpers.plant_cells import PlantCell, plant_file, seeded_entries
from helpers.plant_clients import start_plant
from helpers.repository import SIM_CELL
from helpers.sim_processes import stop
from prometheus_client.parser import text_string_to_metric_families

from monoguide.daemon.plant import load_plant_settings
from monoguide.daemon.service import CycleEntry, Journal

HOST, PORT = "127.0.82.1", 48201


DOC = Path(__file__).parents[3] / "docs" / "metrics.md"


def _text(url: str) -> str:
    with urllib.request.urlopen(url, timeout=5) as answer:
        return answer.read().decode()


def _scrape(url: str) -> dict[str, dict[tuple[tuple[str, str], ...], float]]:
    text = _text(url)
    samples: dict[str, dict[tuple[tuple[str, str], ...], float]] = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            samples.setdefault(sample.name, {})[tuple(sorted(sample.labels.items()))] = sample.value
    return samples


def _expected(entries: list[CycleEntry]) -> Counter[tuple[str, str]]:
    return Counter(("error", e.error.code) if e.error else ("ok", "none") for e in entries)


def _counters(samples: dict[str, dict[tuple[tuple[str, str], ...], float]]) -> Counter[tuple[str, str]]:
    found: Counter[tuple[str, str]] = Counter()
    for labels, n in samples["monoguide_cycles_total"].items():
        found[(dict(labels)["status"], dict(labels)["error_code"])] = int(n)
    return found


def test_the_counters_match_the_journal(plant_cell: PlantCell) -> None:
    before = _scrape(plant_cell.metrics_url)
    assert _counters(before) == _expected(plant_cell.seeded)
    assert before["monoguide_journal_cycle_counter"][()] == len(plant_cell.seeded)
    assert before["monoguide_service_running"][()] == 1
    assert before["monoguide_device_connected"][(("device", "robot"),)] == 0
    assert before["monoguide_calibration_health_level"][()] != before["monoguide_calibration_health_level"][()]  # NaN

    new = seeded_entries(8, time.time())
    with Journal(plant_cell.state_dir) as journal:
        for entry in new:
            journal.commit_cycle(entry)
    deadline = time.monotonic() + 10.0
    while True:
        after = _scrape(plant_cell.metrics_url)
        if after["monoguide_last_cycle"][()] == len(plant_cell.seeded) + len(new) or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    assert _counters(after) == _expected(plant_cell.seeded + new)
    assert after["monoguide_cycle_seconds_count"][()] == len(new)
    assert after["monoguide_cycle_seconds_sum"][()] == pytest.approx(sum(e.timings_s["cycle"] for e in new))
    good = [e for e in new if e.error is None]
    assert after["monoguide_cycle_overhead_seconds_count"][()] == len(good)
    last = good[-1].result
    x, y, z, a, b, c = last["base_offset_xyzabc"]  # the journal's mm and deg
    for axis, mm in zip("xyz", (x, y, z), strict=True):
        assert after["monoguide_base_offset_translation_metres"][(("axis", axis),)] == pytest.approx(mm / 1000.0)
    for axis, deg in zip("abc", (a, b, c), strict=True):
        assert after["monoguide_base_offset_rotation_radians"][(("axis", axis),)] == pytest.approx(math.radians(deg))
    assert after["monoguide_reprojection_rms_pixels"][()] == pytest.approx(last["rms_px"])
    assert after["monoguide_sigma_position_metres"][()] == pytest.approx(last["sigma_trans_mm"] / 1000.0)
    assert after["monoguide_sigma_rotation_radians"][()] == pytest.approx(math.radians(last["sigma_rot_deg"]))
    assert after["monoguide_journal_bytes"][()] >= (plant_cell.state_dir / "journal.sqlite3").stat().st_size


def _level_becomes(plant_cell: PlantCell, wanted: float) -> float:
    deadline = time.monotonic() + 10.0
    while True:
        level = _scrape(plant_cell.metrics_url)["monoguide_calibration_health_level"][()]
        if level == wanted or time.monotonic() > deadline:
            return level
        time.sleep(0.1)


def test_the_calibration_health_level_follows_the_service(plant_cell: PlantCell) -> None:
    assert plant_cell.beat is not None
    latched = {"code": "CALIBRATION_SUSPECT", "message": "job 1: the residual's trend passed its alarm level",
               "cycle": 17, "at": "2026-12-01T10:00:00+00:00", "job": 1}
    try:
        plant_cell.beat.health = {"latched": None, "warning": True, "monitors": {}}
        assert _level_becomes(plant_cell, 1.0) == 1.0
        plant_cell.beat.health = {"latched": latched, "warning": True, "monitors": {}}
        assert _level_becomes(plant_cell, 2.0) == 2.0
        plant_cell.beat.health = {"latched": None, "warning": False, "monitors": {}}
        assert _level_becomes(plant_cell, 0.0) == 0.0
    finally:
        plant_cell.beat.health = None


def test_the_metrics_listen_on_loopback_unless_told(tmp_path: Path) -> None:
    plant_toml = tmp_path / "plant.toml"
    plant_toml.write_text("[plant]\nopcua_port = 48299\n")
    settings = load_plant_settings(plant_toml)
    assert (settings.metrics_host, settings.opcua_host) == ("127.0.0.1", "127.0.0.1")
    assert settings.users == () and settings.anonymous is False


def test_the_metrics_are_those_the_document_states(plant_cell: PlantCell) -> None:
    """Each family served is a row of docs/metrics.md with its type, each row is served; a monoguide metric's name
    ends in one base unit or none; no ``_created`` series."""
    text = _text(plant_cell.metrics_url)
    assert "_created" not in text
    served = {f.name: f.type for f in text_string_to_metric_families(text)}
    stated: dict[str, str] = {}
    for row in re.findall(r"^\| `([a-z_]+)` \| (counter|gauge|histogram) \|", DOC.read_text(), re.MULTILINE):
        stated[row[0].removesuffix("_total") if row[1] == "counter" else row[0]] = row[1]
    assert served == stated
    units = ("_metres", "_radians", "_seconds", "_bytes", "_pixels")
    for name in served:
        if name.startswith("monoguide_"):
            assert sum(unit in name for unit in units) <= 1, name
            assert not re.search(r"_(millimetres|degrees|mm|deg|ms)(_|$)", name), name


def test_off_loopback_without_tls_and_basic_auth_is_refused(tmp_path: Path) -> None:
    plant_toml = tmp_path / "plant.toml"
    plant_toml.write_text('[plant]\nmetrics_host = "0.0.0.0"\n')
    done = subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "plant", "--config", str(SIM_CELL),
                           "--state-dir", str(tmp_path / "state"), "--plant-config", str(plant_toml)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines()[-1].split(": ", 1)[1].startswith(
        f"PLANT_METRICS_AUTH_REQUIRED {plant_toml}: [plant].metrics_host = '0.0.0.0' without"), done.stderr


def test_tls_and_basic_auth_in_the_exporter_toolkit_shape(tmp_path: Path) -> None:
    """[plant.metrics_web]: the scrape over TLS with the right user and password (bcrypt), 401 without or with a
    wrong one, 429 after login_failures wrong ones; nothing in clear."""
    host, port = "127.0.82.2", 48211
    cert, key = tmp_path / "metrics.crt", tmp_path / "metrics.key"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out",
                    str(cert), "-days", "2", "-subj", f"/CN={host}", "-addext", f"subjectAltName=IP:{host}"],
                   check=True, capture_output=True)
    hashed = {user: bcrypt.hashpw(b"scrape me", bcrypt.gensalt(4)).decode().replace("$2b$", "$2y$", 1)  # the toolkit's
              for user in ("prometheus", "grafana")}
    extra = (f"login_failures = 3\n[plant.metrics_web.tls_server_config]\ncert_file = \"{cert}\"\n"
             f"key_file = \"{key}\"\n[plant.metrics_web.basic_auth_users]\n"
             + "".join(f'{user} = "{h}"\n' for user, h in hashed.items()))
    process, line = start_plant(SIM_CELL, tmp_path / "state", plant_file(tmp_path / "plant.toml", host, port, extra),
                                tmp_path / "plant.log")
    try:
        url = line.split()[4]
        assert url == f"https://{host}:{port + 1}/metrics"
        context = ssl.create_default_context(cafile=str(cert))

        def scrape(user: str | None, password: str = "") -> int:
            headers = {} if user is None else {
                "Authorization": "Basic " + base64.b64encode(f"{user}:{password}".encode()).decode()}
            try:
                with urllib.request.urlopen(urllib.request.Request(url, headers=headers), context=context,
                                            timeout=10) as answer:
                    assert b"monoguide_cycles_total" in answer.read()
                    return answer.status
            except urllib.error.HTTPError as refused:
                return refused.code

        assert scrape("prometheus", "scrape me") == 200
        assert scrape("prometheus", "scrape me") == 200  # remembered: no bcrypt again
        assert scrape(None) == 401
        assert scrape("prometheus", "wrong") == 401
        assert scrape("nobody", "scrape me") == 401
        assert scrape("grafana", "scrape me") == 429  # three failures from this address: it waits...
        assert scrape("prometheus", "scrape me") == 200  # ...but a header it proved before is still good
        with pytest.raises(OSError):  # no answer in clear
            urllib.request.urlopen(url.replace("https", "http"), timeout=5)
    finally:
        stop(process)
