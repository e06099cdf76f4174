"""UMap's pictures: cumulative error and the estimates drawn on the floor plan."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_error_cdf(path: Path, err: np.ndarray, mode: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.5))
    e = np.sort(err)
    ax.step(e, np.arange(1, len(e) + 1) / len(e), where="post")
    ax.set_xscale("symlog", linthresh=1.0)
    ax.set_xlabel("error [m]")
    ax.set_ylabel("share of frames")
    ax.set_title(f"cumulative error ({mode})")
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_estimates_on_plan(path: Path, truth: np.ndarray, est: np.ndarray, polys: list[np.ndarray], segments: np.ndarray,
                           mode: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(12, 3))
    if polys:
        for poly in polys:
            q = np.vstack([poly, poly[:1]])
            ax.plot(q[:, 0], q[:, 1], "k-", lw=0.8)
    else:
        for s in segments:
            ax.plot([s[0], s[3]], [s[1], s[4]], "k-", lw=0.4)
    ax.plot(truth[:, 0], truth[:, 1], "b.", ms=5, label="ground truth")
    ax.plot(est[:, 0], est[:, 1], "r.", ms=5, label=f"{mode} estimate")
    for t, s in zip(truth, est):
        ax.plot([t[0], s[0]], [t[1], s[1]], "r-", lw=0.3, alpha=0.5)
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=7)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
