"""Plots a person would rather look at than read (PNG, matplotlib's Agg backend)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def _save(fig: plt.Figure, path: Path, dpi: int = 110, photo: bool = False, tight: bool = True) -> Path:
    """Save under a temporary name and rename, so a killed run never leaves half a PNG;
    a failed save (a full disk) leaves no temporary file either. ``photo``: pictures of
    images or matrices, which zlib hardly shrinks: the fastest compression (level 1 took a
    fifth of level 6's time on the strips, for files about a tenth larger). ``tight``:
    crop to the drawn content (a second layout pass; a figure laid out by ``layout=
    "constrained"`` or placed by hand needs none)."""
    from placeloc.core.artifacts import tmp_path_for

    path = Path(path)
    tmp = tmp_path_for(path)
    try:
        fmt = path.suffix.lstrip(".") or "png"
        extra = {"pil_kwargs": {"compress_level": 1}} if photo and fmt == "png" else {}
        fig.savefig(tmp, dpi=dpi, bbox_inches="tight" if tight else None, format=fmt, **extra)
        tmp.replace(path)
    finally:
        plt.close(fig)
        tmp.unlink(missing_ok=True)
    return path


LINE_STYLES = ("-", "--", "-.", ":")
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")


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
    fig, ax = plt.subplots(figsize=(6.0, 4.8))
    order = sorted(curves, key=lambda k: -_auc(*curves[k]))
    for i, label in enumerate(order):
        rec, prec = curves[label]
        if not len(rec):
            ax.plot([], [], label=f"{label} (no matches)")
            continue
        x, y = np.r_[0.0, rec], np.r_[prec[0], prec]
        line, = ax.plot(x, y, LINE_STYLES[i % len(LINE_STYLES)], lw=2.2 - 0.25 * min(i, 4), marker=MARKERS[i % len(MARKERS)],
                        markevery=max(1, len(x) // 6), ms=5, alpha=0.9, label=f"{label}  (AUC {_auc(rec, prec):.3f})",
                        zorder=10 - i)
        # where the curve ends (every match accepted): visible even under a curve that goes further
        ax.plot(x[-1], y[-1], "|", color=line.get_color(), ms=16, mew=2.5, zorder=20)
        ax.annotate(f"{x[-1]:.3f}", (x[-1], y[-1]), textcoords="offset points", xytext=(0, -16 - 11 * i), ha="center",
                    fontsize=7.5, color=line.get_color(), zorder=20)
    ax.set_xlim(-0.01, 1.01)
    ax.set_ylim(0, 1.03)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("precision")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    if curves:
        ax.legend(fontsize=8, loc="lower left", framealpha=0.9)
    return _save(fig, path)


def plot_recall_at_n(curves: dict[str, tuple[Sequence[int], Sequence[float | None]]], path: Path,
                     title: str = "Recall@N") -> Path:
    """``curves``: label -> (N values, recall at each N; None = unknown). Log-scaled N."""
    fig, ax = plt.subplots(figsize=(6.0, 4.4))
    all_n: set[int] = set()
    for i, (label, (ns, vals)) in enumerate(curves.items()):
        pts = [(n, v) for n, v in zip(ns, vals) if v is not None]
        if not pts:
            continue
        x, y = zip(*pts)
        all_n.update(x)
        (line,) = ax.plot(x, y, LINE_STYLES[i % len(LINE_STYLES)], marker=MARKERS[i % len(MARKERS)], ms=6, lw=2,
                          label=label)
        for xi, yi in pts:  # values in the line's colour, first curve above its points, second below
            ax.annotate(f"{yi:.2f}", (xi, yi), textcoords="offset points", xytext=(0, 8 if i % 2 == 0 else -14),
                        ha="center", fontsize=7.5, color=line.get_color(), fontweight="bold")
    ax.set_xscale("log")
    ticks = sorted(all_n) or [1]
    ax.set_xticks(ticks, [str(t) for t in ticks])
    ax.minorticks_off()
    ax.set_ylim(0, 1.08)
    ax.set_xlabel("N (candidates considered per query)")
    ax.set_ylabel("recall@N")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    if curves:
        ax.legend(fontsize=8, loc="lower right", framealpha=0.9)
    return _save(fig, path)


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
    n = len(panels)
    fig, axes = plt.subplots(1, n, figsize=(6.6 * n, 5.6), squeeze=False, layout="constrained")
    sr, sq = stride
    for ax, (name, matrix) in zip(axes[0], panels.items()):
        nr, nq = matrix.shape
        finite = matrix[np.isfinite(matrix)]
        vmin, vmax = (np.percentile(finite, [1, 99]) if finite.size else (0, 1))
        im = ax.imshow(matrix, cmap="gray", aspect="auto", vmin=vmin, vmax=vmax, interpolation="nearest",
                       extent=(-0.5 * sq, (nq - 0.5) * sq, (nr - 0.5) * sr, -0.5 * sr))
        cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02)
        cb.set_label(f"{name} (lower = more alike)", fontsize=8)
        if gt_points is not None and len(gt_points[0]):
            ax.scatter(gt_points[0], gt_points[1], s=7, c="cyan", marker="s", alpha=0.8, lw=0, zorder=2,
                       label="ground truth (a true pair that counts)")
        if gt_lo is not None and gt_hi is not None and (gt_hi >= gt_lo).any():
            q = np.arange(len(gt_lo))
            ok = gt_hi >= gt_lo
            ax.fill_between(q[ok], gt_lo[ok] - 0.5, gt_hi[ok] + 0.5, color="cyan", alpha=0.18, lw=0, zorder=2)
            ax.plot(q[ok], gt_lo[ok] - 0.5, color="cyan", lw=0.8, zorder=3, label="ground truth band")
            ax.plot(q[ok], gt_hi[ok] + 0.5, color="cyan", lw=0.8, zorder=3)
        if matches is not None:
            q = np.arange(len(matches))
            has = matches >= 0
            if correct is None:
                ax.scatter(q[has], matches[has], s=6, c="orange", label="best match", zorder=4)
            else:
                good, bad = has & correct, has & ~correct
                ax.scatter(q[good], matches[good], s=6, c="lime", label=f"correct match ({good.sum()})", zorder=4)
                ax.scatter(q[bad], matches[bad], s=9, c="red", marker="x", label=f"wrong match ({bad.sum()})", zorder=5)
        ax.set_xlabel("query frame")
        ax.set_ylabel("reference frame")
        ax.set_title(name, fontsize=9)
        # lower left: below the diagonal, where neither a route band nor a loop closure (an earlier frame) lies
        ax.legend(fontsize=7, loc="lower left", markerscale=2, framealpha=0.85)
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path, photo=True, tight=False)


def plot_sweep(curves: dict[str, tuple[np.ndarray, np.ndarray]], recalls: dict[str, tuple[Sequence[int], Sequence[float | None]]],
               path: Path, title: str = "Sweep") -> Path:
    """PR curves (AUC in the legend) and standard Recall@N of every run of a sweep, side by side."""
    fig, (ax_pr, ax_rn) = plt.subplots(1, 2, figsize=(12.5, 5.0), layout="constrained")
    labels = list(dict.fromkeys([*curves, *recalls]))
    style = {k: (f"C{i % 10}", LINE_STYLES[i % 4], MARKERS[i % 8]) for i, k in enumerate(labels)}  # same look in both panels
    order = sorted(curves, key=lambda k: -_auc(*curves[k]))
    for i, label in enumerate(order):
        rec, prec = curves[label]
        if len(rec):
            x, y = np.r_[0.0, rec], np.r_[prec[0], prec]
            c, ls, mk = style[label]
            ax_pr.plot(x, y, ls, color=c, marker=mk, markevery=max(1, len(x) // 6), ms=4, lw=1.8,
                       label=f"{label} (AUC {_auc(rec, prec):.3f})", zorder=20 - i)
    ax_pr.set(xlim=(-0.01, 1.01), ylim=(0, 1.03), xlabel="recall (share of all queries)", ylabel="precision",
              title="precision-recall")
    ax_pr.grid(alpha=0.3)
    all_n: set[int] = set()
    for label, (ns, vals) in recalls.items():
        pts = [(n, v) for n, v in zip(ns, vals) if v is not None]
        if pts:
            x, y = zip(*pts)
            all_n.update(x)
            c, ls, mk = style[label]
            ax_rn.plot(x, y, ls, color=c, marker=mk, ms=5, lw=1.8, label=label)
    ax_rn.set_xscale("log")
    ticks = sorted(all_n) or [1]
    ax_rn.set_xticks(ticks, [str(t) for t in ticks])
    ax_rn.minorticks_off()
    ax_rn.set(ylim=(0, 1.05), xlabel="N", ylabel="standard recall@N (all queries)", title="Recall@N")
    ax_rn.grid(alpha=0.3)
    for ax in (ax_pr, ax_rn):
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="lower left" if ax is ax_pr else "lower right", framealpha=0.9)
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)
