"""The operator page in a real browser on the whole simulated cell: ``monoguide sim-cell`` (its PLC plays three
parts), ``monoguide run --cycles 3`` and ``monoguide web``, each a process of its own. The Now page follows the
service from start to stop without reloading; the second part's first view is occluded (sim-cell's fault
channel), and that cycle's page, reached by clicking its row, names the code the journal holds; an ok cycle's
centres are drawn within 1 px of the journal's record. The screenshots of the README are taken here
(``MONOGUIDE_SCREENSHOTS=docs/images``)."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from helpers.browser import chromium, image_pixel_under, save_screenshot
from helpers.cell_configs import cell_config
from helpers.sim_processes import keep_reading, start_sim_cell, stop
from helpers.web_pages import web_process

from monoguide.daemon.service import Journal

pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.timeout(400)]

ROBOT_HOST, PLC_HOST, WEB_HOST, WEB_PORT = "127.0.24.10", "127.0.24.11", "127.0.24.12", 8241
RUN_S = 240.0


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """The cell run once for the module, watched through the Now page while it runs."""
    tmp = tmp_path_factory.mktemp("browser-cell")
    shots = tmp_path_factory.mktemp("screenshots")
    state, state_dir = tmp / "sim-state.json", tmp / "state"
    config = cell_config(tmp, ROBOT_HOST, PLC_HOST, sharp=True, state_file=state)
    sim, _ = start_sim_cell(config, "--parts", "3", stdin=subprocess.PIPE, timeout_s=60.0)
    keep_reading(sim)
    states: list[str] = []
    try:
        with web_process(state_dir, WEB_HOST, WEB_PORT, "--config", str(config)), chromium() as driver:
            from selenium.webdriver.common.by import By

            driver.get(f"http://{WEB_HOST}:{WEB_PORT}/")
            driver.execute_script("window.notReloaded = true")
            service = subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "run", "--config", str(config),
                                        "--state-dir", str(state_dir), "--cycles", "3"],
                                       stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            try:
                faulted = shot = False
                deadline = time.monotonic() + RUN_S
                while service.poll() is None or (states and states[-1] != "stopped" and time.monotonic() < deadline):
                    assert time.monotonic() < deadline, f"the run did not end; states seen {states}"
                    seen = driver.find_element(By.ID, "state").text
                    if not states or states[-1] != seen:
                        states.append(seen)
                    counter = driver.find_element(By.ID, "counter").text
                    if counter == "1" and not faulted:  # the first cycle is in: occlude the next part's first view
                        sim.stdin.write("camera occluded 1\n")
                        sim.stdin.flush()
                        faulted = True
                    if counter == "2" and not shot:  # the failed cycle is the last result
                        save_screenshot(driver, shots, "operator-now", full_page=False)
                        shot = True
                    time.sleep(0.05)
                not_reloaded = driver.execute_script("return window.notReloaded")
            finally:
                code = stop(service, 30.0)
            yield {"driver": driver, "states": states, "state_dir": state_dir, "shots": shots, "code": code,
                   "not_reloaded": not_reloaded, "log": service.stderr}
    finally:
        stop(sim, 15.0)


def test_now_follows_the_service_from_start_to_stop(run: dict[str, Any]) -> None:
    states = run["states"]
    assert run["code"] == 0
    assert run["not_reloaded"] is True  # the page refreshed itself
    # polled once a second: a state shorter than that may pass unseen (idle between two parts is ~0.1 s)
    assert states[0] in ("no status", "starting") and states[-1] == "stopped", states
    assert any(s in ("measuring", "solving", "checking", "writing", "reporting", "awaiting_ack") for s in states)


def test_the_failed_cycle_is_one_click_away_and_names_its_code(run: dict[str, Any]) -> None:
    from selenium.webdriver.common.by import By

    with Journal(run["state_dir"], read_only=True) as journal:
        rows = journal.last_cycles(10)
    failed = [r for r in rows if r.status == "error"]
    assert len(rows) == 3 and len(failed) == 1, [(r.number, r.status, r.error_code) for r in rows]
    driver = run["driver"]
    driver.get(f"http://{WEB_HOST}:{WEB_PORT}/cycles")
    driver.find_element(By.CSS_SELECTOR, "#cycles tbody tr.error a").click()
    assert driver.current_url.endswith(f"/cycles/{failed[0].number}")
    assert driver.find_element(By.ID, "cycle-error-code").text == failed[0].error_code
    assert failed[0].error_message in driver.find_element(By.ID, "cycle-error-message").text
    save_screenshot(driver, run["shots"], "operator-failed-cycle")


def test_an_ok_cycles_centres_are_drawn_where_its_record_says(run: dict[str, Any]) -> None:
    from selenium.webdriver.common.by import By

    with Journal(run["state_dir"], read_only=True) as journal:
        row = next(r for r in journal.last_cycles(10) if r.status == "ok")
    assert row.record is not None
    width, height = row.record["camera"]["width"], row.record["camera"]["height"]
    driver = run["driver"]
    driver.set_window_size(1400, 1000)
    driver.get(f"http://{WEB_HOST}:{WEB_PORT}/cycles/{row.number}")
    time.sleep(2.0)  # the previews (5 MP PNGs scaled) arrive
    for observation in row.record["observations"]:
        view, (u_true, v_true) = observation["view"], observation["pixel"]
        mark = driver.find_element(By.CSS_SELECTOR, f"#view-{view + 1} svg.frame circle.centre")
        u, v = image_pixel_under(driver, mark, width, height)
        assert abs(u - u_true) <= 1.0 and abs(v - v_true) <= 1.0, (view, (u, v), (u_true, v_true))
    save_screenshot(driver, run["shots"], "operator-cycle", full_page=False)
    assert Path(run["shots"], "operator-cycle.png").stat().st_size > 10_000
