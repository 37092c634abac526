"""The metrics endpoint scraped over HTTP and read with Prometheus' own parser: the cycle counters equal the seeded
journal's rows by status and error code, before and after cycles are committed while it runs."""

from __future__ import annotations

import time
import urllib.request
from collections import Counter
from pathlib import Path

import pytest
from helpers.plant_cells import PlantCell, seeded_entries
from prometheus_client.parser import text_string_to_metric_families

from monoguide.daemon.plant import load_plant_settings
from monoguide.daemon.service import CycleEntry, Journal

HOST, PORT = "127.0.82.1", 48201


def _scrape(url: str) -> dict[str, dict[tuple[tuple[str, str], ...], float]]:
    with urllib.request.urlopen(url, timeout=5) as answer:
        text = answer.read().decode()
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
    for axis, value in zip("xyzabc", last["base_offset_xyzabc"], strict=True):
        assert after["monoguide_base_offset"][(("axis", axis),)] == pytest.approx(value)
    assert after["monoguide_reprojection_rms_pixels"][()] == pytest.approx(last["rms_px"])
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
