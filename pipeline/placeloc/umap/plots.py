"""UMap's own pictures: a panorama's detected lines against the map rendered at the
estimate and at the truth. The cumulative error and the estimates on the plan belong to
the ``poses`` result contract (:mod:`placeloc.evaluation.pose_estimates`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from placeloc.evaluation.pose_estimates import plot_error_cdf, plot_estimates_on_plan  # noqa: F401  (re-exported)


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_panorama_overlay(path: Path, query: np.ndarray, at_estimate: np.ndarray, at_truth: np.ndarray | None,
                          title: str) -> None:
    """One panorama's detected lines (grey) with the map's lines rendered at the estimated
    pose (red) and at the true pose (green): where they differ shows why a query failed.

    Drawn on a figure of its own (not pyplot's) with fixed margins: tight_layout drew each
    picture twice, 126 against 81 ms a picture here, and evaluate draws twelve."""
    _plt()   # the Agg backend
    from matplotlib.figure import Figure

    h, w = query.shape
    img = np.ones((h, w, 3))
    img[query > 0] = (0.55, 0.55, 0.55)
    if at_truth is not None:
        img[at_truth > 0] = (0.1, 0.65, 0.1)
    img[at_estimate > 0] = (0.85, 0.1, 0.1)
    if at_truth is not None:
        img[(at_truth > 0) & (at_estimate > 0)] = (0.55, 0.35, 0.0)
    fig = Figure(figsize=(10, 5.6))
    ax = fig.subplots()
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.1, top=0.9)
    ax.imshow(img, interpolation="nearest", extent=(180, -180, -90, 90), aspect="auto")
    ax.set_xlabel("azimuth relative to the panorama's centre column [deg] (left is counter-clockwise)")
    ax.set_ylabel("elevation [deg]")
    ax.set_title(title + "\ngrey: detected lines; red: map at the estimate; green: map at the truth; brown: both", fontsize=9)
    fig.savefig(path, dpi=100)
