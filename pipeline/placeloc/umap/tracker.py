"""Consistency Adjustment trackers: chain single-image UMap estimates along a sequence,
each frame's search limited around where the CA step (sec. 4 of the paper) puts it.

- :func:`ca_steps` turns matched AKAZE features of consecutive frames and the laser rows
  into per-frame CA measurements (signed steps for the robust tracker, moved distances for
  the paper's).
- :func:`ca_chain` is the paper's tracker: search radius = CA distance + mean + std of the
  CA error around the previous estimate.
- :func:`ca_track` is the robust tracker (see its docstring).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from placeloc.geometry.rays import ray_ranges
from placeloc.umap import ca as ca_mod
from placeloc.umap.scoring import Scorer


@dataclass
class CASteps:
    """Per-frame CA measurements; entry k is about the move from frame k-1 to k (entry 0 unused)."""

    distance: np.ndarray   # moved distance (|step| for the robust tracker), nan when CA failed
    step: np.ndarray       # signed step along the wall (robust tracker), nan otherwise
    reliable: np.ndarray   # the vote's winner was large and clearly ahead (robust tracker)
    alt: np.ndarray        # the vote's runner-up step: a second motion hypothesis
    matches: np.ndarray    # matches kept by the vote
    theta: np.ndarray      # camera angle to the wall at frame k-1 (from the sensor)


def ca_steps(pts: np.ndarray, desc: np.ndarray, offsets: np.ndarray, d: np.ndarray, theta: np.ndarray, *,
             focal: float, width: int, hfov_deg: float, tracker: str, formula: str, phi_deg: float, wall_right: bool,
             vote_tol_m: float, vote_rel_tol: float, reliable_matches: int, reliable_ratio: float, bin_px: float,
             min_matches: int) -> CASteps:
    """CA measurements between consecutive frames. ``pts``/``desc`` hold every frame's
    keypoints, frame k's at ``offsets[k]:offsets[k + 1]``; ``d``/``theta`` the sensor rows.
    ``phi_deg`` <= 0 uses :func:`placeloc.umap.ca.effective_phi` of ``hfov_deg``."""
    n = len(offsets) - 1
    out = CASteps(np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, dtype=bool), np.full(n, np.nan),
                  np.zeros(n, dtype=np.int64), np.zeros(n))
    phi = phi_deg if phi_deg > 0 else ca_mod.effective_phi(hfov_deg)
    cx = (width - 1) / 2.0
    for k in range(1, n):
        a, b = slice(offsets[k - 1], offsets[k]), slice(offsets[k], offsets[k + 1])
        dk, out.theta[k] = d[k - 1], theta[k - 1]
        if tracker == "robust":
            out.step[k], out.matches[k], second, out.alt[k] = ca_mod.signed_step(
                pts[a], desc[a], pts[b], desc[b], dk, out.theta[k], focal, cx, wall_right, vote_tol_m, vote_rel_tol)
            out.reliable[k] = ca_mod.is_reliable(int(out.matches[k]), second, reliable_matches=reliable_matches,
                                                 reliable_ratio=reliable_ratio)
            out.distance[k] = abs(out.step[k])
            continue
        shift = ca_mod.centroid_shift(pts[a], desc[a], pts[b], desc[b], bin_px, min_matches)
        if shift is None:
            continue
        out.matches[k] = shift[3]
        if formula == "paper":
            out.distance[k] = ca_mod.moved_distance_paper(shift[0], dk, out.theta[k], phi, width)
        else:
            out.distance[k] = ca_mod.moved_distance_exact(shift[1], shift[2], dk, out.theta[k], focal, cx, wall_right)
    return out


def ca_chain(anchor: int, umap_best: np.ndarray, umap_score: np.ndarray, ca_dist: np.ndarray, poses: np.ndarray,
             lines: np.ndarray, scorer: Scorer, *, error_mean_m: float, error_std_m: float, fallback_radius_m: float,
             keep_heading: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The paper's UMap+CA from one anchor frame: chain forward and backward, each search
    limited to (CA moved distance + mean + std of the CA error) around the previous estimate."""
    n = len(umap_best)
    best, score = umap_best.copy(), umap_score.copy()
    radius = np.full(n, np.nan)
    order = [(k, k - 1, k) for k in range(anchor + 1, n)] + [(k, k + 1, k + 1) for k in range(anchor - 1, -1, -1)]
    for k, prev, step in order:
        m = ca_dist[step]
        r = (m + error_mean_m + error_std_m) if np.isfinite(m) else fallback_radius_m
        dist = np.hypot(poses[:, 0] - poses[best[prev], 0], poses[:, 1] - poses[best[prev], 1])
        near = dist <= r
        if keep_heading:
            # CA matched features between the frames, so the views overlap: on a database
            # whose headings are 90 deg apart only the previous heading is consistent.
            near &= np.isclose(poses[:, 3], poses[best[prev], 3])
        rows = np.flatnonzero(near)
        if rows.size == 0:  # radius below the grid step: take the nearest grid positions
            rows = np.flatnonzero(dist <= dist.min() + 1e-9)
        radius[k] = r
        best[k], score[k] = scorer.best(lines[k], rows)
    return best, score, radius


