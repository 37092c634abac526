"""A failed cycle's page from a real ``monoguide web`` process on rows written by the real ``Journal`` as the service
journals failed cycles (each visited view's image, what was found, where each hole was sought, the failure), and on
rows of before that only say it in their message: how it failed near the top, each image with what was found and a
mark of its own where the hole was expected and not found — each at the seeded pixel the row holds."""

from __future__ import annotations

import re
from collections.abc import Iterator

import cv2
import numpy as np
import pytest
from helpers.web_pages import FailedCycles, prepare_failed_cycles, request, web_with_and_without_config

HOST, PORT, BARE_PORT = "127.0.26.1", 8261, 8262  # BARE: without --config


@pytest.fixture(scope="module")
def failed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FailedCycles]:
    truth = prepare_failed_cycles(tmp_path_factory.mktemp("failed") / "state")
    with web_with_and_without_config(truth.state_dir, HOST, PORT, BARE_PORT):
        yield truth


def _page(path: str, port: int = PORT) -> str:
    answer = request(HOST, port, path)
    assert answer.status == 200, (path, answer.status, answer.text[:300])
    return answer.text


def _view(html: str, view: int) -> str:
    found = re.search(rf'<section class="view" id="view-{view}">(.*?)</section>', html, re.S)
    assert found is not None, view
    return found.group(1)


def _frame(html: str, view: int) -> str:
    found = re.search(r'<svg class="frame[^"]*"(.*?)</svg>', _view(html, view), re.S)
    assert found is not None, view
    return found.group(0)


def _marks(svg: str, kind: str) -> list[dict[str, str]]:
    """Every element of class ``kind`` (the first class) with its attributes."""
    return [dict(re.findall(r'([\w-]+)="([^"]*)"', tag)) for tag in re.findall(rf'<\w+ class="{kind}[ "][^>]*>', svg)]


def _at(mark: dict[str, str]) -> tuple[float, float]:
    return float(mark["data-u"]), float(mark["data-v"])


def _close(a: tuple[float, float], b: tuple[float, float], tol: float = 1e-6) -> bool:
    return abs(a[0] - b[0]) <= tol and abs(a[1] - b[1]) <= tol


def test_how_it_failed_is_said_before_the_images(failed: FailedCycles) -> None:
    html = _page(f"/cycles/{failed.hood}")
    assert re.search(r'id="cycle-error-code">HOLE_NOT_FOUND<', html)
    assert re.search(r'id="failure-stage">measuring<', html)
    assert re.search(r'id="failure-exception">HoleNotFound<', html)
    assert re.search(r'id="failure-view">S6<', html) and re.search(r'id="failure-point">H4<', html)
    u, v = failed.missing[failed.hood][2]
    assert f"({u:.1f}, {v:.1f}) px" in html
    assert "S6, H4: hole expected at" in html and 'id="cycle-error-meaning"' in html
    assert html.index('id="failure"') < html.index('<section class="view"')
    assert 'id="failure-unexpected"' not in html
    panel = html[html.index('id="failure"'):html.index('<section class="view"')]
    u, v = failed.missing[failed.hood][2]
    square = re.search(r'id="stopped-square">.*?data-x="(\d+)" data-y="(\d+)">\s*<image href="([^"]+)"', panel, re.S)
    assert square is not None and square.group(3) == f"/cycles/{failed.hood}/views/2/holes/3.png"
    assert _close(_at(_marks(panel, "missing")[0]), (u, v))  # where H4 was sought, in its square in the panel


def test_each_visited_view_shows_its_image_and_what_was_found(failed: FailedCycles) -> None:
    n = failed.hood
    html = _page(f"/cycles/{n}")
    for view in (1, 2):
        svg = _frame(html, view)
        assert f'href="/cycles/{n}/views/{view}/preview.jpg"' in svg, view
        centres = {int(m["data-point"]): _at(m) for m in _marks(svg, "centre")}
        assert centres.keys() == failed.found[(n, view)].keys(), view
        assert all(_close(centres[j], p) for j, p in failed.found[(n, view)].items()), view
        sought = [(float(m["cx"]), float(m["cy"])) for m in _marks(svg, "expected")]
        for j, p in failed.expected[(n, view)].items():
            if j in failed.found[(n, view)]:
                assert any(_close(s, p) for s in sought), (view, j)
    assert [_at(m) for m in _marks(_frame(html, 1), "mark-found")] == [failed.marks[(n, 1)][1]]
    assert 'data-mark="M1"' in _frame(html, 1)
    # the hole it stopped at: a mark of its own at where it was sought, in its view only
    view, point, lost = failed.missing[n]
    missing = _marks(_frame(html, view), "missing")
    assert len(missing) == 1 and missing[0]["class"] == "missing failed" and missing[0]["data-point"] == str(point)
    assert _close(_at(missing[0]), lost)
    assert "H4 not found" in _frame(html, view) and "the cycle stopped here" in _view(html, view)
    assert not _marks(_frame(html, 1), "missing")
    assert "not visited" in _view(html, 3) and "preview.jpg" not in _view(html, 3)  # S7


