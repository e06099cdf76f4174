"""The co-embedding map figure (the paper's fig. 4): estimates, truth, error lines, landmarks, paths."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402


def _save(fig: plt.Figure, path: Path) -> Path:
    """Save under a temporary name and rename, so a killed run never leaves half a PNG;
    a failed save (a full disk) leaves no temporary file either."""
    import os

    from placeloc.artifacts import TMP_MARK

    path = Path(path)
    tmp = path.with_name(f".{path.name}{TMP_MARK}{os.getpid()}")
    try:
        fig.savefig(tmp, dpi=120, bbox_inches="tight", format=path.suffix.lstrip(".") or "png")
        tmp.replace(path)
    finally:
        plt.close(fig)
        tmp.unlink(missing_ok=True)
    return path


def plot_map(path: Path, est: np.ndarray, truth: np.ndarray, landmarks: np.ndarray, path_est: np.ndarray | None,
             path_truth: np.ndarray | None, title: str, units: str) -> Path:
    """Top view of the map: a 3-D map is drawn from above (first and last axis: x and depth)."""
    ax0, ax1 = 0, truth.shape[1] - 1
    names = ("x", "y") if truth.shape[1] == 2 else ("X", "Z (depth)")
    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    if path_truth is not None:
        ax.plot(path_truth[:, 0], path_truth[:, 1], color="0.75", lw=0.8, label="true path")
    if path_est is not None:
        ax.plot(path_est[:, 0], path_est[:, 1], color="tab:orange", lw=0.8, alpha=0.8, label="estimated path")
    segs = np.stack([est[:, [ax0, ax1]], truth[:, [ax0, ax1]]], axis=1)
    ax.add_collection(LineCollection(segs, colors="tab:green", lw=0.8, label="error (estimate to truth)"))
    ax.scatter(truth[:, ax0], truth[:, ax1], s=14, facecolors="none", edgecolors="0.4", lw=0.7, label="true position")
    ax.scatter(est[:, ax0], est[:, ax1], s=10, color="tab:blue", label="estimated position")
    ax.scatter(landmarks[:, ax0], landmarks[:, ax1], s=40, marker="s", color="tab:red", label="landmark (known)")
    pts = np.vstack([est[:, [ax0, ax1]], truth[:, [ax0, ax1]], landmarks[:, [ax0, ax1]]])
    span = np.ptp(pts, axis=0) + 1e-12
    # Equal scales unless that would squash the figure into a strip (a forward-looking camera: depth >> width).
    to_scale = max(span) / min(span) < 3.0
    if to_scale:
        ax.set_aspect("equal")
    ax.set_xlabel(f"{names[0]} ({units})")
    ax.set_ylabel(f"{names[1]} ({units})" + ("" if to_scale else ", axes not to scale"))
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3, frameon=False)
    return _save(fig, path)
