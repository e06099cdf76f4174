"""The poses, map and loop-closure contracts' pictures and PIRF-nav2's, drawn in pixels
(no matplotlib): where a known point must land, and what a picture must and must not show."""

from __future__ import annotations

import numpy as np
import pytest

BLUE, RED, ORANGE = (31, 119, 180), (214, 39, 40), (255, 127, 14)


def _pixels(path):
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB")).astype(int)


def _near(img: np.ndarray, colour: tuple[int, int, int], tol: int = 40) -> np.ndarray:
    return np.abs(img - np.array(colour)).sum(axis=2) <= tol


def _lines(mask: np.ndarray, axis: int, share: float) -> list[int]:
    """Rows (axis 1) or columns (axis 0) where more than ``share`` of the pixels are set,
    runs of neighbours merged to their middle."""
    full = np.flatnonzero(mask.mean(axis=axis) > share)
    runs = np.split(full, np.flatnonzero(np.diff(full) > 1) + 1)
    return [int(round(r.mean())) for r in runs if len(r)]


def test_plan_picture_puts_each_answer_where_it_stands_to_scale(tmp_path):
    """A 4 x 4 m room, one frame at (1, 3) answered right there: the red cross lands a
    quarter across and a quarter down the room's walls, and the room is as wide as high.
    A doubtful answer's alternative is an orange ring at its place; none without one."""
    from placeloc.evaluation.pose_estimates import plot_estimates_on_plan

    walls = np.array([[0, 0, 0, 4, 0, 0], [4, 0, 0, 4, 4, 0], [4, 4, 0, 0, 4, 0], [0, 4, 0, 0, 0, 0]], float)
    truth = np.array([[1.0, 3.0]])
    plain = plot_estimates_on_plan(tmp_path / "a.png", truth, truth.copy(), [], walls, "m")
    ringed = plot_estimates_on_plan(tmp_path / "b.png", truth, truth.copy(), [], walls, "m",
                                    alternative=np.array([[3.0, 1.0]]))
    img = _pixels(plain)
    black = img.sum(axis=2) < 500  # dark: a line of one pixel falls on two, half grey
    # columns and rows nearly all black over the picture's middle: the axes' frame, then the walls
    xs = _lines(black[img.shape[0] // 4: 3 * img.shape[0] // 4], 0, 0.4)
    ys = _lines(black[:, img.shape[1] // 4: 3 * img.shape[1] // 4], 1, 0.4)
    assert len(xs) == 4 and len(ys) == 4, (xs, ys)
    (left, right), (top, bottom) = xs[1:3], ys[1:3]
    assert abs((right - left) - (bottom - top)) <= 2  # to scale: a square room is square
    red = np.argwhere(_near(img[:bottom + 10], RED))  # not the legend's sample below
    cy, cx = red.mean(axis=0)
    assert abs(cx - (left + 0.25 * (right - left))) <= 1.5 and abs(cy - (top + 0.25 * (bottom - top))) <= 1.5
    assert not _near(img[:bottom + 10], ORANGE).any()
    ring = _near(_pixels(ringed), ORANGE, tol=120)
    cx, cy = round(left + 0.75 * (right - left)), round(top + 0.75 * (bottom - top))
    # a ring of 12 pixels across there, 2 wide: orange 4 to 6 pixels out on all four sides, hollow (the dotted
    # line from the answer ends in its middle)
    for dx, dy in ((5, 0), (-5, 0), (0, 5), (0, -5)):
        assert ring[cy + dy - 1: cy + dy + 2, cx + dx - 1: cx + dx + 2].any(), (dx, dy)
    assert ring[cy - 2: cy + 3, cx - 2: cx + 3].mean() < 0.5


def test_a_long_plan_is_cut_into_pieces_stacked_each_to_scale(tmp_path):
    """A 40 x 2 m corridor comes in four panels one above the other, each a quarter of its
    length, not one thin strip: twelve frames evenly along it fall in four bands of rows,
    three frames to a band."""
    from placeloc.evaluation.pose_estimates import plot_estimates_on_plan

    walls = np.array([[0, 0, 0, 40, 0, 0], [40, 0, 0, 40, 2, 0], [40, 2, 0, 0, 2, 0], [0, 2, 0, 0, 0, 0]], float)
    truth = np.column_stack([np.linspace(1, 39, 12), np.full(12, 1.0)])
    img = _pixels(plot_estimates_on_plan(tmp_path / "c.png", truth, truth.copy(), [], walls, "m"))
    assert img.shape[0] > img.shape[1] * 0.6  # not a strip
    red = _near(img, RED)
    red[-60:] = False  # the legend's sample
    rows = np.flatnonzero(red.any(axis=1))
    bands = np.split(rows, np.flatnonzero(np.diff(rows) > 20) + 1)
    assert len(bands) == 4
    for band in bands:  # three crosses a band: three runs of red columns
        cols = np.flatnonzero(red[band].any(axis=0))
        assert len(np.split(cols, np.flatnonzero(np.diff(cols) > 1) + 1)) == 3


def test_error_cdf_rises_at_each_error_on_its_log_axis(tmp_path):
    """Errors 0.1 m and 10 m: the curve is at a half from 0.1 m to 10 m, at one after."""
    from placeloc.evaluation.pose_estimates import plot_error_cdf

    img = _pixels(plot_error_cdf(tmp_path / "cdf.png", np.array([0.1, 10.0]), "m"))
    blue = _near(img, BLUE)
    # the axes: 70..700 across for 0.01..15 m (log), 416 (0) .. 36 (1.02) down
    def px(err: float, share: float) -> tuple[int, int]:
        x = 70 + (np.log10(err) - np.log10(0.01)) / (np.log10(15.0) - np.log10(0.01)) * 630
        return round(416 - share / 1.02 * 380), round(x)

    for err, share in ((0.3, 0.5), (3.0, 0.5)):
        y, x = px(err, share)
        assert blue[y - 2: y + 3, x].any(), (err, share)
    y, x = px(3.0, 1.0)
    assert not blue[y - 2: y + 3, x].any()  # not yet at one before 10 m


def test_pose_map_and_loop_pictures_import_no_matplotlib(tmp_path):
    """The pictures every evaluate of these contracts draws, and a sweep's, cost
    milliseconds, not matplotlib's import (0.4 s, more than a small run's localize)."""
    import subprocess
    import sys

    code = (
        "import sys, numpy as np\n"
        "from placeloc.evaluation.pose_estimates import plot_error_cdf, plot_estimates_on_plan\n"
        "from placeloc.evaluation.maps import plot_map\n"
        "from placeloc.evaluation.loops import plot_time_per_frame\n"
        f"d = {str(tmp_path)!r}\n"
        "t = np.array([[0.0, 0.0], [1.0, 2.0]]); w = np.array([[0, 0, 0, 2, 0, 0.0]])\n"
        "plot_error_cdf(d + '/a.png', np.array([0.1, 2.0]), 'm')\n"
        "plot_estimates_on_plan(d + '/b.png', t, t + 0.1, [], w, 'm', np.zeros(2), np.ones(2), names=['a', 'b'])\n"
        "plot_map(d + '/c.png', t, t + 0.1, t[:1], t, t, 'map', 'units')\n"
        "plot_time_per_frame(d + '/d.png', np.arange(5), np.ones(5) * 1e-3, 'm')\n"
        "from placeloc.pirf.plots import plot_accuracy_gap, plot_closure_strips, plot_loop_closure_pairs, plot_loop_closures\n"
        "ok = np.array([True, False])\n"
        "plot_loop_closures(d + '/e.png', np.array([[0, 0], [1, 0], [1, 1.0]]), np.array([2, 2]), np.array([0, 1]), ok, 1.0)\n"
        "plot_loop_closure_pairs(d + '/f.png', np.array([3, 4]), np.array([0, 2]), ok, np.array([3]), np.array([0]), 5, 1, np.arange(5))\n"
        "plot_accuracy_gap(d + '/g.png', [0.5, 0.6, 0.7], [0.5, 0.6, 0.8], 'hnsw', 1.0)\n"
        "plot_closure_strips(d + '/h.png', [(np.zeros((20, 40)), np.ones((20, 40)))], [('a', 'b')], 'strips')\n"
        "from placeloc.evaluation.plots import plot_sweep\n"
        "plot_sweep({'a': (np.array([0.5, 1.0]), np.array([1.0, 0.5]))}, {'a': ([1, 5], [0.5, 0.8])}, d + '/i.png')\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'matplotlib'))\n")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    assert out.strip().splitlines()[-1] == "[]"
    assert all((tmp_path / f"{n}.png").stat().st_size > 1000 for n in "abcdefghi")


def test_accuracy_bars_stand_as_high_as_their_values(tmp_path):
    """Bars of 0.25 and 0.75 (one series): the second's top stands three times as high
    above the axis as the first's."""
    from placeloc.pirf.plots import plot_accuracy_gap

    img = _pixels(plot_accuracy_gap(tmp_path / "g.png", [0.25, 0.75], None, "hnsw", 1.0))
    blue = _near(img, BLUE, tol=20)
    blue[-60:] = False  # the legend's square below the axes
    cols = np.flatnonzero(blue.sum(axis=0) > 20)  # the bars' columns
    runs = np.split(cols, np.flatnonzero(np.diff(cols) > 1) + 1)
    assert len(runs) == 2
    bottom = max(int(np.flatnonzero(blue[:, r].any(axis=1)).max()) for r in runs)
    heights = [bottom + 1 - int(np.flatnonzero(blue[:, r].any(axis=1)).min()) for r in runs]
    assert abs(heights[1] / heights[0] - 3.0) < 0.05


def test_closure_strips_show_each_frame_under_its_title(tmp_path):
    """A black frame beside a white one, 40 x 20 pixels: scaled to the cell's 320 pixels
    (160 high), black at the left cell's middle and white at the right's."""
    from placeloc.pirf.plots import plot_closure_strips

    img = _pixels(plot_closure_strips(tmp_path / "s.png", [(np.zeros((20, 40)), np.full((20, 40), 255.0))],
                                      [("closed", "matched")], "strips"))
    assert img.shape[0] == 40 + 18 + 160 + 8
    # cells 320 wide with gaps of 8 from the left at (width - 656) / 2 + 8, images below a title of 18
    x0 = (img.shape[1] - 2 * 328 + 8) / 2
    y = 40 + 18 + 80
    assert img[y, round(x0 + 160)].tolist() == [0, 0, 0]
    assert img[y, round(x0 + 328 + 160)].tolist() == [255, 255, 255]
    assert img[y, round(x0 + 324)].tolist() == [255, 255, 255]  # the gap between them: the page


def test_an_experiment_that_draws_says_how_to_get_matplotlib_where_it_is_missing():
    """matplotlib is optional (the experiments' figures only): without it the experiment
    stops at once with the command that installs it."""
    import subprocess
    import sys

    code = ("import sys; sys.modules['matplotlib'] = None\n"
            "from placeloc.experiments import pyplot\n"
            "try:\n    pyplot()\nexcept RuntimeError as e:\n    print(e)\n")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    assert "pip install 'placeloc[experiments]'" in out


def test_plan_view_takes_in_the_room_around_the_frames_not_the_whole_corridor():
    """The picture's view, by hand: the frames' extent, a margin of 2 m (or 5 %), the walls
    through that box as far as 1.5 margins beyond the frames, then a pad of 2 % + 0.4 m."""
    from placeloc.evaluation.pose_estimates import plan_view

    room = np.array([[0, 0, 4, 0], [4, 0, 4, 4], [4, 4, 0, 4], [0, 4, 0, 0]], float)
    lo, hi = plan_view(np.array([[1.0, 3.0]]), room)
    # the walls reach x 0..4 and y 0..4 (within 3 m of the frame): the view is the room, padded
    assert lo == pytest.approx([0 - 0.48, 0 - 0.48]) and hi == pytest.approx([4 + 0.48, 4 + 0.48])
    corridor = np.array([[0, 0, 90, 0], [0, 2.4, 90, 2.4]], float)
    frames = np.column_stack([np.linspace(8, 59, 30), np.full(30, 1.6)])
    lo, hi = plan_view(frames, corridor)
    # margin 5 % of 51 m = 2.55 m; the corridor's walls clipped 1.5 margins (3.825 m) beyond the frames
    span = np.array([51 + 2 * 3.825, 2.4])
    assert lo == pytest.approx([8 - 3.825 - (0.02 * span[0] + 0.4), 0 - (0.02 * 2.4 + 0.4)])
    assert hi == pytest.approx([59 + 3.825 + (0.02 * span[0] + 0.4), 2.4 + (0.02 * 2.4 + 0.4)])


def test_names_the_bundled_font_lacks_are_drawn_with_an_installed_font():
    """Pillow's bundled font has no accented letters ("Zürich_01.png" showed a box for the ü):
    such a text is drawn with the first installed fallback font that has every character, and
    ASCII stays with the bundled one."""
    from PIL import Image, ImageDraw

    from placeloc.evaluation import raster as R

    if not R._installed_fallbacks():
        pytest.skip("none of raster.FALLBACK_FONTS is installed here")
    assert R._missing("frame_01.png") == "" and R._missing("Zürich_ü.png") == "ü"
    assert R.font_for("frame_01.png", 24) is R.font(24)
    fallback = R.font_for("Zürich_01.png", 24)
    assert fallback is not R.font(24) and R._has_glyphs(fallback, "ü") and not R._has_glyphs(R.font(24), "ü")

    def ink(text: str, f) -> np.ndarray:
        img = Image.new("L", (60, 40), 0)
        ImageDraw.Draw(img).text((5, 5), text, font=f, fill=255)
        return np.asarray(img)

    # drawn through a canvas: the fallback's ü, not the bundled font's missing-glyph box
    c = R.Canvas(60, 40, ss=1)
    c.text(5, 5, "ü", 24)
    got = np.asarray(c.result().convert("L")) < 128
    assert got.any() and np.array_equal(ink("ü", fallback) > 127, got)
    assert not np.array_equal(ink("ü", R.font(24)) > 127, got)


def test_a_broken_font_file_is_passed_over(tmp_path, monkeypatch):
    """A file named like a fallback font that is not one (empty, cut short) is skipped: the
    text is drawn with the next font that opens, or the bundled one; no error."""
    from placeloc.evaluation import raster as R

    empty = tmp_path / "broken-font.ttf"  # a name Pillow finds nowhere else (it looks a missing file up by name)
    empty.write_bytes(b"")
    monkeypatch.setattr(R, "_fallback_paths", [str(empty)] + list(R._installed_fallbacks()))
    monkeypatch.setattr(R, "_covering", {})
    f = R.font_for("Zürich.png", 24)
    assert f is R.font(24) or R._has_glyphs(f, "ü")
    c = R.Canvas(80, 30)
    c.text(2, 2, "Zürich.png", 11)  # draws, whichever font it got
    monkeypatch.setattr(R, "_fallback_paths", [str(empty)])
    monkeypatch.setattr(R, "_covering", {})
    assert R.font_for("Zürich.png", 24) is R.font(24)


def test_a_home_is_shown_whole_with_its_doors_and_room_names(tmp_path):
    """Someone who located one photo in a 12 x 8 m home sees the whole home, not 2 m around
    the answer: the plan's walls reach every side of the view. A door is a white gap in its
    wall with its two ends marked; a room's name is written in grey where it is given; the
    answer is named beside its cross; the title counts one estimate, not "1 estimates"."""
    from PIL import Image

    from placeloc.evaluation.pose_estimates import plan_view, plot_estimates_on_plan

    home = np.array([[0, 0, 12, 0], [12, 0, 12, 8], [12, 8, 0, 8], [0, 8, 0, 0], [6, 0, 6, 8]], float)
    lo, hi = plan_view(np.array([[1.0, 1.0]]), home)
    pad = 0.02 * np.array([12.0, 8.0]) + 0.4
    assert lo == pytest.approx(-pad) and hi == pytest.approx([12, 8] + pad)
    # past 30 m across only the part around the frames (the corridor of the test above)
    lo, _ = plan_view(np.array([[1.0, 1.0]]), home * [3, 1, 3, 1])
    assert lo[0] > -1.0 and _[0] < 20.0

    walls6 = np.column_stack([home[:, 0], home[:, 1], np.zeros(5), home[:, 2], home[:, 3], np.zeros(5)])
    door = np.array([[6.0, 3.0, 6.0, 5.0]])                 # in the middle wall, y 3..5
    path = plot_estimates_on_plan(tmp_path / "home.png", None, np.array([[3.0, 4.0]]), [], walls6, "umap",
                                  None, np.array([90.0]), names=["photo.png"], openings=door,
                                  labels=["kitchen"], label_xy=np.array([[9.0, 4.0]]))
    img = _pixels(path)
    dark = img.sum(axis=2) < 400
    # the middle wall: the dark column between the outer walls, at x = 6 of 0..12
    xs = _lines(dark[img.shape[0] // 5: img.shape[0] // 2], 0, 0.3)   # rows of y 8..~5 m: wall, no door
    assert len(xs) == 5, xs                                          # frame, wall, middle wall, wall, frame
    mid = xs[2]
    ys = _lines(dark[:, img.shape[1] // 8: img.shape[1] // 3], 1, 0.4)
    top, bottom = ys[1], ys[2]                                        # y = 8 and y = 0
    at = lambda y_m: round(bottom + (top - bottom) * y_m / 8.0)       # noqa: E731
    assert dark[at(4.0) - 3: at(4.0) + 4, mid - 1: mid + 2].sum() == 0     # the door's middle: white
    assert dark[at(1.5) - 3: at(1.5) + 4, mid - 1: mid + 2].any(axis=1).all()  # the wall below it: drawn
    # the room's name in grey from its top left corner at (9, 4) (right of it and below, not left of it); the
    # answer's name in red to the right of its cross
    grey = _near(img, (140, 140, 140), tol=60)
    x9 = round(xs[1] + (xs[3] - xs[1]) * 9.0 / 12.0)
    assert grey[at(4.0): at(4.0) + 20, x9: x9 + 60].sum() > 30
    assert grey[at(4.0): at(4.0) + 20, x9 - 60: x9 - 2].sum() == 0
    red = _near(img[:bottom], RED, tol=90)
    x3 = round(xs[1] + (xs[3] - xs[1]) * 3.0 / 12.0)
    assert red[at(4.0) - 25: at(4.0), x3 + 8: x3 + 90].sum() > 40   # "photo.png" beside the cross
    title = np.asarray(Image.open(path).convert("L"))[:40]
    assert (title < 128).any()
    from placeloc.evaluation import raster as R
    assert R.text_width("umap: 1 estimate (no ground truth)", 14) < R.text_width("umap: 1 estimates (no ground truth)", 14)


def test_a_strip_cell_is_as_wide_as_its_label_under_square_frames(tmp_path):
    """Square frames (a fish-eye camera's) give panels 110 pixels wide, narrower than
    "best 0000103.jpg  conf 0.0537" at 12 pixels: each cell widens to its widest label, so
    the red label of the best match ends before the next panel's label starts (the page is
    white in the gap between them), and the frames keep their shape (110 x 110)."""
    import cv2

    from placeloc.evaluation.raster import text_width
    from placeloc.evaluation.show import PANEL_HEIGHT_PX, Row, draw_strip_figure

    names = {}
    for name, value in (("0000106.jpg", 40), ("0000103.jpg", 160), ("0000107.jpg", 90)):
        names[name] = tmp_path / name
        cv2.imwrite(str(names[name]), np.full((96, 96, 3), value, np.uint8))
    rows = [Row("0000106.jpg", "0000103.jpg", 0.0537, False, "0000107.jpg")]
    img = _pixels(draw_strip_figure(rows, [0], names, names, tmp_path / "s.png", "t"))
    label = "best 0000103.jpg  conf 0.0537"
    assert text_width(label, 12) > PANEL_HEIGHT_PX  # the case: a label wider than its frame
    cell = img.shape[1] // 3
    assert cell >= text_width(label, 12) + 10
    # the label row (above the frames): red ink only inside the middle cell
    red = _near(img, (220, 0, 0), 60)
    label_rows = red[50:50 + 22]
    cols = np.flatnonzero(label_rows.any(axis=0))
    assert cols.min() >= cell and cols.max() < 2 * cell
    # the middle frame keeps its square shape: the grey of 0000103 spans 110 columns in its row
    y = 50 + 26 + PANEL_HEIGHT_PX // 2
    grey = np.flatnonzero(np.abs(img[y] - 160).sum(axis=1) <= 6)
    assert abs(len(grey) - PANEL_HEIGHT_PX) <= 2


def test_a_map_whose_features_fill_a_corner_gets_a_close_up_beside_it(tmp_path):
    """Ten features in a 1 x 1 square and landmarks 40 away (tears-of-steel's shape: its
    features 5-8 m deep, landmarks to 50 m): the features fill 2.5 % of the whole along each
    axis, so a second chart beside the whole map draws them alone, and there they spread
    over most of the box (blue in at least half of its columns' span), where the whole
    map's chart squeezes them into a few dozen pixels. With the landmarks beside them, one
    chart only."""
    from placeloc.evaluation.maps import plot_map

    rng = np.random.default_rng(0)
    feats = rng.uniform(0, 1, (10, 2))
    far = _pixels(plot_map(tmp_path / "far.png", feats, feats, np.array([[0.0, 40.0], [40.0, 40.0]]), None, None,
                           "map", "m"))
    near = _pixels(plot_map(tmp_path / "near.png", feats, feats, np.array([[0.0, 1.0], [1.0, 1.0]]), None, None,
                            "map", "m"))
    assert far.shape[1] > near.shape[1] + 500           # a second chart beside the first
    blue = _near(far, (31, 119, 180), 60)[:-90]   # the data, not the legends below them
    half = far.shape[1] // 2
    left_cols, right_cols = np.flatnonzero(blue[:, :half].any(axis=0)), np.flatnonzero(blue[:, half:].any(axis=0))
    assert left_cols.max() - left_cols.min() < 40       # squeezed into the corner of the whole map
    assert right_cols.max() - right_cols.min() > 300    # the close-up: spread over its 620-pixel box


def test_the_slowest_frame_is_not_hidden_under_a_legend(tmp_path):
    """Frames at map sizes 0-99 taking 1 ms, and one at map size 5 taking 10 ms: the top
    left of the chart, where a legend box stood and covered it (PIRF-nav2's smoke run). Its
    dot is drawn: blue pixels in the chart's top twentieth, near its left edge."""
    from placeloc.evaluation.loops import plot_time_per_frame

    x = np.arange(100.0)
    s = np.full(100, 1e-3)
    s[5] = 10e-3
    img = _pixels(plot_time_per_frame(tmp_path / "t.png", x, s, "method"))
    blue = _near(img, (31, 119, 180), 60)
    # the box spans x 80-640, y 54-394 of the canvas; 10 ms sits at 1/1.05 of its height
    top = 54 + round((394 - 54) * (1 - 1 / 1.05))
    assert blue[top - 6:top + 7, 80:130].any()
    assert blue[394 - round(340 / 10.5) - 6:394 - round(340 / 10.5) + 7, 80:640].sum() > 100  # and the others at 1 ms


@pytest.mark.parametrize("data_corner, expected_side", [("lower left", "right"), ("lower right", "left")])
def test_a_legend_given_corners_takes_the_first_that_covers_no_data(tmp_path, data_corner, expected_side):
    """Points packed into one lower corner of a 0-1 box: a legend offered lower left, then
    lower right, stands in the lower corner the points leave free (its white box framed in
    light grey), and with no data drawn it takes the first corner offered."""
    from placeloc.evaluation import raster as R

    def legend_side(points: bool) -> str:
        c = R.Canvas(400, 300, ss=1)
        ax = R.Axes(c, (40, 20, 380, 280), (0.0, 1.0), (0.0, 1.0))
        if points:
            xs = np.linspace(0.02, 0.3, 12) if data_corner == "lower left" else np.linspace(0.7, 0.98, 12)
            ax.markers(np.repeat(xs, 12), np.tile(np.linspace(0.02, 0.3, 12), 12), (0, 0, 0), "o", 4)
        ax.legend([R.LegendEntry("a curve", (255, 0, 0), line_width=2)], ("lower left", "lower right"))
        img = _pixels(c.save(tmp_path / "l.png"))
        frame = _near(img, (204, 204, 204), 6)
        cols = np.flatnonzero(frame[150:].any(axis=0))
        return "left" if cols.mean() < 200 else "right"

    assert legend_side(points=True) == expected_side
    assert legend_side(points=False) == "left"
