"""``daemon/figures.py``: how every figure is drawn and written (matplotlib only when drawing, the Agg canvas,
the bundled font whatever the machine's matplotlibrc says, the same PNG for the same input), and the drawing
helpers against hand-made input."""

from __future__ import annotations

import io
import logging
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers.figure_checks import describe
from PIL import Image

from monoguide.daemon.figures import DPI, bar_chart, draw_style, label_points, new_figure, outline, save_png

ROOT = Path(__file__).parents[2]
DRAWING_MODULES = ("figures", "simulate._report", "calibrate._report", "plan._drawing", "cli.plan")


def test_importing_the_drawing_modules_does_not_load_matplotlib() -> None:
    """Commands that draw nothing never pay for matplotlib: importing every module that can draw leaves it out
    of ``sys.modules``; drawing one figure (the control) brings it in."""
    program = "\n".join([
        "import sys",
        *(f"import monoguide.daemon.{name}" for name in DRAWING_MODULES),
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'matplotlib'))",
        "from monoguide.daemon.figures import new_figure",
        "new_figure((10, 10))",
        "print('matplotlib' in sys.modules, 'matplotlib.pyplot' in sys.modules)",
    ])
    run = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert run.returncode == 0, run.stderr
    before, after = run.stdout.splitlines()
    assert before == "[]"
    assert after == "True False"  # drawn on the Agg canvas, pyplot never imported


@draw_style
def _two_series(seed: int):
    rng = np.random.default_rng(seed)
    figure = new_figure((321, 203))
    ax = figure.add_subplot()
    ax.plot(rng.normal(size=20), label="one")
    ax.plot(rng.normal(size=20), label="two")
    ax.set_xlabel("sample")
    ax.set_ylabel("value (mm)")
    ax.set_title("two series")
    ax.legend()
    return figure


def test_a_figure_is_written_at_its_pixel_size_readable_by_pillow_and_opencv(tmp_path: Path) -> None:
    figure = _two_series(seed=3)
    path = tmp_path / "two.png"
    save_png(figure, path)
    with Image.open(path) as image:
        image.load()
        assert image.size == (321, 203) and image.format == "PNG"
        assert round(image.info["dpi"][0]) == DPI
        grey = np.asarray(image.convert("L"))
    assert (grey < 128).sum() > 300 and (grey > 250).mean() > 0.5  # ink on a white page, neither blank nor full
    picture = cv2.imread(str(path))
    assert picture is not None and picture.shape == (203, 321, 3)
    assert figure.axes == []  # released once written


def test_the_same_input_gives_the_same_png_without_a_timestamp(tmp_path: Path) -> None:
    first, second, other = io.BytesIO(), io.BytesIO(), io.BytesIO()
    save_png(_two_series(seed=3), first)
    save_png(_two_series(seed=3), second)
    save_png(_two_series(seed=4), other)
    assert first.getvalue() == second.getvalue()
    assert first.getvalue() != other.getvalue()  # the content is in the bytes: the comparison can fail
    with Image.open(first) as image:
        assert not {key.lower() for key in image.info} & {"creation time", "software", "date", "time"}


def test_text_is_set_in_the_bundled_dejavu_sans_whatever_the_rc_says(caplog: pytest.LogCaptureFixture) -> None:
    """A machine whose matplotlibrc asks for a font it lacks: outside the figures' style matplotlib warns and
    falls back (the control); a figure drawn and written by ``daemon/figures.py`` warns about nothing and sets
    its text in matplotlib's own DejaVu Sans."""
    import matplotlib
    from matplotlib import font_manager

    with matplotlib.rc_context({"font.family": "No Such Font Family"}):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="matplotlib"):
            font_manager.findfont(font_manager.FontProperties())
        assert any("No Such Font Family" in r.getMessage() for r in caplog.records)  # the control
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="matplotlib"):
            figure = _two_series(seed=1)
            fonts = {font_manager.findfont(t.get_fontproperties()) for t in figure.findobj(matplotlib.text.Text)}
            save_png(figure, io.BytesIO())
        assert caplog.records == []
    assert len(fonts) == 1
    font = Path(fonts.pop())
    assert font.name == "DejaVuSans.ttf" and font.is_relative_to(Path(matplotlib.get_data_path()))


def test_the_outline_is_the_convex_hull_counter_clockwise() -> None:
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0], [1.0, 0.5], [1.0, 0.0]])
    hull = outline(square)
    np.testing.assert_array_equal(hull, [[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    x, y = hull[:, 0], hull[:, 1]
    assert 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)) == pytest.approx(2.0)  # + : counter-clockwise
    assert outline(np.array([[0.0, 0.0], [1.0, 1.0]])).shape == (2, 2)


@draw_style
def test_points_that_fall_on_one_another_share_one_label() -> None:
    """From the side, holes that differ only in y coincide: one label names them both."""
    ax = new_figure((200, 200)).add_subplot()
    xy = np.array([[0.0, 0.0], [1200.0, 0.0], [1200.0, 5.0], [0.0, 0.0]])
    label_points(ax, ["P1", "P2", "P3", "P4"], xy, "black", span=1200.0)
    assert sorted(t.get_text() for t in ax.texts) == ["P1, P4", "P2, P3"]


@draw_style
def test_a_bar_chart_starts_at_zero_and_shows_every_bar_and_its_reference() -> None:
    figure = new_figure((600, 300))
    ax = figure.add_subplot()
    values = [0.02, float("nan"), 0.05, 0.01]
    bar_chart(ax, ["B1", "B2", "B3", "B4"], values, label="residual", reference=0.03, reference_label="RMS")
    seen = describe(figure)["axes"][0]
    assert seen["bars"] == [[0.02, 0.0, 0.05, 0.01]]  # NaN: no bar
    low, high = seen["ylim"]
    assert low == 0.0 and high > 0.05
    assert seen["xticks"] == ["B1", "B2", "B3", "B4"] and sorted(seen["series"]) == ["RMS", "residual"]
    assert seen["points"]["RMS"][1].tolist() == [0.03, 0.03]
