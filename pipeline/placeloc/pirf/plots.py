"""PIRF-nav2 figures written into a run directory, drawn in pixels
(:mod:`placeloc.evaluation.raster`): milliseconds each, where matplotlib's import alone
took 0.4 s of a small run's evaluate."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from placeloc.evaluation import raster as R

GREEN, RED, BLUE, ORANGE = R.CYCLE[2], R.CYCLE[3], R.CYCLE[0], R.CYCLE[1]
PATH_GREY, PAIR_GREY = (191, 191, 191), (153, 153, 153)


def _square_limits(lo: np.ndarray, hi: np.ndarray, w: float, h: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """Limits around ``lo``..``hi`` widened on the short side so that a ``w`` x ``h`` box shows both axes to scale."""
    c, span = (lo + hi) / 2, np.maximum(hi - lo, 1e-9)
    per_px = max(span[0] / w, span[1] / h)
    return (c[0] - per_px * w / 2, c[0] + per_px * w / 2), (c[1] - per_px * h / 2, c[1] + per_px * h / 2)


def plot_loop_closures(path: Path, r_xy: np.ndarray, frames: np.ndarray, nodes: np.ndarray, correct: np.ndarray,
                       radius: float) -> Path:
    """The mapping path with each loop closure drawn at the frame that closed it, green when
    the matched node stands within ``radius`` metres, red otherwise (with a line to where it
    matched); to scale."""
    r_xy = np.asarray(r_xy, float)
    good, bad = frames[correct], frames[~correct]
    pts = r_xy[np.isfinite(r_xy).all(axis=1)]
    lo, hi = (pts.min(axis=0), pts.max(axis=0)) if len(pts) else (np.zeros(2), np.ones(2))
    pad = 0.04 * np.maximum(hi - lo, 1e-9).max()
    lo, hi = lo - pad, hi + pad
    w, h = R.to_scale_box(lo, hi, 620.0)
    xlim, ylim = _square_limits(lo, hi, w, h)
    prec = f"{correct.mean():.3f}" if len(correct) else "n/a"
    entries = [R.LegendEntry("mapping path", PATH_GREY, line_width=1.5),
               R.LegendEntry(f"correct loop closure ({len(good)})", GREEN, marker="o", marker_size=6),
               R.LegendEntry(f"wrong loop closure ({len(bad)}), line to match", RED, marker="x", marker_size=8),
               R.LegendEntry("start", R.BLACK, marker="^", marker_size=10)]
    c, ax, rows = R.titled_chart(f"PIRF-nav2 loop closures: {len(frames)}, precision {prec}\n"
                                f"(correct = matched node within {radius:g} m)", w, h, entries, xlim, ylim, "x (m)", "y (m)")
    ax.line(r_xy[:, 0], r_xy[:, 1], PATH_GREY, 1.5)
    ax.markers(r_xy[good, 0], r_xy[good, 1], GREEN, "o", 6)
    n_bad = nodes[~correct]
    ax.segments(r_xy[bad, 0], r_xy[bad, 1], r_xy[n_bad, 0], r_xy[n_bad, 1], (230, 140, 140), 1.0)
    ax.markers(r_xy[bad, 0], r_xy[bad, 1], RED, "x", 8)
    ax.markers(r_xy[:1, 0], r_xy[:1, 1], R.BLACK, "^", 10)
    R.legend_below(c, ax, rows)
    return c.save(path)


def plot_loop_closure_pairs(path: Path, frames: np.ndarray, nodes: np.ndarray, correct: np.ndarray, truth_i: np.ndarray,
                            truth_j: np.ndarray, n_frames: int, tolerance: int, local: np.ndarray) -> Path:
    """Loop closures judged by a matrix or CSV truth (no positions to draw a path with): each
    closure as (frame, matched earlier frame), green when the truth has a one there within
    ``tolerance`` frames, red otherwise, over the truth's pairs in grey. ``truth_i/j`` are
    original indices, ``local`` maps them to positions in the frame list."""
    ok = (truth_i < len(local)) & (truth_j < len(local))
    ti, tj = local[truth_i[ok]], local[truth_j[ok]]
    keep = (ti >= 0) & (tj >= 0)
    good, bad = correct, ~correct
    lim = (-0.5, max(n_frames, 1) - 0.5)  # no frames: an empty square, not a range of nothing
    prec = f"{correct.mean():.3f}" if len(correct) else "none to judge"
    entries = ([R.LegendEntry(f"true pair (frame, earlier frame): {int(keep.sum())}", PAIR_GREY, marker="s",
                              marker_size=5)] if keep.any() else []) + [
        R.LegendEntry(f"correct loop closure ({int(good.sum())})", GREEN, marker="o", marker_size=6),
        R.LegendEntry(f"wrong loop closure ({int(bad.sum())})", RED, marker="x", marker_size=8)]
    c, ax, rows = R.titled_chart(f"PIRF-nav2 loop closures: {len(frames)}, precision {prec}\n(correct = a one in the "
                                f"truth matrix within {tolerance} frames)", 560, 560, entries, lim, lim,
                                "frame that closed the loop", "earlier frame it matched")
    if keep.any():
        ax.markers(ti[keep], tj[keep], PAIR_GREY, "s", 1.5)
    ax.markers(frames[good], nodes[good], GREEN, "o", 6)
    ax.markers(frames[bad], nodes[bad], RED, "x", 8)
    R.legend_below(c, ax, rows)
    return c.save(path)


def plot_accuracy_gap(path: Path, ann: list[float], bf: list[float] | None, backend: str, radius: float) -> Path:
    """Localization accuracy against gap tolerance (Figs. 6-7), ANN beside brute force, each
    bar labelled with its value."""
    gaps = np.arange(len(ann))
    series = [(f"ANN ({backend})", ann, BLUE)] + ([("brute force", bf, ORANGE)] if bf is not None else [])
    entries = [R.LegendEntry(label, colour, marker="s", marker_size=11) for label, _, colour in series]
    c, ax, rows = R.titled_chart(f"localization of the unseen run\n(correct: matched node within gap nodes of one "
                                f"within {radius:g} m)", 420, 300, entries, (-0.6, len(ann) - 0.4), (0.0, 1.0),
                                "gap tolerance (nodes)", "localization accuracy", xticks=gaps,
                                xtick_labels=[str(int(g)) for g in gaps], yticks=np.round(np.arange(0, 1.01, 0.2), 1))
    width = 0.8 / len(series)
    for s, (_, values, colour) in enumerate(series):
        for g, v in zip(gaps, values):
            v = 0.0 if v is None or not np.isfinite(v) else float(v)
            x0 = g - 0.4 + s * width
            (px0, px1), (py0, py1) = ax.xy(np.array([x0, x0 + width]), np.array([0.0, v]))
            c.draw.rectangle((px0, py1, px1, py0), fill=colour)
            ax.text(x0 + width / 2, v, f"{v:.2f}", 11, dy=-3, anchor="md")
    ax.box()
    R.legend_below(c, ax, rows)
    return c.save(path)


def plot_closure_strips(path: Path, images: list[tuple[Any, ...]], titles: list[tuple[str, ...]], heading: str) -> Path:
    """One row per loop closure: the frame that closed the loop, the node it matched and
    the earlier frame that truly stands nearest (greyscale frames), each under its title."""
    import cv2

    cols = max(len(r) for r in images)
    cell_w, most_h, title_h, gap = 320, 240, 18, 8

    def grey(img: Any) -> np.ndarray:
        g = np.asarray(img)
        return np.clip(g[..., :3].mean(axis=2) if g.ndim == 3 else g, 0, 255).astype(np.uint8)

    rows = [[grey(img) for img in imgs] for imgs in images]
    # each frame scaled to the cell's width (or to most_h high), each row as high as its tallest
    scales = [[min(cell_w / g.shape[1], most_h / g.shape[0]) for g in row] for row in rows]
    heights = [max(round(g.shape[0] * k) for g, k in zip(row, ks)) for row, ks in zip(rows, scales)]
    width = max(cols * (cell_w + gap) + gap, int(R.text_width(heading, 14)) + 40)
    c = R.Canvas(width, 40 + sum(title_h + h + gap for h in heights), ss=1)  # images and text only: no smoothing needed
    c.text(width / 2, 26, heading, 14, anchor="ms")
    x0 = (width - cols * (cell_w + gap) + gap) / 2
    y = 40.0
    for row, ks, tts, h in zip(rows, scales, titles, heights):
        for col, (g, k, title) in enumerate(zip(row, ks, tts)):
            x = x0 + col * (cell_w + gap)
            c.text(x + cell_w / 2, y + title_h - 4, _fit(title, cell_w, 11), 11, anchor="ms")
            size = (max(1, round(g.shape[1] * k)), max(1, round(g.shape[0] * k)))
            small = cv2.resize(g, size, interpolation=cv2.INTER_AREA if k < 1 else cv2.INTER_LINEAR)
            c.paste(np.repeat(small[..., None], 3, axis=2), x + (cell_w - size[0]) / 2, y + title_h)
        y += title_h + h + gap
    return c.save(path, photo=True)


def _fit(text: str, width: float, size: float) -> str:
    """``text`` cut with an ellipsis to fit ``width`` pixels."""
    if R.text_width(text, size) <= width:
        return text
    while text and R.text_width(text + "…", size) > width:
        text = text[:-1]
    return text + "…"


