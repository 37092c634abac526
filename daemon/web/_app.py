"""The operator page as a Starlette application: the routes of the five pages, the downloads, the images and the
charts, each a plain function run in the server's worker threads (the journal is SQLite, read synchronously).

Every route answers GET (and HEAD); none changes anything (``_guard``). Errors are pages of their own: a journal
missing or unreadable is a 503 naming its code and the process keeps serving; an unknown cycle a 404; a bad
filter a 400.
"""

from __future__ import annotations

import json
import time
from datetime import datetime
from pathlib import Path
from typing import Any

import jinja2
from starlette.applications import Starlette
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import FileResponse, HTMLResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from monoguide.daemon.errors import JournalEntryMissing
from monoguide.daemon.web._calibration import calibration_facts, report_figures
from monoguide.daemon.web._cycle import cycle_facts, hole_crop, part_config
from monoguide.daemon.web._cycles import BadQuery, cycle_line, cycles_request
from monoguide.daemon.web._images import ImageGone, crop, image_file, preview
from monoguide.daemon.web._now import now_facts
from monoguide.daemon.web._overlay import view_images
from monoguide.daemon.web._rows import CycleRow, find_rows, read_cycle
from monoguide.daemon.web._source import StateSource
from monoguide.daemon.web._trends import CHARTS, chart_png, trend_rows, trend_window
from monoguide.solver.errors import MonoguideError

HERE = Path(__file__).parent
NO_STORE = {"cache-control": "no-store"}


def build_app(source: StateSource) -> Starlette:
    """The page's application over ``source`` (which the caller closes)."""
    pages = _Pages(source)
    routes = [
        Route("/", pages.now, name="now"),
        Route("/now.json", pages.now_json),
        Route("/cycles", pages.cycles, name="cycles"),
        Route("/cycles/{number:int}", pages.cycle, name="cycle"),
        Route("/cycles/{number:int}/record.json", pages.record),
        Route("/cycles/{number:int}/views/{view:int}/image.png", pages.original),
        Route("/cycles/{number:int}/views/{view:int}/preview.jpg", pages.preview),
        Route("/cycles/{number:int}/views/{view:int}/holes/{point:int}.png", pages.hole),
        Route("/trends", pages.trends, name="trends"),
        Route("/trends/{chart:str}.png", pages.chart),
        Route("/calibration", pages.calibration, name="calibration"),
        Route("/calibration/figures/{index:int}.png", pages.calibration_figure),
        Mount("/static", StaticFiles(directory=HERE / "static"), name="static"),
    ]
    return Starlette(routes=routes, exception_handlers={HTTPException: pages.http_error})


