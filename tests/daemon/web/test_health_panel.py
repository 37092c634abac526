"""The calibration health on the *Now* and *Calibration* pages of a real ``monoguide web`` process: from the status
file's ``calibration_health`` as the service's own health monitor (``CalibrationHealth``) summarises it, from the
service's ``calibration-health.json`` when the status file has none, "not available" when neither is there; and a
status file holding NaN does not take ``/now.json`` down."""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Iterator
from html import unescape
from pathlib import Path
from typing import Any

import pytest
from helpers.repository import SIM_CELL
from helpers.web_pages import request, web_process

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.cycle import Residual
from monoguide.daemon.service import STATUS_FILE, ServiceStatus, write_status
from monoguide.daemon.service._health import HEALTH_FILE, CalibrationHealth
from monoguide.solver.errors import CalibrationSuspect

HOST, PORT = "127.0.26.4", 8265
AT = "2026-12-01T10:00:00+00:00"


@pytest.fixture(scope="module")
def state_dir(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    state = tmp_path_factory.mktemp("health") / "state"
    state.mkdir()
    with web_process(state, HOST, PORT, "--config", str(SIM_CELL)):
        yield state


@pytest.fixture
def fresh(state_dir: Path) -> Path:
    for name in (STATUS_FILE, HEALTH_FILE):
        (state_dir / name).unlink(missing_ok=True)
    return state_dir


def _status(state_dir: Path, health: dict[str, Any] | None) -> None:
    now = time.time()
    write_status(state_dir, ServiceStatus("idle", now, os.getpid(), now, 1.0, calibration_health=health))


def _now_health() -> dict[str, Any]:
    answer = request(HOST, PORT, "/now.json")
    assert answer.status == 200
    return json.loads(answer.body)["health"]


def _page(path: str) -> str:
    answer = request(HOST, PORT, path)
    assert answer.status == 200, answer.text[:300]
    return answer.text


def test_the_status_files_health_is_shown(fresh: Path) -> None:
    health = CalibrationHealth(fresh, load_cell_config(SIM_CELL))
    for k in range(1, 6):
        reading = health.observe(1, k, AT, Residual(2.0, 2))
    assert not reading.warning
    _status(fresh, health.summary())
    facts = _now_health()
    assert facts["level"] == "ok" and facts["summary"].startswith("ok") and "running service" in facts["summary"]
    assert re.search(r'id="health" class="health-ok">ok', _page("/"))
    html = _page("/calibration")
    row = re.search(r'<tr data-job="1">(.*?)</tr>', html, re.S)
    assert row is not None
    cells = re.findall(r'<td class="num">([^<]*)</td>', row.group(1))
    assert cells == [f"{reading.statistic:.2f}", f"{reading.warning_level:.2f}", f"{reading.alarm_level:.2f}", "5"]

    with pytest.raises(CalibrationSuspect):
        for k in range(6, 60):
            health.observe(1, k, AT, Residual(40.0, 2))
    latched = health.summary()["latched"]
    _status(fresh, health.summary())
    facts = _now_health()
    assert facts["level"] == "alarm" and f"CALIBRATION_SUSPECT since cycle {latched['cycle']}" in facts["summary"]
    html = _page("/calibration")
    assert 'class="health-alarm"' in html and latched["message"] in unescape(html)
    assert 'id="health-latched"' in html


def test_without_it_in_the_status_file_the_services_health_file_is_read(fresh: Path) -> None:
    health = CalibrationHealth(fresh, load_cell_config(SIM_CELL))
    health.wait_ready()
    health.latch(CalibrationSuspect("job 1: a check job failed: the camera moved 0.4 mm"), 17, AT, 1)
    _status(fresh, None)
    facts = _now_health()
    assert facts["level"] == "alarm" and "since cycle 17" in facts["summary"] and HEALTH_FILE in facts["summary"]
    assert "the camera moved 0.4 mm" in _page("/calibration")
    health.clear("inspected")
    facts = _now_health()
    assert facts["level"] is None and facts["summary"].startswith("no alarm latched")


def test_neither_is_not_available(fresh: Path) -> None:
    facts = _now_health()
    assert facts["level"] is None and facts["summary"].startswith("not available")
    assert "no service has written a status file" in facts["summary"]
    _status(fresh, None)
    assert "the service's status file carries none" in _now_health()["summary"]


def test_a_status_file_holding_nan_answers_strict_json(fresh: Path) -> None:
    now = time.time()
    status = ServiceStatus("idle", now, os.getpid(), now, 1.0, plc={"heartbeat": 3, "job": 1},
                           calibration_health={"warning": False, "monitors": {"1": {"statistic": 1.0}}}).as_dict()
    status["plc"]["heartbeat"] = float("nan")
    status["calibration_health"]["monitors"]["1"]["statistic"] = float("inf")
    (fresh / STATUS_FILE).write_text(json.dumps(status, allow_nan=True))
    answer = request(HOST, PORT, "/now.json")
    assert answer.status == 200
    facts = json.loads(answer.body, parse_constant=lambda name: pytest.fail(f"{name} in /now.json"))
    assert facts["service"]["plc"]["heartbeat"] is None and facts["health"]["level"] == "ok"
    assert _page("/").count('id="health"') == 1