def test_the_images_served_are_the_ones_the_row_names(failed: FailedCycles) -> None:
    n = failed.hood
    for view in (1, 2):
        answer = request(HOST, PORT, f"/cycles/{n}/views/{view}/image.png")
        assert answer.status == 200 and answer.body == failed.images[(n, view)].read_bytes(), view
    assert request(HOST, PORT, f"/cycles/{n}/views/3/image.png").status == 404  # never visited
    # the square around where the lost hole was sought: light, no dark disc in it
    view, point, (u, v) = failed.missing[n]
    html = _page(f"/cycles/{n}")
    square = re.search(rf'data-x="(\d+)" data-y="(\d+)">\s*<image href="/cycles/{n}/views/{view}/holes/{point}.png"',
                       html)
    assert square is not None
    x0, y0 = int(square.group(1)), int(square.group(2))
    crop = request(HOST, PORT, f"/cycles/{n}/views/{view}/holes/{point}.png")
    assert crop.status == 200 and crop.headers["content-type"] == "image/png"
    image = cv2.imdecode(np.frombuffer(crop.body, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert x0 <= u < x0 + image.shape[1] and y0 <= v < y0 + image.shape[0]
    assert int(image.min()) > 130  # nothing dark was drawn where H4 should have been
    found = request(HOST, PORT, f"/cycles/{n}/views/{view}/holes/2.png")  # H3, found in the same view: dark
    assert found.status == 200
    assert int(cv2.imdecode(np.frombuffer(found.body, np.uint8), cv2.IMREAD_GRAYSCALE).min()) < 60


def test_without_a_config_the_images_take_their_size_from_the_files(failed: FailedCycles) -> None:
    n = failed.hood
    html = _page(f"/cycles/{n}", BARE_PORT)
    svg = _frame(html, 2)
    assert 'viewBox="-0.5 -0.5 2456 2058"' in svg and f'/cycles/{n}/views/2/preview.jpg' in svg
    view, point, lost = failed.missing[n]
    missing = _marks(_frame(html, view), "missing")
    assert len(missing) == 1 and missing[0]["data-point"] == str(point) and _close(_at(missing[0]), lost)
    centres = {int(m["data-point"]): _at(m) for m in _marks(svg, "centre")}
    assert all(_close(centres[j], p) for j, p in failed.found[(n, 2)].items())
    assert request(HOST, BARE_PORT, f"/cycles/{n}/views/2/image.png").body == failed.images[(n, 2)].read_bytes()


def test_a_cycle_that_failed_solving_draws_its_records_centres(failed: FailedCycles) -> None:
    n = failed.solving
    html = _page(f"/cycles/{n}")
    assert re.search(r'id="failure-stage">solving<', html)
    assert re.search(r'id="failure-exception">InconsistentMeasurement<', html)
    assert 'id="download-record"' in html
    for view in range(1, 5):
        svg = _frame(html, view)
        centres = {int(m["data-point"]): _at(m) for m in _marks(svg, "centre")}
        assert centres.keys() == failed.found[(n, view)].keys()
        assert all(_close(centres[j], p) for j, p in failed.found[(n, view)].items())
        assert not _marks(svg, "missing") and f"/cycles/{n}/views/{view}/preview.jpg" in svg


def test_an_unexpected_error_says_so(failed: FailedCycles) -> None:
    html = _page(f"/cycles/{failed.unexpected}")
    assert 'id="failure-unexpected"' in html
    assert re.search(r'id="failure-stage">writing<', html) and re.search(r'id="failure-exception">KeyError<', html)
    assert re.search(r'id="cycle-error-code">CYCLE_ERROR<', html)


@pytest.mark.parametrize("which", ["old_hole", "old_mark"])
def test_an_older_rows_message_places_what_was_not_found(failed: FailedCycles, which: str) -> None:
    n = getattr(failed, which)
    view, point, at = failed.missing[n]
    html = _page(f"/cycles/{n}")
    assert "read from the message" in html
    svg = _frame(html, view)
    missing = _marks(svg, "missing" if point is not None else "mark-missing")
    assert len(missing) == 1 and _close(_at(missing[0]), at)
    if point is not None:
        assert missing[0]["data-point"] == str(point) and "P2 not found" in svg
        assert re.search(r'id="failure-view">S2<', html) and re.search(r'id="failure-point">P2<', html)
    else:
        assert missing[0]["data-mark"] == "M2" and "M2 not found" in svg
    others = [v for v in range(1, 5) if v != view]
    assert not any(_marks(_frame(html, v), "missing") or _marks(_frame(html, v), "mark-missing") for v in others)


def test_a_good_cycle_draws_no_failure_marks(failed: FailedCycles) -> None:
    html = _page(f"/cycles/{failed.ok}")
    assert 'id="failure"' not in html and 'id="not-shown"' not in html
    for kind in ("missing", "expected", "mark-found", "mark-missing"):
        assert f'class="{kind}' not in html, kind
    assert html.count('class="centre"') == 8 and html.count('class="rim"') == 8  # 4 views, each in its square too


def test_a_record_of_another_part_than_the_configs_job_is_drawn_without_the_config(failed: FailedCycles) -> None:
    """The roof's record (4 holes) journaled as job 2, whose part in the config is the hood (6 holes): its centres
    are drawn, and the page says why without the config's names, rims and regions."""
    html = _page(f"/cycles/{failed.mismatched}")
    assert html.count('class="centre"') == 8 and 'class="rim"' not in html
    assert "not those of the config&#39;s part (hood, job 2, 6 holes)" in html
    for view in range(1, 5):  # each view's hole in its square (the record's view v sees point v - 1)
        square = request(HOST, PORT, f"/cycles/{failed.mismatched}/views/{view}/holes/{view - 1}.png")
        assert square.status == 200 and square.body[:8] == b"\x89PNG\r\n\x1a\n", view
