"""The operator page in a real browser (Debian's chromium through Selenium) on a prepared journal: what a person
sees — each found centre drawn within 1 px of where the journal says the hole is, and over the dark disc of the
image itself; a failed cycle's page naming its code; journal text shown as text; the Now page following the
service's status file without reloading. The same in a whole simulated cell: tests/daemon/web/test_browser_cell.py."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from helpers.browser import chromium, image_pixel_under, save_screenshot, screen_point, wait_images
from helpers.repository import EXAMPLE_RECORD, SIM_CELL
from helpers.web_pages import HOLE_RADIUS_PX, Prepared, prepare_state, web_process

from monoguide.daemon.service import ServiceStatus, write_status
from monoguide.daemon.service._status import DeviceStatus

pytestmark = pytest.mark.browser

HOST, PORT = "127.0.23.1", 8231
CAMERA = json.loads(EXAMPLE_RECORD.read_text())["camera"]
W, H = CAMERA["width"], CAMERA["height"]


@pytest.fixture(scope="module")
def page(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Prepared, Any, Path]]:
    shots = tmp_path_factory.mktemp("screenshots")
    prepared = prepare_state(tmp_path_factory.mktemp("browser") / "state", cycles=8)
    with web_process(prepared.state_dir, HOST, PORT, "--config", str(SIM_CELL)), chromium() as driver:
        yield prepared, driver, shots


def _open(driver: Any, path: str) -> None:
    driver.get(f"http://{HOST}:{PORT}{path}")


def test_each_centre_is_drawn_where_the_journal_says(page: tuple[Prepared, Any, Path]) -> None:
    prepared, driver, shots = page
    n = prepared.ok[2]
    _open(driver, f"/cycles/{n}")
    wait_images(driver)
    from selenium.webdriver.common.by import By

    checked = 0
    for view in range(4):
        u_true, v_true = prepared.centres[(n, view)]
        frame = driver.find_elements(By.CSS_SELECTOR, f"#view-{view + 1} svg.frame circle.centre")
        square = driver.find_elements(By.CSS_SELECTOR, f"#view-{view + 1} svg.crop")
        assert len(frame) == len(square) == 1, view  # in the whole view and in the hole's square
        x0, y0 = int(square[0].get_attribute("data-x")), int(square[0].get_attribute("data-y"))
        side = int(square[0].find_element(By.CSS_SELECTOR, "image").get_attribute("width"))
        for mark, place in ((frame[0], (W, H, 0, 0)), (square[0].find_element(By.CSS_SELECTOR, "circle.centre"),
                                                        (side, side, x0, y0))):
            u, v = image_pixel_under(driver, mark, *place)
            assert abs(u - u_true) <= 1.0 and abs(v - v_true) <= 1.0, (view, (u, v), (u_true, v_true))
            checked += 1
    assert checked == 8
    save_screenshot(driver, shots, "browser-cycle")


def test_the_mark_lies_on_the_dark_hole_of_the_image(page: tuple[Prepared, Any, Path]) -> None:
    """The pixels a person sees: inside the drawn hole (half a radius from the true centre, off the cross) the
    magnified square is dark, two radii out it is the light frame."""
    prepared, driver, _ = page
    n = prepared.ok[2]
    _open(driver, f"/cycles/{n}")
    wait_images(driver)
    driver.execute_script("document.getElementById('view-1').scrollIntoView()")
    time.sleep(0.3)
    from selenium.webdriver.common.by import By

    crop = driver.find_element(By.CSS_SELECTOR, "#view-1 svg.crop image")
    box = driver.find_element(By.CSS_SELECTOR, "#view-1 svg.crop")
    x0, y0 = int(box.get_attribute("data-x")), int(box.get_attribute("data-y"))
    side = int(crop.get_attribute("width"))
    shot = cv2.imdecode(np.frombuffer(driver.get_screenshot_as_png(), np.uint8), cv2.IMREAD_GRAYSCALE)
    u, v = prepared.centres[(n, 0)]
    d = HOLE_RADIUS_PX / np.sqrt(2)
    inside = [screen_point(driver, crop, side, side, u - x0 + s * d / 2, v - y0 + t * d / 2)
              for s, t in ((1, 1), (-1, 1), (1, -1), (-1, -1))]
    outside = [screen_point(driver, crop, side, side, u - x0 + s * 2 * d, v - y0 + t * 2 * d)
               for s, t in ((1, 1), (-1, 1), (1, -1), (-1, -1))]
    assert all(shot[y, x] < 80 for x, y in inside), [int(shot[y, x]) for x, y in inside]
    assert all(shot[y, x] > 130 for x, y in outside), [int(shot[y, x]) for x, y in outside]


def test_a_failed_cycle_names_its_code_and_shows_journal_text_as_text(page: tuple[Prepared, Any, Path]) -> None:
    prepared, driver, shots = page
    from selenium.webdriver.common.by import By

    _open(driver, "/cycles?status=error")
    rows = driver.find_elements(By.CSS_SELECTOR, "#cycles tbody tr.error a")
    assert [int(a.text) for a in rows] == sorted(prepared.failed, reverse=True)
    next(a for a in rows if int(a.text) == prepared.escaped).click()
    assert driver.current_url.endswith(f"/cycles/{prepared.escaped}")
    assert driver.find_element(By.ID, "cycle-error-code").text == prepared.failed[prepared.escaped]
    message = driver.find_element(By.ID, "cycle-error-message").text
    assert "<script>alert('x')</script> & <b>" in message  # shown as the journal holds it, never run
    assert driver.execute_script("return document.querySelectorAll('script:not([src])').length") == 0
    save_screenshot(driver, shots, "browser-failed-cycle")


def test_now_follows_the_status_file_without_reloading(page: tuple[Prepared, Any, Path]) -> None:
    prepared, driver, shots = page
    from selenium.webdriver.common.by import By

    def status(state: str) -> None:
        now = time.time()
        write_status(prepared.state_dir, ServiceStatus(state, now, os.getpid(), now, 1.0, {
            "plc": DeviceStatus(True), "camera": DeviceStatus(state != "starting"), "robot": DeviceStatus(True)}))

    status("idle")
    _open(driver, "/")
    assert driver.find_element(By.ID, "state").text == "idle"
    driver.execute_script("window.notReloaded = true")
    for state in ("measuring", "starting", "idle"):
        status(state)
        deadline = time.monotonic() + 5
        while driver.find_element(By.ID, "state").text != state:
            assert time.monotonic() < deadline, f"the Now page did not show {state}"
            time.sleep(0.1)
        camera = driver.find_element(By.CSS_SELECTOR, '#devices tr[data-device="camera"] td').text
        assert camera == ("NOT connected" if state == "starting" else "connected")
    assert driver.execute_script("return window.notReloaded") is True
    assert driver.find_element(By.ID, "counter").text == str(max([*prepared.ok, *prepared.failed]))
    save_screenshot(driver, shots, "browser-now")