def ca_track(anchor: int, umap_best: np.ndarray, umap_score: np.ndarray, step: np.ndarray, reliable: np.ndarray,
             theta: np.ndarray, poses: np.ndarray, lines: np.ndarray, scorer: Scorer, *, error_mean_m: float,
             error_std_m: float, fallback_radius_m: float, fallback_step_m: float | None, wall_right: bool,
             keep_heading: bool, tie_tol: float, recover_ratio: float, laser_tol_m: float, alt: np.ndarray | None = None,
             laser: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust UMap+CA from one anchor frame, forward then backward.

    ``step[k]``: signed CA step along the wall from frame k-1 to k (nan if none), ``reliable[k]``
    whether its vote group had enough matches, ``theta[k]`` the camera angle to the wall at
    frame k-1. Each frame's search is centred on the position CA predicts (previous estimate +
    step along the wall), within ``|error_mean| + 2 error_std`` (+0.1 m grid quantisation).
    An unreliable or missing CA step falls back to the sequence's median reliable step with
    ``fallback_radius_m`` (or ``fallback_step_m`` in its direction when calibrated: CA fails
    mostly on large steps, so the median reliable step underestimates them). If the best score
    inside the gate is ``recover_ratio`` times below the best within ``fallback_radius_m`` of
    the previous estimate, the CA step is taken to be wrong and the wider search wins
    (re-localization). ``alt[k]`` (optional) is the vote's runner-up step, a second motion
    hypothesis tried before the wide search under the same ratio: a wrong winning group often
    has the true motion as runner-up. ``laser`` (optional) = (d per frame, theta per frame, wall
    faces): candidate poses whose plan ray cast towards the wall differs from the measured
    laser distance by more than ``laser_tol_m`` are dropped (the laser CA already relies on
    fixes the distance across the wall, which the line images of a corridor barely
    constrain). Returns (best rows, scores, radii)."""
    n = len(umap_best)
    best, score = umap_best.copy(), umap_score.copy()
    radius = np.full(n, np.nan)
    xy = poses[:, :2]
    gate = abs(error_mean_m) + 2.0 * error_std_m + 0.1
    ok = reliable & np.isfinite(step)
    typical = float(np.median(step[ok])) if ok.any() else 0.0
    if fallback_step_m is not None:  # calibrated size of the steps CA fails on (large ones), same direction
        typical = math.copysign(float(fallback_step_m), typical)
    order = [(k, k - 1, k, 1.0) for k in range(anchor + 1, n)] + [(k, k + 1, k + 1, -1.0) for k in range(anchor - 1, -1, -1)]
    for k, prev, st, sgn in order:
        pp = poses[best[prev]]
        t = ca_mod.wall_tangent(float(pp[3]), float(theta[st]), wall_right)
        if ok[st]:
            pred, r = pp[:2] + sgn * step[st] * t, gate
        else:
            pred, r = pp[:2] + sgn * typical * t, fallback_radius_m
        heading_ok = np.isclose(poses[:, 3], pp[3]) if keep_heading else np.ones(len(poses), bool)
        if laser is not None:
            th_k = laser[1][k]  # frame k's laser points at heading -/+ theta
            near_prev = heading_ok & (np.hypot(*(xy - pp[:2]).T) <= fallback_radius_m + 2 * abs(typical) + gate)
            cand = np.flatnonzero(near_prev)
            ang = poses[cand, 3] - th_k if wall_right else poses[cand, 3] + th_k
            rng_ = np.full(len(cand), np.inf)
            for a_ in np.unique(ang):
                on = ang == a_
                rng_[on] = ray_ranges(xy[cand[on]], float(a_), laser[2])
            fits = np.abs(rng_ - laser[0][k]) <= laser_tol_m
            if fits.any():
                heading_ok = np.zeros(len(poses), bool)
                heading_ok[cand[fits]] = True
        dist = np.hypot(*(xy - pred).T)
        rows = np.flatnonzero((dist <= r) & heading_ok)
        if rows.size == 0:  # gate below the grid step: the nearest grid positions
            rows = np.flatnonzero(heading_ok & (dist <= dist[heading_ok].min() + 1e-9))
        i, s = scorer.pick(lines[k], rows, pred, tie_tol=tie_tol)
        if alt is not None and np.isfinite(alt[st]):
            pred2 = pp[:2] + sgn * alt[st] * t
            rows2 = np.flatnonzero((np.hypot(*(xy - pred2).T) <= gate) & heading_ok)
            if rows2.size:
                j, s2 = scorer.pick(lines[k], rows2, pred2, tie_tol=tie_tol)
                if s2 > s * recover_ratio:
                    i, s, r, pred = j, s2, gate, pred2
        if r < fallback_radius_m:
            wide = np.flatnonzero((np.hypot(*(xy - pp[:2]).T) <= fallback_radius_m) & heading_ok)
            if wide.size:
                j, sw = scorer.pick(lines[k], wide, pred, tie_tol=tie_tol)
                if sw > s * recover_ratio:
                    i, s, r = j, sw, fallback_radius_m
        best[k], score[k], radius[k] = i, s, r
    return best, score, radius
