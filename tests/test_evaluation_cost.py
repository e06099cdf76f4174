"""What keeps evaluate cheap gives the same answers as the direct way: the ground truth's
positive pairs without its dense block, the dissimilarity ratio's minima without a mask of
the difference matrix's size."""

from __future__ import annotations

import numpy as np
import pytest

from placeloc.evaluation.ground_truth import GroundTruth, band_of
from placeloc.evaluation.metrics import split_row_minima


def _truths(tmp_path):
    """One ground truth of every form on 40 references x 30 queries."""
    rng = np.random.default_rng(7)
    ranges = tmp_path / "ranges.csv"
    ranges.write_text("query,ref_first,ref_last\n0,3,5\n0,4,9\n2,38,45\n7,0,0\n29,10,12\n29,30,31\n")
    pairs = tmp_path / "pairs.csv"
    pairs.write_text("query,reference\n1,6\n1,20\n4,39\n")
    ref_xy = np.c_[np.arange(40) * 2.0, np.zeros(40)]
    q_xy = np.c_[np.arange(30) * 2.6 + rng.normal(0, 0.5, 30), rng.normal(0, 1, 30)]
    ref_xy[5] = q_xy[5] + (3.0, 4.0)  # exactly on the radius: a positive (<= radius)
    return {
        "synchronous": GroundTruth(40, 30, synchronous=True, tolerance=2),
        "ranges": GroundTruth.from_csv(ranges, 40, 30),
        "pairs with tolerance": GroundTruth.from_csv(pairs, 40, 30, tolerance=1),
        "matrix": GroundTruth(40, 30, matrix=rng.random((40, 30)) < 0.1),
        "positions": GroundTruth(40, 30, ref_xy=ref_xy, query_xy=q_xy, radius=5.0),
    }


@pytest.mark.parametrize("form", ["synchronous", "ranges", "pairs with tolerance", "matrix", "positions"])
def test_positives_are_the_nonzeros_of_the_dense_block(tmp_path, form):
    gt = _truths(tmp_path)[form]
    # every image, and a listing with skipped images (original indices with gaps)
    for r_idx, q_idx in ((np.arange(40), np.arange(30)), (np.r_[0:5, 7:22, 25:40], np.r_[0:3, 4:29])):
        dense = gt.block_idx(r_idx, q_idx)
        cols, rows = np.nonzero(dense.T)
        got_rows, got_cols = gt.positives(r_idx, q_idx)
        assert got_rows.tolist() == rows.tolist() and got_cols.tolist() == cols.tolist()
        assert len(rows) > 3  # the forms above do have positives here
        # the band drawn under the matrix: first and last positive row per query, 1 > 0 where none
        lo, hi = gt.band(r_idx, q_idx)
        anyp = dense.any(axis=0)
        assert lo.tolist() == np.where(anyp, np.argmax(dense, axis=0), 1).tolist()
        assert hi.tolist() == np.where(anyp, len(r_idx) - 1 - np.argmax(dense[::-1], axis=0), 0).tolist()


def test_position_exactly_on_the_radius_counts():
    gt = GroundTruth(2, 1, ref_xy=np.array([[3.0, 4.0], [3.0, 4.000001]]), query_xy=np.zeros((1, 2)), radius=5.0)
    assert [r.tolist() for r in gt.positives(np.arange(2), np.arange(1))] == [[0], [0]]


def test_band_of_by_hand():
    lo, hi = band_of(np.array([4, 5, 6, 0, 9]), np.array([0, 0, 0, 2, 2]), 4)
    assert lo.tolist() == [4, 1, 0, 1] and hi.tolist() == [6, 0, 9, 0]


