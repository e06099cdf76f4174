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
    from placeloc.evaluation import raster as R

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
    # an image in an axis-parallel frame: no supersampling needed
    canvas = R.Canvas(1000, 560, ss=1)
    ax = R.Axes(canvas, (70, 56, 980, 504), (180.0, -180.0), (-90.0, 90.0))
    ax.frame(np.arange(-150, 151, 50), np.arange(-80, 81, 20), grid=False)
    ax.image(np.round(img * 255).astype(np.uint8))
    ax.box()
    ax.labels("azimuth relative to the panorama's centre column [deg] (left is counter-clockwise)", "elevation [deg]",
              title + "\ngrey: detected lines; red: map at the estimate"
              + (f"; green: map at {second}; brown: both" if at_truth is not None else "")
              + ("; blue: not in the photo" if unseen is not None and np.any(unseen) else ""),
              size=12, title_size=11)
    canvas.save(path)
