"""The Prometheus rules and the Grafana dashboard monoguide ships (package data, config/prometheus/): checked and
unit-tested with promtool, the dashboard's queries held to the metrics served, and a real Prometheus server
(Debian's `prometheus`) scraping three `monoguide plant` processes on recorded journals, where the cell whose
calibration alarm is latched raises MonoguideCalibrationSuspect and the others raise nothing."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import time
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from helpers.plant_cells import StatusBeat, plant_file, seeded_entries, write_journal
from helpers.plant_clients import start_plant
from helpers.repository import ROOT, SIM_CELL
from helpers.sim_processes import stop

from monoguide.daemon.packaged import config_file

PROMETHEUS_HOST, PROMETHEUS_PORT = "127.0.87.1", 49090
CELLS = (("127.0.87.11", 48711), ("127.0.87.12", 48721), ("127.0.87.13", 48731))
SUSPECT = 1  # the cell whose calibration alarm is latched
RULES, DASHBOARD = "prometheus/monoguide-rules.yml", "prometheus/monoguide-dashboard.json"
RULES_TEST = Path(__file__).parent / "prometheus" / "monoguide-rules-test.yml"
FIRING_S = 60.0


def _tool(name: str) -> str:
    found = shutil.which(name)
    if found is None:
        pytest.fail(f"{name} is not installed: apt-get install -y prometheus (.ci/run installs it)")
    return found


@pytest.mark.prometheus
def test_the_shipped_rules_pass_promtool_check_and_their_unit_tests() -> None:
    rules = config_file(RULES)
    assert rules.is_file() and config_file(DASHBOARD).is_file()
    checked = subprocess.run([_tool("promtool"), "check", "rules", str(rules)], capture_output=True, text=True,
                             timeout=60)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    assert "SUCCESS: 11 rules found" in checked.stdout
    tested = subprocess.run([_tool("promtool"), "test", "rules", RULES_TEST.name], cwd=RULES_TEST.parent,
                            capture_output=True, text=True, timeout=60)
    assert tested.returncode == 0, tested.stdout + tested.stderr
    assert "SUCCESS" in tested.stdout


def test_the_dashboard_asks_only_for_what_is_served_or_recorded() -> None:
    dashboard = json.loads(config_file(DASHBOARD).read_text())
    documented = set(re.findall(r"^\| `([a-z_:]+)` \|", (ROOT / "docs" / "metrics.md").read_text(), re.MULTILINE))
    recorded = set(re.findall(r"record: ([a-z_:0-9]+)", config_file(RULES).read_text()))
    served = documented | {f"{m}_bucket" for m in documented} | recorded
    asked = {name for panel in dashboard["panels"] for target in panel["targets"]
             for name in re.findall(r"\b(monoguide[a-z_:0-9]*)", target["expr"])}
    assert asked and asked <= served, asked - served
    assert "cell" in {v["name"] for v in dashboard["templating"]["list"]}
    assert all('instance=~"$cell"' in t["expr"] for p in dashboard["panels"] for t in p["targets"])


@pytest.mark.prometheus
def test_a_real_prometheus_fires_the_calibration_alert_for_that_cell_only(tmp_path: Path) -> None:
    prometheus = _tool("prometheus")
    beats, plants = [], []
    try:
        def start(index: int) -> str:
            host, port = CELLS[index]
            state_dir = tmp_path / f"cell{index}" / "state"
            write_journal(state_dir, seeded_entries(8, time.time() - 600.0))
            beat = StatusBeat(state_dir)
            if index == SUSPECT:
                beat.health = {"latched": True, "warning": True}
            beats.append(beat)
            process, line = start_plant(SIM_CELL, state_dir, plant_file(tmp_path / f"plant{index}.toml", host, port),
                                        tmp_path / f"plant{index}.log")
            plants.append(process)
            return line.split()[4].removeprefix("http://").removesuffix("/metrics")

        with ThreadPoolExecutor(len(CELLS)) as pool:  # the plants start side by side
            targets = list(pool.map(start, range(len(CELLS))))
        config = tmp_path / "prometheus.yml"
        config.write_text(
            "global: {scrape_interval: 1s, evaluation_interval: 1s}\n"
            f"rule_files: ['{config_file(RULES)}']\n"
            "scrape_configs:\n  - job_name: monoguide\n"
            f"    static_configs: [{{targets: {json.dumps(targets)}}}]\n")
        server = subprocess.Popen([prometheus, f"--config.file={config}", f"--storage.tsdb.path={tmp_path / 'tsdb'}",
                                   f"--web.listen-address={PROMETHEUS_HOST}:{PROMETHEUS_PORT}"],
                                  stdout=subprocess.DEVNULL, stderr=(tmp_path / "prometheus.log").open("w"), text=True)
        plants.append(server)
        firing: list[dict] = []
        deadline = time.monotonic() + FIRING_S
        while time.monotonic() < deadline and not firing:
            time.sleep(1.0)
            try:
                with urllib.request.urlopen(f"http://{PROMETHEUS_HOST}:{PROMETHEUS_PORT}/api/v1/alerts",
                                            timeout=5) as answer:
                    alerts = json.load(answer)["data"]["alerts"]
            except OSError:
                continue
            firing = [a for a in alerts if a["state"] == "firing"]
        assert firing, (tmp_path / "prometheus.log").read_text()[-3000:]
        assert [(a["labels"]["alertname"], a["labels"]["instance"]) for a in firing] == [
            ("MonoguideCalibrationSuspect", targets[SUSPECT])]
        assert firing[0]["annotations"]["summary"] == f"{targets[SUSPECT]}: calibration suspect (CALIBRATION_SUSPECT " \
                                                      "latched)"
    finally:
        for process in plants:
            stop(process)
        for beat in beats:
            beat.stop()
