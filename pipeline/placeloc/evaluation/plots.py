"""Plots a person would rather look at than read (PNG).

The pictures evaluate draws on every run (precision-recall, Recall@N, the difference
matrices here; the poses, map and loop-closure contracts' and the methods' own beside
them) and a sweep's summary are drawn with :mod:`placeloc.evaluation.raster` (Pillow), in
milliseconds; matplotlib's import alone took 0.4 s. Only the experiments' figures for the
docs use matplotlib (an optional dependency).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from placeloc.evaluation import raster as R

LINE_STYLES = ("-", "--", "-.", ":")
# the raster charts' markers (Pillow draws these shapes)
RASTER_MARKERS = ("o", "s", "^", "D", "v", "x", "+")
PT = 110 / 72  # output pixels per typographic point at the pictures' 110 dpi


def _auc(rec: np.ndarray, prec: np.ndarray) -> float:
    if len(rec) == 0:
        return 0.0
    r = np.r_[0.0, rec]
    p = np.r_[prec[0], prec]
    return float(np.sum(np.diff(r) * (p[1:] + p[:-1]) * 0.5))


def plot_pr_curves(curves: dict[str, tuple[np.ndarray, np.ndarray]], path: Path, title: str = "Precision-recall",
                   xlabel: str = "recall (share of all queries matched correctly)") -> Path:
    """``curves``: label -> (recall, precision). Each curve has its own line style and a
    few markers, so curves lying on top of each other stay visible, and a bar with its
    recall where it ends; the legend gives the AUC (trapezoids over recall, as
    :class:`placeloc.evaluation.metrics.PRCurve`)."""
    extra = 17 * title.count("\n")  # room for a title of several lines
    c = R.Canvas(660, 530 + extra)
    ax = R.Axes(c, (70, 34 + extra, 640, 466 + extra), (-0.01, 1.01), (0.0, 1.03))
    ticks = np.round(np.arange(0, 1.01, 0.2), 1)
    ax.frame(ticks, ticks)
    order = sorted(curves, key=lambda k: -_auc(*curves[k]))
    entries: list[R.LegendEntry] = []
    ends: list[tuple[float, float, R.Colour, int]] = []
    for i, label in enumerate(order):
        rec, prec = curves[label]
        colour = R.CYCLE[i % len(R.CYCLE)]
        if not len(rec):
            entries.append(R.LegendEntry(f"{label} (no matches)", colour, line_width=2.0))
            continue
        x, y = np.r_[0.0, rec], np.r_[prec[0], prec]
        style, marker = LINE_STYLES[i % len(LINE_STYLES)], RASTER_MARKERS[i % len(RASTER_MARKERS)]
        width = (2.2 - 0.25 * min(i, 4)) * PT
        ax.line(x, y, colour, width, style)
        every = max(1, len(x) // 6)
        ax.markers(x[::every], y[::every], colour, marker, 5 * PT)
        entries.append(R.LegendEntry(f"{label}  (AUC {_auc(rec, prec):.3f})", colour, line_width=width, style=style,
                                     marker=marker, marker_size=5 * PT))
        ends.append((float(x[-1]), float(y[-1]), colour, i))
    ax.labels(xlabel, "precision", title)
    # where each curve ends (every match accepted): visible even under a curve that goes further
    for x_end, y_end, colour, i in ends:
        ax.markers(np.array([x_end]), np.array([y_end]), colour, "|", 16 * PT, edge=2.5 * PT)
        # under the end, or over it where under would cross the x axis (an end at low precision)
        low = y_end < 0.15
        ax.text(x_end, y_end, f"{x_end:.3f}", 11, dy=(-(10 + 11 * i) if low else (16 + 11 * i)) * PT, fill=colour,
                anchor="md")
    # lower left, unless every curve ends before half the recall: then the right half is empty
    # and the lower left holds the curves' ends and their labels; the other corners where
    # that one would cover a curve (a curve falling to low precision at low recall)
    first = "lower right" if ends and max(e[0] for e in ends) <= 0.5 else "lower left"
    ax.legend(entries, (first, *(c for c in ("lower left", "lower right", "upper right", "upper left") if c != first)),
              size=11)
    return c.save(path)


def plot_kept_precision(path: Path, kept: np.ndarray, right: np.ndarray, n_frames: int, *, confidence_label: str,
                        label: str, right_means: str, kept_at_100: int, threshold: float | None) -> Path:
    """Which answers to trust: the share of the kept answers that are right against the share
    of all ``n_frames`` kept as a confidence threshold falls, from ``kept`` frames and the
    ``right`` answers among them at each threshold (one point per threshold, from the most
    confident answer to all of them; drawn from the first point's precision at 0, as
    :func:`plot_pr_curves`); the share right over all frames as a dashed line (what a
    confidence that says nothing would give); a diamond where the last threshold keeping
    only right answers stands (``kept_at_100`` frames, at confidence ``threshold``)."""
    c = R.Canvas(700, 560)
    ax = R.Axes(c, (84, 40, 676, 476), (-0.01, 1.01), (0.0, 1.05))
    ticks = np.round(np.arange(0, 1.01, 0.2), 1)
    ax.frame(ticks, ticks, size=13)
    ax.labels("share of all frames kept (threshold falling)", f"precision (share of kept answers {right_means})",
              f"{label}: trusting the answers by {confidence_label}", size=14, title_size=15)
    kept, right = np.asarray(kept, np.float64), np.asarray(right, np.float64)
    if not len(kept):
        return c.save(path)
    share, precision = kept / n_frames, right / kept
    grey, blue, green = (110, 110, 110), R.CYCLE[0], R.CYCLE[2]
    ax.line(np.array([0.0, 1.0]), np.array([precision[-1]] * 2), grey, 1.6 * PT, "--")
    ax.line(np.r_[0.0, share], np.r_[precision[0], precision], blue, 2.4 * PT)
    few = len(kept) <= 60  # every threshold a point while they can be told apart
    if few:
        ax.markers(share, precision, blue, "o", 4.5 * PT)
    entries = [R.LegendEntry("kept answers" + (" (a point per threshold)" if few else ""), blue, line_width=2.4 * PT,
                             marker="o" if few else "", marker_size=4.5 * PT),
               R.LegendEntry(f"all answers: {int(right[-1])} of {n_frames} right", grey, line_width=1.6 * PT,
                             style="--")]
    if kept_at_100 > 0:
        ax.markers(np.array([kept_at_100 / n_frames]), np.array([1.0]), green, "D", 9 * PT)
        entries.append(R.LegendEntry(f"{kept_at_100} of {n_frames} kept, every one right", green, marker="D",
                                     marker_size=9 * PT))
        if threshold is not None:
            entries.append(R.LegendEntry(f"at {confidence_label} >= {threshold:.4g}", green))
    else:
        entries.append(R.LegendEntry("no threshold keeps only right answers", R.BLACK))
    # lower left: a confidence worth having keeps its first answers right, so the curve starts high there
    ax.legend(entries, ("lower left", "lower right", "upper right", "upper left"), size=13)
    return c.save(path)


def plot_recall_at_n(curves: dict[str, tuple[Sequence[int], Sequence[float | None]]], path: Path,
                     title: str = "Recall@N") -> Path:
    """``curves``: label -> (N values, recall at each N; None = unknown). Log-scaled N."""
    plotted = []
    all_n: set[int] = set()
    for label, (ns, vals) in curves.items():
        pts = [(int(n), float(v)) for n, v in zip(ns, vals) if v is not None]
        plotted.append((label, pts))
        all_n.update(n for n, _ in pts)
    ticks = sorted(all_n) or [1]
    lo, hi = min(ticks), max(ticks)
    if hi == lo:
        lo, hi = lo / 1.5, hi * 1.5
    pad = (np.log10(hi) - np.log10(lo)) * 0.05
    extra = 17 * title.count("\n")
    c = R.Canvas(660, 490 + extra)
    ax = R.Axes(c, (70, 34 + extra, 640, 426 + extra), (10 ** (np.log10(lo) - pad), 10 ** (np.log10(hi) + pad)), (0.0, 1.08), xlog=True)
    ax.frame(ticks, np.round(np.arange(0, 1.01, 0.2), 1), xlabels=[str(t) for t in ticks])
    entries: list[R.LegendEntry] = []
    for i, (label, pts) in enumerate(plotted):
        if not pts:
            continue
        colour = R.CYCLE[i % len(R.CYCLE)]
        style, marker = LINE_STYLES[i % len(LINE_STYLES)], RASTER_MARKERS[i % len(RASTER_MARKERS)]
        x, y = (np.array(v, np.float64) for v in zip(*pts))
        ax.line(x, y, colour, 2 * PT, style)
        ax.markers(x, y, colour, marker, 6 * PT)
        entries.append(R.LegendEntry(label, colour, line_width=2 * PT, style=style, marker=marker, marker_size=6 * PT))
        for xi, yi in pts:  # values in the line's colour, first curve above its points, second below
            above = i % 2 == 0
            ax.text(xi, yi, f"{yi:.2f}", 11, dy=-8 * PT if above else 8 * PT, fill=colour, anchor="md" if above else "ma")
    ax.labels("N (candidates considered per query)", "recall@N", title)
    ax.legend(entries, ("lower right", "lower left", "upper left", "upper right"), size=11)
    return c.save(path)


_MATCH_GOOD, _MATCH_BAD, _MATCH_UNJUDGED, _TRUTH = (0, 255, 0), (255, 0, 0), (255, 165, 0), (0, 255, 255)


def plot_difference_matrices(panels: dict[str, np.ndarray], path: Path, *, matches: np.ndarray | None = None,
                             correct: np.ndarray | None = None, gt_lo: np.ndarray | None = None,
                             gt_hi: np.ndarray | None = None, gt_points: tuple[np.ndarray, np.ndarray] | None = None,
                             stride: tuple[int, int] = (1, 1), title: str = "") -> Path:
    """Difference matrices side by side (e.g. raw and enhanced), each with a colour bar:
    rows = reference, columns = query, darker = more alike. Under the matches (green =
    correct, red = wrong, orange = no ground truth) the ground-truth band is outlined in
    cyan, so that it stays visible where a match hides it; a truth that is no band (a
    loop-closure matrix: several revisits per frame) is drawn as cyan points
    ``gt_points`` = (query, reference). The legend lists only what is drawn. ``stride`` =
    (reference, query) subsampling already applied; axes are in original frame numbers."""
    panel_w, extra = 712, 18 * title.count("\n")
    height = 616 + extra
    # not supersampled: the matrix is an image already, and smoothing thousands of markers
    # and two 800 x 800 panels at twice the size cost a third of the picture
    c = R.Canvas(panel_w * max(1, len(panels)), height, ss=1)
    sr, sq = stride
    for k, (name, matrix) in enumerate(panels.items()):
        x0 = k * panel_w
        nr, nq = matrix.shape
        finite = matrix[np.isfinite(matrix)]
        vmin, vmax = R.percentiles(finite, (1, 99)) if finite.size else (0.0, 1.0)
        ax = R.Axes(c, (x0 + 76, 60 + extra, x0 + 600, height - 58), (-0.5 * sq, (nq - 0.5) * sq), (-0.5 * sr, (nr - 0.5) * sr),
                    y_down=True)
        ax.image(R.grey_image(matrix, vmin, vmax))
        entries: list[R.LegendEntry] = []
        if gt_points is not None and len(gt_points[0]):
            ax.markers(np.asarray(gt_points[0]), np.asarray(gt_points[1]), _TRUTH, "s", 3.5)
            entries.append(R.LegendEntry("ground truth (a true pair that counts)", _TRUTH, marker="s", marker_size=5))
        if gt_lo is not None and gt_hi is not None and (gt_hi >= gt_lo).any():
            ok = gt_hi >= gt_lo
            q = np.arange(len(gt_lo))[ok]
            lo, hi = gt_lo[ok] - 0.5, gt_hi[ok] + 0.5
            ax.fill_between(q, lo, hi, _TRUTH, 0.18)
            ax.line(q, lo, _TRUTH, 1.2)
            ax.line(q, hi, _TRUTH, 1.2)
            entries.append(R.LegendEntry("ground truth band", _TRUTH, line_width=1.5))
        if matches is not None:
            q = np.arange(len(matches))
            has = matches >= 0
            if correct is None:
                ax.markers(q[has], matches[has], _MATCH_UNJUDGED, "o", 5)
                entries.append(R.LegendEntry("best match", _MATCH_UNJUDGED, marker="o", marker_size=6))
            else:
                good, bad = has & correct, has & ~correct
                ax.markers(q[good], matches[good], _MATCH_GOOD, "o", 5)
                ax.markers(q[bad], matches[bad], _MATCH_BAD, "x", 6, edge=2)
                entries += [R.LegendEntry(f"correct match ({good.sum()})", _MATCH_GOOD, marker="o", marker_size=6),
                            R.LegendEntry(f"wrong match ({bad.sum()})", _MATCH_BAD, marker="x", marker_size=7)]
        xt = R.nice_ticks(0, (nq - 0.5) * sq, most=9)
        yt = R.nice_ticks(0, (nr - 0.5) * sr, most=9)
        ax.frame(xt, yt, grid=False, size=12)
        ax.labels("query frame", "reference frame", name, size=13, title_size=13)
        # lower left: below the diagonal, where neither a route band nor a loop closure (an earlier frame) lies
        ax.legend(entries, ("lower left", "upper right", "lower right", "upper left"), size=11)
        R.colour_bar(c, (x0 + 612, 60 + extra, x0 + 630, height - 58), vmin, vmax, f"{name} (lower = more alike)", size=11)
    if title:
        c.text(c.width / 2, 10, title, 14, anchor="ma")
    return c.save(path, photo=True)


def plot_sweep(curves: dict[str, tuple[np.ndarray, np.ndarray]], recalls: dict[str, tuple[Sequence[int], Sequence[float | None]]],
               path: Path, title: str = "Sweep") -> Path:
    """PR curves (AUC in the legend) and standard Recall@N of every run of a sweep, side by
    side, each run in the same colour, line style and marker in both panels."""
    labels = list(dict.fromkeys([*curves, *recalls]))
    look = {k: (R.CYCLE[i % len(R.CYCLE)], LINE_STYLES[i % len(LINE_STYLES)], RASTER_MARKERS[i % len(RASTER_MARKERS)])
            for i, k in enumerate(labels)}
    extra = 17 * title.count("\n")
    c = R.Canvas(1380, 560 + extra)
    c.text(c.width / 2, 22, title, 14, anchor="ms")
    # precision-recall, left
    ax = R.Axes(c, (70, 50 + extra, 660, 490 + extra), (-0.01, 1.01), (0.0, 1.03))
    ticks = np.round(np.arange(0, 1.01, 0.2), 1)
    ax.frame(ticks, ticks)
    ax.labels("recall (share of all queries)", "precision", "precision-recall")
    entries: list[R.LegendEntry] = []
    order = sorted(curves, key=lambda k: -_auc(*curves[k]))
    for label in reversed(order):  # the best drawn last, on top
        rec, prec = curves[label]
        if len(rec):
            colour, style, marker = look[label]
            x, y = np.r_[0.0, rec], np.r_[prec[0], prec]
            ax.line(x, y, colour, 1.8 * PT, style)
            every = max(1, len(x) // 6)
            ax.markers(x[::every], y[::every], colour, marker, 4.5 * PT)
    for label in order:
        rec, prec = curves[label]
        if len(rec):
            colour, style, marker = look[label]
            entries.append(R.LegendEntry(f"{label} (AUC {_auc(rec, prec):.3f})", colour, line_width=1.8 * PT, style=style,
                                         marker=marker, marker_size=4.5 * PT))
    ax.legend(entries, ("lower left", "lower right", "upper right", "upper left"), size=10)
    # Recall@N, right, log N
    pts_of = {label: [(int(n), float(v)) for n, v in zip(ns, vals) if v is not None] for label, (ns, vals) in recalls.items()}
    all_n = sorted({n for pts in pts_of.values() for n, _ in pts}) or [1]
    lo, hi = min(all_n), max(all_n)
    if hi == lo:
        lo, hi = lo / 1.5, hi * 1.5
    pad = (np.log10(hi) - np.log10(lo)) * 0.05
    ax = R.Axes(c, (770, 50 + extra, 1360, 490 + extra), (10 ** (np.log10(lo) - pad), 10 ** (np.log10(hi) + pad)), (0.0, 1.05),
                xlog=True)
    ax.frame(all_n, ticks, xlabels=[str(n) for n in all_n])
    ax.labels("N", "standard recall@N (all queries)", "Recall@N")
    entries = []
    for label, pts in pts_of.items():
        if pts:
            colour, style, marker = look[label]
            x, y = (np.array(v, np.float64) for v in zip(*pts))
            ax.line(x, y, colour, 1.8 * PT, style)
            ax.markers(x, y, colour, marker, 5.5 * PT)
            entries.append(R.LegendEntry(label, colour, line_width=1.8 * PT, style=style, marker=marker, marker_size=5.5 * PT))
    ax.legend(entries, ("lower right", "lower left", "upper left", "upper right"), size=10)
    return c.save(path)