def test_split_row_minima_by_hand_and_against_masked_minima():
    block = np.array([[5.0, 1.0, 7.0], [2.0, 3.0, 0.5], [4.0, 4.0, 4.0]], np.float32)
    rows, cols = np.array([0, 1, 1, 2, 2, 2]), np.array([0, 0, 1, 0, 1, 2])
    at_positive, elsewhere = split_row_minima(block.copy(), rows, cols)
    # row 0: positive 5, others 1 and 7; row 1: positives 2 and 3, other 0.5; row 2: all positive
    assert at_positive.tolist() == [5.0, 2.0, 4.0] and elsewhere.tolist() == [1.0, 0.5, np.inf]
    rng = np.random.default_rng(3)
    block = rng.random((50, 20)).astype(np.float32)
    mask = rng.random((50, 20)) < 0.15
    mask[7] = False  # a reference without a positive
    cols, rows = np.nonzero(mask.T)
    at_positive, elsewhere = split_row_minima(block.copy(), rows, cols)
    assert at_positive.tolist() == block.min(axis=1, where=mask, initial=np.inf).tolist()
    assert elsewhere.tolist() == block.min(axis=1, where=~mask, initial=np.inf).tolist()
    assert at_positive[7] == np.inf


# ---------------------------------------------------------------------------------------
# the pictures evaluate draws on every run (Pillow, no matplotlib)
# ---------------------------------------------------------------------------------------
def test_nice_ticks_and_their_labels():
    from placeloc.evaluation.raster import nice_ticks, tick_label

    assert nice_ticks(0, 3575.5, most=9).tolist() == [0, 500, 1000, 1500, 2000, 2500, 3000, 3500]
    ticks = nice_ticks(0, 1, most=6)
    assert [tick_label(v, ticks) for v in ticks] == ["0.0", "0.2", "0.4", "0.6", "0.8", "1.0"]
    ticks = nice_ticks(0, 79.5, most=9)  # 80 frames: a tick every 10
    assert [tick_label(v, ticks) for v in ticks] == ["0", "10", "20", "30", "40", "50", "60", "70"]
    assert nice_ticks(-0.5, 80.5, most=9).tolist() == [0, 20, 40, 60, 80]  # a span of 81 over at most 8 steps: 20 a step


def test_axes_put_data_where_the_limits_say():
    """A marker at a data point lands on the pixel the box and limits give; a matrix fills the box."""
    from placeloc.evaluation.raster import Axes, Canvas, grey_image

    c = Canvas(200, 100)
    ax = Axes(c, (20, 10, 180, 90), (0.0, 10.0), (0.0, 1.0))
    ax.markers(np.array([2.5]), np.array([0.25]), (255, 0, 0), "s", 6)
    img = np.asarray(c.result())
    # x: 20 + 2.5 / 10 * 160 = 60; y (upwards): 90 - 0.25 * 80 = 70
    assert img[70, 60].tolist() == [255, 0, 0] and img[70, 70].tolist() == [255, 255, 255]
    c = Canvas(200, 100)
    ax = Axes(c, (20, 10, 180, 90), (-0.5, 1.5), (-0.5, 0.5), y_down=True)
    ax.image(grey_image(np.array([[0.0, np.nan]]), 0.0, 1.0))  # black cell, then an empty (NaN) one
    img = np.asarray(c.result())
    assert img[50, 60].tolist() == [0, 0, 0] and img[50, 140].tolist() == [255, 255, 255]
    assert grey_image(np.array([[-1.0, 0.5, 2.0]]), 0.0, 1.0)[0, :, 0].tolist() == [0, 128, 255]


def test_percentiles_as_numpy_computes_them():
    from placeloc.evaluation.raster import percentiles

    rng = np.random.default_rng(5)
    for n in (1, 2, 7, 1000):
        v = rng.normal(size=n).astype(np.float32)
        assert percentiles(v, (1, 99)) == pytest.approx(tuple(np.percentile(v.astype(np.float64), [1, 99])), abs=1e-12)
    assert percentiles(np.arange(101.0), (1, 50, 99)) == (1.0, 50.0, 99.0)


