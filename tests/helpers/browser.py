"""A real browser in a test: Debian's chromium, headless, driven by Selenium through Debian's chromium-driver
(never a downloaded browser). A test that needs it fails, saying how to install it, when it is not there; the
suite's script leaves these tests out then and says so (scripts/test.sh)."""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

CHROMIUM = ("/usr/bin/chromium", "/usr/bin/chromium-browser")
DRIVER = ("/usr/bin/chromedriver", "/usr/lib/chromium/chromedriver")
SCREENSHOTS_ENV = "MONOGUIDE_SCREENSHOTS"  # a folder: the browser tests save their screenshots there too


@contextmanager
def chromium(width: int = 1400, height: int = 1000) -> Iterator[Any]:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    binary = next((p for p in CHROMIUM if Path(p).is_file()), None)
    driver_path = next((p for p in DRIVER if Path(p).is_file()), shutil.which("chromedriver"))
    if binary is None or driver_path is None:
        pytest.fail("the browser tests need Debian's chromium and chromium-driver: "
                    "apt-get install -y chromium chromium-driver (scripts/test.sh leaves them out without)")
    options = webdriver.ChromeOptions()
    options.binary_location = binary
    for argument in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                     f"--window-size={width},{height}", "--hide-scrollbars", "--force-device-scale-factor=1"):
        options.add_argument(argument)
    driver = webdriver.Chrome(service=Service(driver_path), options=options)
    driver.set_page_load_timeout(60)
    try:
        yield driver
    finally:
        driver.quit()


def save_screenshot(driver: Any, folder: Path, name: str, full_page: bool = True) -> Path:
    """``folder/name.png`` (the page's whole height when ``full_page``), and a copy in ``$MONOGUIDE_SCREENSHOTS``."""
    if full_page:
        height = driver.execute_script("return document.documentElement.scrollHeight")
        width = driver.execute_script("return window.innerWidth")
        driver.set_window_size(width, min(int(height) + 20, 6000))
    path = folder / f"{name}.png"
    driver.save_screenshot(str(path))
    extra = os.environ.get(SCREENSHOTS_ENV)
    if extra:
        Path(extra).mkdir(parents=True, exist_ok=True)
        shutil.copy(path, Path(extra) / path.name)
    return path


def image_pixel_under(driver: Any, element: Any, width: int, height: int, x0: int = 0,
                      y0: int = 0) -> tuple[float, float]:
    """The camera pixel (u, v; pixel centres at whole numbers) under the centre of ``element`` (an SVG mark), as
    the browser laid it out: from the screen rectangles of the mark and of the ``<image>`` beside it, which shows
    camera pixels ``x0 .. x0 + width``, ``y0 .. y0 + height`` (the whole frame, or a hole's square). Nothing is
    read from the mark's attributes."""
    u, v = driver.execute_script("""
        const mark = arguments[0], image = mark.ownerSVGElement.querySelector("image");
        const m = mark.getBoundingClientRect(), i = image.getBoundingClientRect();
        return [(m.left + m.width / 2 - i.left) / i.width, (m.top + m.height / 2 - i.top) / i.height];
    """, element)
    return x0 + u * width - 0.5, y0 + v * height - 0.5


def screen_point(driver: Any, image: Any, width: int, height: int, u: float, v: float) -> tuple[int, int]:
    """Where image pixel (u, v) of an ``<image>`` of ``width`` x ``height`` px lies on the screen (viewport px)."""
    x, y = driver.execute_script("""
        const r = arguments[0].getBoundingClientRect();
        return [r.left + (arguments[1] + 0.5) / arguments[3] * r.width,
                r.top + (arguments[2] + 0.5) / arguments[4] * r.height];
    """, image, u, v, width, height)
    return round(x), round(y)


def wait_images(driver: Any, timeout_s: float = 20.0) -> None:
    """Until every <image> of the page has loaded (an SVG image has no `complete`: its bytes arrived)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        urls = driver.execute_script(
            "return Array.from(document.querySelectorAll('svg image')).map(i => i.href.animVal)")
        done = driver.execute_script("return performance.getEntriesByType('resource').map(e => e.name)")
        if all(any(d.endswith(u) for d in done) for u in urls):
            time.sleep(0.3)  # decoded and painted
            return
        time.sleep(0.1)
    pytest.fail("the page's images did not load")
