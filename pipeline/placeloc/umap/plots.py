"""UMap's own pictures: a panorama's detected lines against the map rendered at the
estimate and at the truth. The cumulative error and the estimates on the plan belong to
the ``poses`` result contract (:mod:`placeloc.evaluation.pose_estimates`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from placeloc.evaluation.pose_estimates import plot_error_cdf, plot_estimates_on_plan  # noqa: F401  (re-exported)


def plot_panorama_overlay(path: Path, query: np.ndarray, at_estimate: np.ndarray, at_truth: np.ndarray | None,
                          title: str, second: str = "the truth", unseen: np.ndarray | None = None) -> None:
    """One panorama's detected lines (grey) with the map's lines rendered at the estimated
    pose (red) and at the true pose (green): where they differ shows why a query failed.
    ``second`` names the green pose in the legend (a doubtful answer's rival, where there is
    no truth). ``unseen`` (H,) bool: the rows the photo did not cover (a photo sphere stored
    cropped), shaded, so that the map's lines there read as outside the photo, not missed.

    Drawn straight into pixels (:mod:`placeloc.evaluation.raster`), as the ranked results'
    pictures are: with matplotlib (``tight_layout`` drawing it twice) a picture took 126 ms
    here, with fixed margins 81 ms, and evaluate draws twelve."""
    h, w = query.shape
    img = np.ones((h, w, 3))
    if unseen is not None:
        img[np.asarray(unseen, bool)] = (0.86, 0.89, 0.95)
    img[query > 0] = (0.55, 0.55, 0.55)
    if at_truth is not None:
        img[at_truth > 0] = (0.1, 0.65, 0.1)
    img[at_estimate > 0] = (0.85, 0.1, 0.1)
    if at_truth is not None:
        img[(at_truth > 0) & (at_estimate > 0)] = (0.55, 0.35, 0.0)
    _equirect_picture(path, np.round(img * 255).astype(np.uint8),
                      "azimuth relative to the panorama's centre column [deg] (left is counter-clockwise)",
                      title + "\ngrey: detected lines; red: map at the estimate"
                      + (f"; green: map at {second}; brown: both" if at_truth is not None else "")
                      + ("; blue: not in the photo" if unseen is not None and np.any(unseen) else ""))


def _equirect_picture(path: Path, img: np.ndarray, xlabel: str, title: str) -> Path:
    """An (H, W, 3) uint8 equirectangular image in its frame of azimuth (180 deg on the
    left) and elevation: UMap's panorama pictures."""
    from placeloc.evaluation import raster as R

    # an image in an axis-parallel frame: no supersampling needed
    canvas = R.Canvas(1000, 560, ss=1)
    ax = R.Axes(canvas, (70, 56, 980, 504), (180.0, -180.0), (-90.0, 90.0))
    ax.frame(np.arange(-150, 151, 50), np.arange(-80, 81, 20), grid=False)
    ax.image(img)
    ax.box()
    ax.labels(xlabel, "elevation [deg]", title, size=12, title_size=11)
    return canvas.save(path)


def plot_map_view(path: Path, lines: np.ndarray, title: str) -> Path:
    """The map's lines (H, W bool, an equirectangular line image) in black on white, in
    the frame of :func:`plot_panorama_overlay`: what a 360 degree camera at a point of the
    plan would see of the map, to hold against a photo taken there (``placeloc plan``)."""
    img = np.full((*lines.shape, 3), 255, np.uint8)
    img[np.asarray(lines, bool)] = 0
    return _equirect_picture(path, img, "azimuth from the centre column [deg] (left is counter-clockwise)", title)


def plot_ceiling_scores(path: Path, means: np.ndarray, found: float, panoramas: int) -> Path:
    """The home's ceiling search (``umap.grid.ceilings``) at a glance: each ceiling searched
    against its mean over the run's ``panoramas`` of their best grid-table score (``means``:
    (C, 2) rows of ceiling, mean), the ceiling found marked. A sharp peak says the photos
    agree on the height; a flat top or a peak at either end says they do not, or that the
    home's lies outside the heights listed."""
    from placeloc.evaluation import raster as R

    means = np.asarray(means, np.float64).reshape(-1, 2)
    x, y = means[:, 0], means[:, 1]
    pad_x = max(0.05, 0.08 * float(np.ptp(x)))
    span = max(float(np.ptp(y)), 1e-4)
    ylim = (float(y.min()) - 0.12 * span, float(y.max()) + 0.22 * span)
    c = R.Canvas(720, 440)
    ax = R.Axes(c, (86, 44, 700, 380), (float(x.min()) - pad_x, float(x.max()) + pad_x), ylim)
    ax.frame(x, R.nice_ticks(*ylim, most=6), xlabels=[f"{v:.2f}" for v in x])
    blue, orange = R.CYCLE[0], R.CYCLE[1]
    ax.line(np.array([found, found]), np.array(ylim), orange, 1.6, "--")
    ax.line(x, y, blue, 2.0)
    ax.markers(x, y, blue, "o", 8.0)
    best = int(np.argmax(y))
    right = found < float(x.min()) + 0.6 * float(np.ptp(x) or 1.0)
    ax.text(found, ylim[1] - 0.06 * (ylim[1] - ylim[0]), f" ceiling found: {found:.2f} m ", 12, fill=orange,
            anchor="lm" if right else "rm", box=(255, 255, 255))
    # the best mean beside its point, on the side away from the dashed line
    ax.text(x[best], y[best], f"{y[best]:.4f}", 11, dx=-8 if found >= x[best] else 8, dy=-8,
            anchor="rd" if found >= x[best] else "ld")
    ax.labels("ceiling height searched [m]", "mean best grid score",
              f"The home's ceiling: each height's mean best score over the {panoramas} panoramas")
    return c.save(path)
