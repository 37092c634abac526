"""The pages over HTTP from a real ``monoguide web`` process on a prepared journal (written by the real
``Journal``, images with their holes where the journal says): what each page shows is the seeded truth."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import quote

import pytest
from helpers.repository import SIM_CELL
from helpers.web_pages import T0, Prepared, prepare_state, request, web_process

from monoguide.solver.record import solve_record

HOST, PORT = "127.0.21.1", 8211


@pytest.fixture(scope="module")
def prepared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Prepared]:
    state = prepare_state(tmp_path_factory.mktemp("pages") / "state")
    with web_process(state.state_dir, HOST, PORT, "--config", str(SIM_CELL)):
        yield state


def _get(path: str) -> tuple[int, str]:
    answer = request(HOST, PORT, path)
    return answer.status, answer.text


def _cycle_numbers(html: str) -> list[int]:
    return [int(n) for n in re.findall(r'data-cycle="(\d+)"', html)]


def test_cycles_newest_first_and_filtered_as_seeded(prepared: Prepared) -> None:
    everything = sorted([*prepared.ok, *prepared.failed], reverse=True)
    assert _cycle_numbers(_get("/cycles")[1]) == everything
    assert _cycle_numbers(_get("/cycles?status=error")[1]) == sorted(prepared.failed, reverse=True)
    assert _cycle_numbers(_get("/cycles?code=HOLE_NOT_FOUND&job=1")[1]) == sorted(
        (n for n in prepared.failed if prepared.jobs[n] == 1), reverse=True)
    # cycle n finished at T0 + 60 n + 5: the window [T0 + 300, T0 + 480) holds cycles 5, 6, 7 (8 at T0 + 485)
    start, end = (_local(T0 + 300), _local(T0 + 480))
    assert _cycle_numbers(_get(f"/cycles?from={start}&to={end}")[1]) == [7, 6, 5]


def test_cycles_page_on_through_older(prepared: Prepared) -> None:
    status, first = _get("/cycles?limit=5")
    older = re.search(r'id="older" href="([^"]+)"', first)
    assert status == 200 and older is not None
    second = _get(older.group(1).replace("&amp;", "&"))[1]
    assert _cycle_numbers(first) + _cycle_numbers(second)[:5] == sorted([*prepared.ok, *prepared.failed],
                                                                        reverse=True)[:10]


@pytest.mark.parametrize("query", ["status=maybe", "job=-1", "job=99999999", "from=yesterday", "before=0x10",
                                   "code=a;DROP TABLE cycle", "colour=red"])
def test_a_bad_filter_is_a_400_naming_it(prepared: Prepared, query: str) -> None:
    key, value = query.split("=")
    status, html = _get(f"/cycles?{key}={quote(value)}")
    assert status == 400 and "BAD_FILTER" in html
    assert query.split("=")[0] in html


def test_one_cycle_marks_the_journals_centres(prepared: Prepared) -> None:
    n = prepared.ok[2]
    status, html = _get(f"/cycles/{n}")
    assert status == 200
    for (cycle, view), (u, v) in prepared.centres.items():
        if cycle != n:
            continue
        found = re.search(rf'class="centre" data-view="{view + 1}" data-point="\d+" data-u="([\d.]+)" '
                          rf'data-v="([\d.]+)"', html)
        assert found is not None, view
        assert abs(float(found.group(1)) - u) < 1e-6 and abs(float(found.group(2)) - v) < 1e-6
    assert html.count('class="rim"') >= 8  # each hole's rim in the view and in its square (a config was given)
    assert html.count('class="region"') >= 8


def test_a_failed_cycle_names_its_code_and_says_what_it_means(prepared: Prepared) -> None:
    n = max(prepared.failed)
    status, html = _get(f"/cycles/{n}")
    assert status == 200
    assert re.search(r'id="cycle-error-code">HOLE_NOT_FOUND<', html)
    assert "no record: the cycle failed before one existed" in html
    assert 'id="cycle-error-meaning"' in html


def test_journal_text_is_escaped(prepared: Prepared) -> None:
    for path in (f"/cycles/{prepared.escaped}", "/cycles"):
        html = _get(path)[1]
        assert "<script>alert" not in html and "<b>" not in html
    assert "&lt;script&gt;alert(&#39;x&#39;)&lt;/script&gt; &amp; &lt;b&gt;" in _get(f"/cycles/{prepared.escaped}")[1]


def test_the_record_downloads_and_solves_again(prepared: Prepared) -> None:
    n = prepared.ok[1]
    answer = request(HOST, PORT, f"/cycles/{n}/record.json")
    assert answer.status == 200 and "attachment" in answer.headers["content-disposition"]
    record = json.loads(answer.body)
    assert record["id"] == f"cycle-{n}"
    result, _ = solve_record(record)
    assert result["status"] == "ok"


def test_the_images_download_as_stored(prepared: Prepared) -> None:
    n = prepared.ok[1]
    answer = request(HOST, PORT, f"/cycles/{n}/views/2/image.png")
    assert answer.status == 200 and answer.headers["content-type"] == "image/png"
    assert answer.body == (prepared.state_dir / "images" / f"cycle-{n}" / "S2.png").read_bytes()
    preview = request(HOST, PORT, f"/cycles/{n}/views/2/preview.jpg")
    assert preview.status == 200 and preview.body[:2] == b"\xff\xd8"


def test_pruned_images_are_said_to_be_pruned(prepared: Prepared) -> None:
    status, html = _get(f"/cycles/{prepared.pruned}")
    assert status == 200 and 'id="pruned"' in html
    answer = request(HOST, PORT, f"/cycles/{prepared.pruned}/views/1/image.png")
    assert answer.status == 404 and "pruned" in answer.text


def test_a_row_naming_a_file_outside_the_images_folder_serves_nothing(prepared: Prepared) -> None:
    answer = request(HOST, PORT, f"/cycles/{prepared.outside}/views/1/image.png")
    assert answer.status == 404 and "root:" not in answer.text and "outside the images folder" in answer.text
    assert request(HOST, PORT, f"/cycles/{prepared.outside}/views/2/image.png").status == 200


def test_now_json_has_the_counter_and_the_last_cycle(prepared: Prepared) -> None:
    facts = json.loads(request(HOST, PORT, "/now.json").body)
    newest = max([*prepared.ok, *prepared.failed])
    assert facts["journal"]["cycle_counter"] == newest
    assert facts["journal"]["last"]["number"] == newest
    assert facts["service"]["state"] is None and "no status file" in facts["service"]["reason"]
    assert facts["health"]["level"] is None and facts["health"]["summary"].startswith("not available")


def test_trends_and_calibration_pages_answer(prepared: Prepared) -> None:
    for chart in ("offset", "quality", "errors"):
        answer = request(HOST, PORT, f"/trends/{chart}.png?last=50", timeout_s=90.0)  # matplotlib's first figure
        assert answer.status == 200 and answer.body[:8] == b"\x89PNG\r\n\x1a\n", chart
    assert _get("/trends?last=0")[0] == 400
    status, html = _get("/calibration")
    assert status == 200 and "not available" in html and str(SIM_CELL) in html


def _local(seconds: float) -> str:
    from datetime import datetime

    return datetime.fromtimestamp(seconds).strftime("%Y-%m-%dT%H:%M:%S")


def test_prepared_images_exist(prepared: Prepared) -> None:
    assert (prepared.state_dir / "images" / f"cycle-{prepared.ok[1]}" / "S1.png").is_file()
    assert not (prepared.state_dir / "images" / "cycle-1" / "S1.png").exists()  # pruned
    assert isinstance(prepared.state_dir, Path)