class _Pages:
    def __init__(self, source: StateSource) -> None:
        self.source = source
        self.templates = jinja2.Environment(loader=jinja2.FileSystemLoader(HERE / "templates"), autoescape=True)
        self.templates.filters.update(when=_when, num=_number, xyzabc=_xyzabc)

    # --- the pages ----------------------------------------------------------------------------------

    def now(self, request: Request) -> Response:
        return self._page("now.html", "Now", facts=now_facts(self.source))

    def now_json(self, request: Request) -> Response:
        return JSONResponse(now_facts(self.source), headers=NO_STORE)

    def cycles(self, request: Request) -> Response:
        try:
            asked = cycles_request(dict(request.query_params))
        except BadQuery as bad:
            return self._error(400, "BAD_FILTER", str(bad))
        try:
            with self.source.journal() as journal:
                rows, notes = find_rows(journal, asked.query)
                codes = journal.error_codes()
                counter = journal.cycle_counter()
        except MonoguideError as error:
            return self._journal_error(error)
        older = None
        if len(rows) == asked.query.limit and rows[-1].number > 1:
            older = {**asked.given, "before": str(rows[-1].number)}
        return self._page("cycles.html", "Cycles", lines=[cycle_line(r) for r in rows], given=asked.given,
                          codes=codes, counter=counter, older=older, notes=notes,
                          newest={k: v for k, v in asked.given.items() if k != "before"})

    def cycle(self, request: Request) -> Response:
        number = request.path_params["number"]
        try:
            with self.source.journal() as journal:
                facts = cycle_facts(journal, number, self.source.config)
        except MonoguideError as error:
            return self._journal_error(error)
        return self._page("cycle.html", f"Cycle {number}", facts=facts, row=facts["row"])

    def record(self, request: Request) -> Response:
        number = request.path_params["number"]
        try:
            with self.source.journal() as journal:
                row = read_cycle(journal, number)
        except MonoguideError as error:
            return self._journal_error(error)
        if row.record is None:
            why = "its row cannot be read" if row.unreadable else "it failed before it had a record"
            return self._error(404, "JOURNAL_NO_RECORD", f"cycle {number} has no record: {why}")
        try:
            text = json.dumps(row.record, indent=1)
        except (ValueError, RecursionError) as exc:
            return self._error(404, "JOURNAL_NO_RECORD", f"cycle {number}: its record cannot be written out ({exc})")
        return Response(text + "\n", media_type="application/json", headers={
            "content-disposition": f'attachment; filename="cycle-{number}-record.json"'})

    def original(self, request: Request) -> Response:
        return self._image(request, lambda path, row, view: FileResponse(
            path, media_type="image/png", filename=f"cycle-{row.number}-view-{view + 1}.png"))

    def preview(self, request: Request) -> Response:
        return self._image(request, lambda path, row, view: Response(preview(path), media_type="image/jpeg"))

    def hole(self, request: Request) -> Response:
        point = request.path_params["point"]

        def answer(path: Path, row: CycleRow, view: int) -> Response:
            try:
                path, box = hole_crop(self.source.state_dir, row, self.source.config, view, point)
            except ImageGone:
                raise
            except LookupError as missing:
                return self._error(404, "NO_SUCH_HOLE", str(missing))
            return Response(crop(path, box), media_type="image/png")

        return self._image(request, answer)

    def trends(self, request: Request) -> Response:
        try:
            window = trend_window(dict(request.query_params))
        except BadQuery as bad:
            return self._error(400, "BAD_FILTER", str(bad))
        return self._page("trends.html", "Trends", window=window, charts=CHARTS)

    def chart(self, request: Request) -> Response:
        name = request.path_params["chart"]
        if name not in CHARTS:
            return self._error(404, "NO_SUCH_CHART", f"no chart {name[:40]!r}; the charts are {', '.join(CHARTS)}")
        try:
            window = trend_window(dict(request.query_params))
            with self.source.journal() as journal:
                rows, _ = trend_rows(journal, window, time.time())
        except BadQuery as bad:
            return self._error(400, "BAD_FILTER", str(bad))
        except MonoguideError as error:
            return self._journal_error(error)
        return Response(chart_png(name, rows), media_type="image/png", headers=NO_STORE)

    def calibration(self, request: Request) -> Response:
        return self._page("calibration.html", "Calibration", facts=calibration_facts(self.source))

    def calibration_figure(self, request: Request) -> Response:
        found = report_figures(self.source.config) if self.source.config is not None else []
        index = request.path_params["index"]
        if not 0 <= index < len(found):
            return self._error(404, "NO_SUCH_FIGURE", f"the calibration report has {len(found)} figures")
        return FileResponse(found[index], media_type="image/png")

    async def http_error(self, request: Request, exc: Exception) -> Response:
        status = getattr(exc, "status_code", 500)
        return self._error(status, "NOT_FOUND" if status == 404 else f"HTTP_{status}", str(getattr(exc, "detail", "")))

    # --- private ------------------------------------------------------------------------------------

    def _image(self, request: Request, answer: Any) -> Response:
        number, view = request.path_params["number"], request.path_params["view"] - 1
        try:
            with self.source.journal() as journal:
                row = read_cycle(journal, number)
            images = view_images(row, part_config(self.source.config, row.job))
            path = image_file(self.source.state_dir, number, view, images[view] if 0 <= view < len(images) else None,
                              row.images_pruned_at is not None)
            return answer(path, row, view)
        except ImageGone as gone:
            return self._error(404, "IMAGE_GONE", str(gone))
        except MonoguideError as error:
            return self._journal_error(error)

    def _page(self, template: str, title: str, status: int = 200, **values: Any) -> Response:
        html = self.templates.get_template(template).render(title=title, state_dir=str(self.source.state_dir),
                                                            **values)
        return HTMLResponse(html, status_code=status, headers=NO_STORE)

    def _journal_error(self, error: MonoguideError) -> Response:
        status = 404 if isinstance(error, JournalEntryMissing) else 503
        return self._error(status, error.code, error.message)

    def _error(self, status: int, code: str, message: str) -> Response:
        return self._page("error.html", f"{code}", status=status, code=code, message=message, status_code=status)


def _when(seconds: Any) -> str:
    if not isinstance(seconds, int | float) or isinstance(seconds, bool):
        return "-"
    try:
        return datetime.fromtimestamp(seconds).strftime("%Y-%m-%d %H:%M:%S")
    except (ValueError, OverflowError, OSError):
        return f"{seconds:g} (not a time)"


def _number(value: Any, digits: int = 3) -> str:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return "-"
    try:
        return f"{float(value):.{digits}f}"
    except OverflowError:
        return "-"


def _xyzabc(values: Any) -> str:
    if not isinstance(values, list | tuple) or not values:
        return "-"
    return " ".join(_number(v, 2) for v in values)