def test_dashed_line_is_on_for_its_share_of_the_pattern():
    from placeloc.evaluation.raster import _dash_runs

    runs = _dash_runs(np.array([0.0, 1000.0]), np.array([5.0, 5.0]), (6.0, 2.0))
    drawn = sum(r[-1][0] - r[0][0] for r in runs)
    assert len(runs) == 125 and drawn == pytest.approx(1000 * 6 / 8, abs=2)


def test_difference_matrix_picture_shows_the_matrix_and_the_matches(tmp_path):
    """Left half of D alike (black), right half not (white); a wrong match is a red cross
    where it is; the picture has the size of two panels."""
    from PIL import Image

    from placeloc.evaluation.plots import plot_difference_matrices

    d = np.zeros((40, 40), np.float32)
    d[:, 20:] = 1.0
    path = plot_difference_matrices({"D": d}, tmp_path / "dm.png", matches=np.full(40, 30), correct=np.zeros(40, bool),
                                    title="t")
    img = np.asarray(Image.open(path).convert("RGB"))
    assert img.shape == (616, 712, 3)
    # the axes box spans x 76..600 and y 60..558 for columns and rows -0.5..39.5
    def px(q: float, r: float) -> tuple[int, int]:
        return round(60 + (r + 0.5) / 40 * 498), round(76 + (q + 0.5) / 40 * 524)

    y, x = px(5, 5)
    assert img[y, x].tolist() == [0, 0, 0]
    y, x = px(35, 5)
    assert img[y, x].tolist() == [255, 255, 255]
    y, x = px(20, 30)  # the match of query 20 is reference 30: a red cross centred there
    assert img[y, x].tolist() == [255, 0, 0]


def test_evaluate_draws_without_importing_matplotlib(route, tmp_path):
    """matplotlib's import alone costs more than a small run's localize: evaluate of a
    ranked result draws its pictures without it (every picture written, none missing)."""
    import subprocess
    import sys

    code = ("import sys; from placeloc.core.config import load_config; from placeloc.core.runner import run_all; "
            f"run_all(load_config({str(route / 'config.yaml')!r}), {str(tmp_path / 'run')!r}, quiet=True); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'matplotlib'))")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    assert out.strip().splitlines()[-1] == "[]"
    for name in ("strips_sample.png", "pr_curve.png", "recall_at_n.png", "difference_matrix.png", "report.html"):
        assert (tmp_path / "run" / name).stat().st_size > 1000


def test_a_title_of_two_lines_gets_its_room(tmp_path):
    from PIL import Image

    from placeloc.evaluation.plots import plot_pr_curves

    curve = {"m": (np.array([0.5, 1.0]), np.array([1.0, 0.5]))}
    one = Image.open(plot_pr_curves(curve, tmp_path / "a.png", title="PR"))
    two = Image.open(plot_pr_curves(curve, tmp_path / "b.png", title="PR\n(second line)"))
    assert two.size[1] - one.size[1] == 17 and one.size[0] == two.size[0]
    # the first line sits above the second, clear of the top edge: ink in the top rows of both lines only
    ink = (np.asarray(two.convert("L"))[:40, 150:510] < 128).any(axis=1)
    assert not ink[:2].any() and ink[5:18].any() and ink[22:36].any()


def test_sidecar_fingerprint_lists_the_files_beside_the_images_in_name_order(tmp_path):
    """What evaluate's stamp holds of the CSV/TXT/JSON/YAML files in an image folder (a
    poses.csv ground truth may read): by hand, the same rows in the same order."""
    import os

    from placeloc.core.config import config_hash
    from placeloc.core.images import list_images
    from placeloc.core.runner import _sidecar_fingerprint

    folder = tmp_path / "imgs"
    folder.mkdir()
    for name in ("f0.png", "f1.png", "poses.csv", "B.TXT", "a.yml", ".hidden.csv", ".csv", "notes.md"):
        (folder / name).write_bytes(b"x" * len(name))
    (folder / "dir.json").mkdir()  # a folder is no sidecar file
    import cv2

    for name in ("f0.png", "f1.png"):
        cv2.imwrite(str(folder / name), np.zeros((4, 4), np.uint8))

    def row(name: str) -> str:
        st = os.stat(folder / name)
        return f"reference/{name}:{st.st_size}:{st.st_mtime_ns}"

    # code-point order; ".hidden.csv" is a CSV, ".csv" (a name without suffix) is not
    expected = config_hash([row(".hidden.csv"), row("B.TXT"), row("a.yml"), row("poses.csv")])
    assert _sidecar_fingerprint({"reference": list_images(folder)}) == expected


