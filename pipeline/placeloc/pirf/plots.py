"""PIRF-nav2 figures written into a run directory (matplotlib, Agg)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_loop_closures(path: Path, r_xy: np.ndarray, frames: np.ndarray, nodes: np.ndarray, correct: np.ndarray,
                       radius: float) -> None:
    """The mapping path with each loop closure drawn at the frame that closed it, green when
    the matched node stands within ``radius`` metres, red otherwise (with a line to where it matched)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    ax.plot(r_xy[:, 0], r_xy[:, 1], "-", color="0.75", lw=1, label="mapping path")
    good, bad = frames[correct], frames[~correct]
    ax.plot(r_xy[good, 0], r_xy[good, 1], ".", color="tab:green", ms=5, label=f"correct loop closure ({len(good)})")
    for f, c in zip(bad, nodes[~correct]):
        ax.plot([r_xy[f, 0], r_xy[c, 0]], [r_xy[f, 1], r_xy[c, 1]], "-", color="tab:red", lw=0.6, alpha=0.6)
    ax.plot(r_xy[bad, 0], r_xy[bad, 1], "x", color="tab:red", ms=6, label=f"wrong loop closure ({len(bad)}), line to match")
    ax.plot(r_xy[:1, 0], r_xy[:1, 1], "k^", ms=7, label="start")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    prec = f"{correct.mean():.3f}" if len(correct) else "n/a"
    ax.set_title(f"PIRF-nav2 loop closures: {len(frames)}, precision {prec}\n(correct = matched node within {radius:g} m)",
                 fontsize=10)
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, borderaxespad=0)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


def plot_loop_closure_pairs(path: Path, frames: np.ndarray, nodes: np.ndarray, correct: np.ndarray, truth_i: np.ndarray,
                            truth_j: np.ndarray, n_frames: int, tolerance: int, local: np.ndarray) -> None:
    """Loop closures judged by a matrix or CSV truth (no positions to draw a path with): each
    closure as (frame, matched earlier frame), green when the truth has a one there within
    ``tolerance`` frames, red otherwise, over the truth's pairs in grey. ``truth_i/j`` are
    original indices, ``local`` maps them to positions in the frame list."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 6.0))
    ok = (truth_i < len(local)) & (truth_j < len(local))
    ti, tj = local[truth_i[ok]], local[truth_j[ok]]
    keep = (ti >= 0) & (tj >= 0)
    if keep.any():
        ax.plot(ti[keep], tj[keep], ",", color="0.6", alpha=0.6)
        ax.plot([], [], "s", color="0.6", ms=4, label=f"true pair (frame, earlier frame): {int(keep.sum())}")
    good, bad = correct, ~correct
    ax.plot(frames[good], nodes[good], "o", color="tab:green", ms=4, label=f"correct loop closure ({int(good.sum())})")
    ax.plot(frames[bad], nodes[bad], "x", color="tab:red", ms=6, mew=1.5, label=f"wrong loop closure ({int(bad.sum())})")
    ax.set_xlim(-0.5, n_frames - 0.5)
    ax.set_ylim(-0.5, n_frames - 0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("frame that closed the loop")
    ax.set_ylabel("earlier frame it matched")
    prec = f"{correct.mean():.3f}" if len(correct) else "none to judge"
    ax.set_title(f"PIRF-nav2 loop closures: {len(frames)}, precision {prec}\n(correct = a one in the truth matrix within "
                 f"{tolerance} frames)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, borderaxespad=0)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


def plot_accuracy_gap(path: Path, ann: list[float], bf: list[float] | None, backend: str, radius: float) -> None:
    """Localization accuracy against gap tolerance (Figs. 6-7), ANN beside brute force."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 3.5))
    gaps = np.arange(len(ann))
    ax.bar(gaps - 0.2, ann, 0.4, label=f"ANN ({backend})")
    if bf is not None:
        ax.bar(gaps + 0.2, bf, 0.4, label="brute force")
    ax.set_xticks(gaps)
    ax.set_xlabel("gap tolerance (nodes)")
    ax.set_ylabel("localization accuracy")
    ax.set_title(f"localization of the unseen run\n(correct: matched node within gap nodes of one within {radius:g} m)", fontsize=9)
    ax.set_ylim(0, 1)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, frameon=False)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


def plot_closure_strips(path: Path, images: list[tuple[Any, ...]], titles: list[tuple[str, ...]], heading: str) -> None:
    """One row per loop closure: the frame that closed the loop, the node it matched and
    the earlier frame that truly stands nearest (greyscale omnidirectional frames)."""
    plt = _plt()
    rows, cols = len(images), max(len(r) for r in images)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.3 * rows + 0.5), squeeze=False)
    for r, (imgs, tts) in enumerate(zip(images, titles)):
        for c in range(cols):
            ax = axes[r, c]
            ax.axis("off")
            if c < len(imgs):
                ax.imshow(imgs[c], cmap="gray", vmin=0, vmax=255)
                ax.set_title(tts[c], fontsize=8)
    fig.suptitle(heading, fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.5 / (2.3 * rows + 0.5)), h_pad=1.0, w_pad=0.4)
    fig.savefig(path, dpi=90)
    plt.close(fig)
