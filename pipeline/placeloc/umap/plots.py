"""UMap's pictures: cumulative error and the estimates drawn on the floor plan."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_error_cdf(path: Path, err: np.ndarray, mode: str) -> None:
    """Share of frames within each error, on a log axis with plain-number ticks, the 0.5 m
    and 1 m marks labelled with their shares."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullLocator

    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    e = np.sort(np.maximum(np.asarray(err, float), 0.01))
    ax.step(e, np.arange(1, len(e) + 1) / len(e), where="post", lw=2, color="tab:blue")
    ax.set_xscale("log")
    lo, hi = 0.01, max(2.0, float(e.max()) * 1.5)
    ax.set_xlim(lo, hi)
    ticks = [t for t in (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100) if lo <= t <= hi]
    ax.xaxis.set_major_locator(FixedLocator(ticks))
    ax.xaxis.set_minor_locator(NullLocator())
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.set_ylim(0, 1.02)
    for mark, colour in ((0.5, "tab:green"), (1.0, "tab:orange")):
        share = float(np.mean(np.asarray(err) <= mark))
        ax.axvline(mark, color=colour, ls="--", lw=1.2)
        ax.text(mark * 1.05, 0.05 if mark < 1 else 0.15, f"{share:.0%} within {mark:g} m", color=colour, fontsize=9)
    ax.set_xlabel("position error [m] (log scale)")
    ax.set_ylabel("share of frames")
    ax.set_title(f"Cumulative position error, {mode} ({len(e)} frames)")
    ax.grid(True, which="major", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_estimates_on_plan(path: Path, truth: np.ndarray, est: np.ndarray, polys: list[np.ndarray], segments: np.ndarray,
                           mode: str, truth_heading_deg: np.ndarray | None = None,
                           est_heading_deg: np.ndarray | None = None) -> None:
    """The plan (room polygons, or the wireframe's floor lines), true and estimated
    positions joined by error lines, headings as short arrows."""
    plt = _plt()
    pts = np.vstack([truth, est] + [p for p in polys]) if polys else np.vstack([truth, est, segments[:, [0, 1]]])
    span = np.ptp(pts, axis=0) + 1.0
    width = 11.0
    height = float(np.clip(width * span[1] / span[0], 2.5, 9.0)) + 0.8
    fig, ax = plt.subplots(figsize=(width, height))
    if polys:
        for poly in polys:
            q = np.vstack([poly, poly[:1]])
            ax.plot(q[:, 0], q[:, 1], "k-", lw=0.9)
    else:
        for s in segments:
            ax.plot([s[0], s[3]], [s[1], s[4]], "k-", lw=0.4)
    err = np.hypot(*(est - truth).T)
    for t, s in zip(truth, est):
        ax.plot([t[0], s[0]], [t[1], s[1]], "-", color="0.5", lw=0.8)
    ax.plot(truth[:, 0], truth[:, 1], "o", color="tab:blue", ms=5, label="true position")
    ax.plot(est[:, 0], est[:, 1], "x", color="tab:red", ms=6, mew=1.5, label=f"{mode} estimate")
    arrow = 0.04 * float(max(span))
    for xy, hd, colour in ((truth, truth_heading_deg, "tab:blue"), (est, est_heading_deg, "tab:red")):
        if hd is None:
            continue
        r = np.radians(np.asarray(hd, float))
        ax.quiver(xy[:, 0], xy[:, 1], arrow * np.cos(r), arrow * np.sin(r), color=colour, angles="xy", scale_units="xy",
                  scale=1.0, width=0.003)
    ax.set_aspect("equal")
    ax.legend(loc="best", fontsize=8, framealpha=0.9)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{mode}: {int(np.sum(err <= 1.0))} of {len(err)} frames within 1 m (median error {np.median(err):.2f} m); "
                 "grey lines join truth and estimate" + ("; arrows: heading" if est_heading_deg is not None else ""),
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_panorama_overlay(path: Path, query: np.ndarray, at_estimate: np.ndarray, at_truth: np.ndarray | None,
                          title: str) -> None:
    """One panorama's detected lines (grey) with the map's lines rendered at the estimated
    pose (red) and at the true pose (green): where they differ shows why a query failed."""
    plt = _plt()
    h, w = query.shape
    img = np.ones((h, w, 3))
    img[query > 0] = (0.55, 0.55, 0.55)
    if at_truth is not None:
        img[at_truth > 0] = (0.1, 0.65, 0.1)
    img[at_estimate > 0] = (0.85, 0.1, 0.1)
    if at_truth is not None:
        img[(at_truth > 0) & (at_estimate > 0)] = (0.55, 0.35, 0.0)
    fig, ax = plt.subplots(figsize=(10, 5.6))
    ax.imshow(img, interpolation="nearest", extent=(180, -180, -90, 90), aspect="auto")
    ax.set_xlabel("azimuth relative to the panorama's centre column [deg] (left is counter-clockwise)")
    ax.set_ylabel("elevation [deg]")
    ax.set_title(title + "\ngrey: detected lines; red: map at the estimate; green: map at the truth; brown: both", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