def test_pr_legend_moves_right_when_every_curve_ends_early(tmp_path):
    """Curves that end before half the recall leave the right half empty: the legend goes
    there, off their ends and the labels under them; a curve reaching further keeps it left,
    unless curves lie in the lower left (low precision at low recall), which it would hide:
    then it takes the lower right, which they leave free."""
    from PIL import Image

    from placeloc.evaluation.plots import plot_pr_curves

    def legend_side(curves: dict) -> str:
        img = np.asarray(Image.open(plot_pr_curves(curves, tmp_path / "pr.png")).convert("RGB"))
        frame = (np.abs(img[380:466].astype(int) - 204).sum(axis=2) <= 6).sum(axis=0)  # the legend's grey frame
        return "right" if frame[330:].sum() > frame[:330].sum() else "left"

    short = {"a": (np.array([0.1, 0.26]), np.array([0.4, 0.26])), "b": (np.array([0.05, 0.13]), np.array([0.2, 0.13]))}
    far = {"c": (np.array([0.5, 0.9]), np.array([1.0, 0.8]))}
    assert legend_side(short) == "right"
    assert legend_side(far) == "left"
    assert legend_side({**short, **far}) == "right"


def test_pictures_drawn_on_threads_are_all_waited_for_and_the_first_error_raised():
    import threading

    from placeloc.evaluation.pictures import background, draw

    main, seen, release = threading.get_ident(), [], threading.Event()

    def picture(k: int) -> None:
        if k == 0:
            release.wait()  # the stage goes on while this one is still drawing
        seen.append((k, threading.get_ident() != main))

    def broken() -> None:
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        with background(threads=2):
            draw(picture, 0)
            draw(broken)
            draw(picture, 1)
            assert (0, True) not in seen
            release.set()
    assert sorted(seen) == [(0, True), (1, True)]  # both finished before the error came out
    # outside a background block (and with one thread) a picture is drawn at once, here
    draw(picture, 2)
    with background(threads=1):
        draw(picture, 3)
        assert seen[-1] == (3, False)
    assert seen[-2] == (2, False)


def test_a_pass_alongside_runs_on_its_own_thread_and_is_filed_on_the_stages_thread_at_settle():
    import threading

    from placeloc.evaluation.pictures import alongside, background, draw

    main, release = threading.get_ident(), threading.Event()
    filed: list[tuple[str, int, bool]] = []

    def slow_picture() -> None:
        release.wait()  # holds the only picture thread until the pass has run

    def minima(k: int) -> int:
        return k * k  # the "pass": reached while the picture thread is still busy

    def file(tag: str) -> object:
        return lambda found: filed.append((tag, found, threading.get_ident() == main))

    with background(threads=2) as side:
        draw(slow_picture)
        draw(slow_picture)  # both picture threads busy: a pass queued behind them would hang
        alongside(lambda: minima(3), file("a"))
        alongside(lambda: minima(4), file("b"))
        assert filed == []  # nothing filed before settle, whatever the threads did
        side.settle()
        assert filed == [("a", 9, True), ("b", 16, True)]  # in order, on the stage's thread
        release.set()

    def broken() -> int:
        raise OSError("read error in localize.h5")

    with pytest.raises(OSError, match="read error"):
        with background(threads=2):
            alongside(broken, file("never"))
            alongside(lambda: minima(5), file("c"))
    assert len(filed) == 2  # a failed pass files nothing, and the rest are not filed after it
    # outside a block, and with one thread, at once
    alongside(lambda: minima(6), file("d"))
    with background(threads=1):
        alongside(lambda: minima(7), file("e"))
        assert filed[-1] == ("e", 49, True)
    assert filed[-2] == ("d", 36, True)


