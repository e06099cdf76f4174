"""Plots a person would rather look at than read (PNG, matplotlib's Agg backend)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def _save(fig: plt.Figure, path: Path) -> Path:
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    fig.savefig(tmp, dpi=110, bbox_inches="tight")
    plt.close(fig)
    tmp.replace(path)
    return path


def plot_pr_curves(curves: dict[str, tuple[np.ndarray, np.ndarray]], path: Path, title: str = "Precision-recall") -> Path:
    """``curves``: label -> (recall, precision)."""
    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    for label, (rec, prec) in curves.items():
        if len(rec):
            ax.plot(np.r_[0.0, rec], np.r_[prec[0], prec], label=label, lw=1.5)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("recall")
    ax.set_ylabel("precision")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    if curves:
        ax.legend(fontsize=8, loc="lower left")
    return _save(fig, path)


def plot_difference_matrix(matrix: np.ndarray, path: Path, matches: np.ndarray | None = None,
                           correct: np.ndarray | None = None, gt_lo: np.ndarray | None = None,
                           gt_hi: np.ndarray | None = None, stride: tuple[int, int] = (1, 1),
                           title: str = "difference matrix (rows = reference, columns = query)") -> Path:
    """Show ``matrix[r, q]`` (lower = darker = more alike), the ground-truth band and the
    matches (green = correct, red = wrong). ``stride`` is the subsampling already applied."""
    fig, ax = plt.subplots(figsize=(6.5, 6.0))
    sr, sq = stride
    nr, nq = matrix.shape
    finite = matrix[np.isfinite(matrix)]
    vmin, vmax = (np.percentile(finite, [1, 99]) if finite.size else (0, 1))
    ax.imshow(matrix, cmap="gray", aspect="auto", vmin=vmin, vmax=vmax, interpolation="nearest",
              extent=(-0.5 * sq, (nq - 0.5) * sq, (nr - 0.5) * sr, -0.5 * sr))
    if gt_lo is not None and gt_hi is not None:
        q = np.arange(len(gt_lo))
        ok = gt_hi >= gt_lo
        ax.fill_between(q[ok], gt_lo[ok], gt_hi[ok], color="deepskyblue", alpha=0.25, lw=0, label="ground truth")
    if matches is not None:
        q = np.arange(len(matches))
        has = matches >= 0
        if correct is None:
            ax.scatter(q[has], matches[has], s=4, c="orange", label="match")
        else:
            good = has & correct
            bad = has & ~correct
            ax.scatter(q[good], matches[good], s=4, c="lime", label="correct match")
            ax.scatter(q[bad], matches[bad], s=4, c="red", label="wrong match")
    ax.set_xlabel("query")
    ax.set_ylabel("reference")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="upper right", markerscale=2)
    return _save(fig, path)


def plot_bars(labels: Sequence[str], values: dict[str, Sequence[float]], path: Path, title: str) -> Path:
    fig, ax = plt.subplots(figsize=(7, 3.8))
    width = 0.8 / max(1, len(values))
    x = np.arange(len(labels))
    for i, (name, vals) in enumerate(values.items()):
        ax.bar(x + i * width, vals, width, label=name)
    ax.set_xticks(x + width * (len(values) - 1) / 2, labels, rotation=30, ha="right")
    ax.set_title(title)
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)
