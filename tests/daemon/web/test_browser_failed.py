"""A failed cycle's page in a real browser (Debian's chromium through Selenium) on rows journaled as the service
journals failed cycles: how it failed is on screen above the images; the mark of the hole that was not found is
drawn within 1 px of where the row says it was sought, over a light part of the image (nothing dark was there),
and each found hole's centre over its dark disc. The screenshot of docs/operator-page.md is taken here
(``MONOGUIDE_SCREENSHOTS=docs/images``: ``operator-failed-cycle.png``)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from helpers.browser import chromium, image_pixel_under, save_screenshot, screen_point, wait_images
from helpers.repository import SIM_CELL
from helpers.web_pages import HOLE_RADIUS_PX, FailedCycles, prepare_failed_cycles, web_process

pytestmark = pytest.mark.browser

HOST, PORT = "127.0.26.5", 8266
W, H = 2456, 2058  # the camera's image (examples/example-record.json, config/sim-cell.toml)


@pytest.fixture(scope="module")
def page(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[FailedCycles, Any, Path]]:
    shots = tmp_path_factory.mktemp("screenshots")
    truth = prepare_failed_cycles(tmp_path_factory.mktemp("browser-failed") / "state")
    with web_process(truth.state_dir, HOST, PORT, "--config", str(SIM_CELL)), chromium(1400, 860) as driver:
        yield truth, driver, shots


def test_the_hole_not_found_is_marked_where_it_was_sought(page: tuple[FailedCycles, Any, Path]) -> None:
    truth, driver, shots = page
    from selenium.webdriver.common.by import By

    n = truth.hood
    driver.get(f"http://{HOST}:{PORT}/cycles/{n}")
    wait_images(driver)
    failure = driver.find_element(By.ID, "failure")
    assert "HoleNotFound" in failure.text and "measuring" in failure.text and "H4" in failure.text
    first_view = driver.find_element(By.CSS_SELECTOR, "section.view")
    assert failure.rect["y"] + failure.rect["height"] <= first_view.rect["y"]
    square = failure.find_element(By.CSS_SELECTOR, "#stopped-square svg.crop")  # where H4 was sought, in the panel
    x0, y0 = int(square.get_attribute("data-x")), int(square.get_attribute("data-y"))
    side = int(square.find_element(By.CSS_SELECTOR, "image").get_attribute("width"))
    view, _, (u_true, v_true) = truth.missing[n]
    u, v = image_pixel_under(driver, square.find_element(By.CSS_SELECTOR, "circle.missing"), side, side, x0, y0)
    assert abs(u - u_true) <= 1.0 and abs(v - v_true) <= 1.0, ((u, v), (u_true, v_true))

    frame = driver.find_element(By.CSS_SELECTOR, f"#view-{view} svg.frame")
    missing = frame.find_elements(By.CSS_SELECTOR, "circle.missing")
    assert len(missing) == 1
    u, v = image_pixel_under(driver, missing[0], W, H)
    assert abs(u - u_true) <= 1.0 and abs(v - v_true) <= 1.0, ((u, v), (u_true, v_true))
    for point, (u_found, v_found) in truth.found[(n, view)].items():
        centre = frame.find_element(By.CSS_SELECTOR, f'circle.centre[data-point="{point}"]')
        u, v = image_pixel_under(driver, centre, W, H)
        assert abs(u - u_found) <= 1.0 and abs(v - v_found) <= 1.0

    # the pixels a person sees in the lost hole's square: light all round where it was sought; a found hole's dark
    driver.execute_script("arguments[0].scrollIntoView()", frame)
    time.sleep(0.3)
    shot = cv2.imdecode(np.frombuffer(driver.get_screenshot_as_png(), np.uint8), cv2.IMREAD_GRAYSCALE)
    image = frame.find_element(By.CSS_SELECTOR, "image")
    d = 0.5 * HOLE_RADIUS_PX
    lost = [screen_point(driver, image, W, H, u_true + s * d, v_true + t * d) for s, t in ((1, 0), (-1, 0), (0, 1))]
    assert all(shot[y, x] > 130 for x, y in lost), [int(shot[y, x]) for x, y in lost]
    (u_found, v_found), = [p for j, p in truth.found[(n, view)].items()]
    e = 0.3 * HOLE_RADIUS_PX  # inside the disc, off the cross, the centre's dot and the dashed ring where it was sought
    found = [screen_point(driver, image, W, H, u_found + s * e, v_found + t * e) for s, t in ((1, 1), (-1, -1))]
    assert all(shot[y, x] < 80 for x, y in found), [int(shot[y, x]) for x, y in found]

    driver.execute_script("window.scrollTo(0, 0)")
    save_screenshot(driver, shots, "operator-failed-cycle", full_page=False)