def test_save_png_writes_the_pixels_of_every_mode(tmp_path):
    from PIL import Image

    from placeloc.evaluation.raster import save_png

    rng = np.random.default_rng(3)
    rgb = rng.integers(0, 256, (17, 23, 3), dtype=np.uint8)
    grey = rng.integers(0, 256, (9, 5), dtype=np.uint8)
    for photo in (False, True):
        got = np.asarray(Image.open(save_png(Image.fromarray(rgb, "RGB"), tmp_path / f"rgb{photo}.png", photo=photo)))
        assert np.array_equal(got, rgb)  # channel order kept (OpenCV writes BGR)
    assert np.array_equal(np.asarray(Image.open(save_png(Image.fromarray(grey, "L"), tmp_path / "l.png"))), grey)
    rgba = np.dstack([rgb, np.full(rgb.shape[:2], 255, np.uint8)])
    got = np.asarray(Image.open(save_png(Image.fromarray(rgba, "RGBA"), tmp_path / "rgba.png")))
    assert np.array_equal(got[..., :3], rgb)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["l.png", "rgba.png", "rgbFalse.png", "rgbTrue.png"])


def test_strips_drawn_from_the_evaluation_are_the_rows_per_query_csv_holds(route, tmp_path):
    """Evaluate draws the strips from its scores in memory, while it writes per_query.csv;
    the rows are those `placeloc show` reads back from that file."""
    from placeloc.core.config import load_config
    from placeloc.core.runner import run_all
    from placeloc.evaluation import ranked
    from placeloc.evaluation.contracts import read_result
    from placeloc.evaluation.show import read_rows

    run = tmp_path / "run"
    cfg = load_config(route / "config.yaml")
    run_all(cfg, run, quiet=True)
    seen = {}
    real = ranked.strip_rows

    def spy(ev):
        seen["rows"] = real(ev)
        return seen["rows"]

    ranked.strip_rows = spy
    try:
        run_all(cfg, run, quiet=True, force=True)
    finally:
        ranked.strip_rows = real
    assert read_result(run / "localize.h5").kind == "ranked"
    from_csv = read_rows(run)
    assert seen["rows"] == from_csv
    assert any(r.correct for r in from_csv) and any(r.best_image for r in from_csv)


def test_per_query_csv_is_what_csv_writer_writes_for_awkward_names_and_missing_candidates(tmp_path):
    """per_query.csv is built as text (placeloc.evaluation.matching.write_per_query_csv); the
    reference here is the csv module's writer, row by row, as the file was written before."""
    import csv
    from types import SimpleNamespace

    from placeloc.evaluation.matching import csv_field, write_per_query_csv
    from placeloc.evaluation.metrics import first_correct_rank

    rng = np.random.default_rng(11)
    awkward = ["plain.png", "a,b.png", 'say "cheese".png', "two\nlines.png", "cr\r.png", " lead space.png",
               "tab\there.png", "ünïcødé.png", "", "semi;colon.png", "'single'.png", '"', ","]
    n_ref, n_q, k = len(awkward), 9, 4
    ref_names = awkward
    query_names = [awkward[(3 * i + 1) % n_ref] for i in range(n_q)]
    ranked = rng.integers(-1, n_ref, (n_q, k))
    scores = rng.random((n_q, k)) * 1e3
    scores[0, 1], scores[2, 3] = np.nan, np.inf
    s = SimpleNamespace(query=np.arange(n_q), has_positive=rng.random(n_q) < 0.7,
                        example_positive=rng.integers(-1, n_ref, n_q), best=ranked[:, 0],
                        confidence=rng.random(n_q), best_correct=rng.random(n_q) < 0.5, ranked=ranked,
                        ranked_scores=scores, ranked_correct=rng.random((n_q, k)) < 0.3)
    got = write_per_query_csv(tmp_path / "per_query.csv", s, query_names, ref_names).read_bytes()

    def name(r: int) -> str:
        return ref_names[r] if r >= 0 else ""

    first = first_correct_rank(s.ranked_correct)
    with open(tmp_path / "reference.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        head = ["query", "query_image", "has_positive", "positive_reference", "positive_image", "best_reference",
                "best_image", "confidence", "correct", "first_correct_rank"]
        w.writerow(head + [f"{c}_{i}" for i in range(1, k + 1) for c in ("ref", "image", "score", "correct")])
        for q in range(n_q):
            row = [q, query_names[q], int(s.has_positive[q]), *(("", "") if s.example_positive[q] < 0 else
                                                                 (int(s.example_positive[q]), name(s.example_positive[q]))),
                   *(("", "") if s.best[q] < 0 else (int(s.best[q]), name(s.best[q]))), f"{s.confidence[q]:.6f}",
                   int(s.best_correct[q]), int(first[q])]
            for j in range(k):
                r, sc = int(ranked[q, j]), float(scores[q, j])
                row += ["" if r < 0 else r, name(r), "" if r < 0 or not np.isfinite(sc) else f"{sc:.6g}",
                        int(s.ranked_correct[q, j])]
            w.writerow(row)
    assert got == (tmp_path / "reference.csv").read_bytes()
    assert [csv_field(t) for t in ("x", "")] == ["x", ""]


def test_a_polyline_keeps_one_point_an_output_pixel_and_its_last():
    from placeloc.evaluation.raster import _one_point_a_pixel

    # canvas pixels, 2 a side of an output pixel: (0.1, 0.2) and (1.9, 1.0) share the first
    px = np.array([0.1, 1.9, 2.0, 2.5, 3.9, 4.0, 4.1, 4.2])
    py = np.array([0.2, 1.0, 0.0, 1.5, 0.1, 0.0, 0.0, 0.0])
    kx, ky = _one_point_a_pixel(px, py, 2)
    assert kx.tolist() == [0.1, 2.0, 4.0, 4.2] and ky.tolist() == [0.2, 0.0, 0.0, 0.0]
    # a pixel left and come back to is drawn again (the path, not the set of pixels)
    kx, _ = _one_point_a_pixel(np.array([0.0, 3.0, 0.5, 3.5]), np.zeros(4), 2)
    assert kx.tolist() == [0.0, 3.0, 0.5, 3.5]
    # a PR curve of 100,000 queries: the points drawn are bounded by the picture, not the queries
    rng = np.random.default_rng(0)
    recall = np.cumsum(rng.random(100_000) < 0.8) / 100_000
    precision = np.cumsum(rng.random(100_000) < 0.8) / np.arange(1, 100_001)
    kx, _ = _one_point_a_pixel(recall * 1800, (1 - precision) * 1500, 3)
    assert len(kx) < 2_000


def test_seqslam_localize_and_evaluate_run_without_importing_opencv(route, tmp_path):
    """OpenCV's import costs a process 20 ms: SeqSLAM's localize and evaluate (pictures
    off, as a sweep runs them) never decode an image, so their processes do without it."""
    import subprocess
    import sys

    from placeloc.core.config import load_config
    from placeloc.core.runner import run_stage

    config = route / "config.yaml"
    run_stage(load_config(config), tmp_path / "run", "extract", quiet=True)
    code = ("import sys; from placeloc.core.config import load_config; from placeloc.core.runner import run_stage; "
            f"cfg = load_config({str(config)!r}, overrides=['plots=false']); "
            f"[run_stage(cfg, {str(tmp_path / 'run')!r}, s, quiet=True) for s in ('localize', 'evaluate')]; "
            "print('cv2' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    assert out.strip().splitlines()[-1] == "False"
    assert (tmp_path / "run" / "metrics.json").is_file()
