"""Hidden-line removal for 2.5-D models, once per camera position and shared by every heading.

A floor plan's walls are vertical faces standing on the floor, so whether a 3-D point q is
hidden from a camera at p depends only on the faces crossed by the plan ray p -> q and the
height of the line of sight where it crosses them. That ray's direction is q's azimuth,
whatever the camera's heading: the visible parts of every segment can be found once per
grid position and then drawn, without any further test, into the views of all headings
(pinhole views) or into one panorama (panoramas, whose yaw is a circular shift).

Per position a 1-D depth buffer over the azimuth (``N_BINS`` bins, 0.044 degrees each)
holds, for each bin, the nearest face crossings of the ray through the bin centre, sorted
by distance: at most ``MAX_HITS`` of them, and none behind the first face that spans the
model's whole height (a floor-to-ceiling wall hides everything behind it). A point is
hidden when a listed crossing lies more than 5 mm before it (the clearance of
:func:`placeloc.geometry.rays.occluded`) at a height of the line of sight inside the face:
the exact test of :func:`~placeloc.geometry.rays.occluded`, except that

- the ray is the bin centre's, not the point's own (at most 0.022 degrees off: 1 mm at
  3 m; it matters only for walls seen at a grazing angle, within about a millimetre of
  their end);
- crossings after the ``MAX_HITS`` nearest are ignored (only a ray that crosses more than
  that many partial-height faces, e.g. lintels, before a full-height wall could differ).

Segments are sampled every ``SAMPLE_DEG`` of view angle, each visibility change is refined
by bisection to ``REFINE`` halvings, and the visible runs are returned as 3-D pieces.
A segment entirely farther than the full-height walls across its whole azimuth span is
dropped without sampling.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from placeloc.geometry.rays import occluded, ray_segment

N_BINS = 2048
COARSE = 16          # fine bins per coarse bin of the whole-segment rejection test
MAX_HITS = 8
SAMPLE_DEG = 0.5
REFINE = 8
CLEARANCE_M = 0.005
MAX_DT = 0.05       # at least 20 samples per segment, even seen end-on


@njit(cache=True)
def depth_lists(px: float, py: float, faces: np.ndarray, tall: np.ndarray, dirs: np.ndarray, hit_key: np.ndarray,
                hit_f: np.ndarray, n_hits: np.ndarray, far: np.ndarray) -> None:
    """Fill the per-bin candidate lists of the camera at plan point (px, py) (module
    docstring): the faces touching each azimuth bin, nearest first (key: distance along the
    bin's centre ray, or to the face's end inside the bin), none behind a full-height face
    that covers the whole bin. ``far[b]``: the farthest distance of that face within bin b
    (inf when there is none). ``dirs``: :func:`bin_directions`."""
    n_bins = hit_key.shape[0]
    k_max = hit_key.shape[1]
    binw = 2.0 * math.pi / n_bins
    n_hits[:] = 0
    far[:] = math.inf
    for f in range(faces.shape[0]):
        ax = faces[f, 0] - px
        ay = faces[f, 1] - py
        bx = faces[f, 2] - px
        by = faces[f, 3] - py
        ta = math.atan2(ay, ax)
        tb = math.atan2(by, bx)
        d = tb - ta
        if d > math.pi:
            d -= 2.0 * math.pi
        elif d < -math.pi:
            d += 2.0 * math.pi
        fa = (ta + math.pi) / binw
        fb = fa + d / binw
        lo = min(fa, fb)
        hi = max(fa, fb)
        d_lo = math.sqrt(ax * ax + ay * ay) if fa <= fb else math.sqrt(bx * bx + by * by)
        d_hi = math.sqrt(bx * bx + by * by) if fa <= fb else math.sqrt(ax * ax + ay * ay)
        is_tall = tall[f]
        k_lo = int(math.floor(lo))
        k_hi = int(math.floor(hi))
        for k in range(k_lo, k_hi + 1):
            b = k % n_bins
            full = k >= lo and k + 1 <= hi
            if lo <= k + 0.5 <= hi:
                t, u = ray_segment(0.0, 0.0, dirs[2 * b + 1, 0], dirs[2 * b + 1, 1], ax, ay, bx, by)
                key = t if t > 0.0 else 0.0
            else:
                key = d_lo if k == k_lo else d_hi
            n = n_hits[b]
            if n > 0 and key >= hit_key[b, n - 1] and (n == k_max or far[b] < math.inf):
                continue  # behind the full-height face, or behind every kept face of a full list
            dropped_tall = n == k_max and far[b] < math.inf  # the last entry, about to fall off
            j = n if n < k_max else k_max - 1
            while j > 0 and hit_key[b, j - 1] > key:
                hit_key[b, j] = hit_key[b, j - 1]
                hit_f[b, j] = hit_f[b, j - 1]
                j -= 1
            hit_key[b, j] = key
            hit_f[b, j] = f
            n = min(n + 1, k_max)
            if is_tall and full:
                n = j + 1  # nothing behind a full-height face covering the whole bin matters
                t0, _ = ray_segment(0.0, 0.0, dirs[2 * b, 0], dirs[2 * b, 1], ax, ay, bx, by)
                t1, _ = ray_segment(0.0, 0.0, dirs[2 * b + 2, 0], dirs[2 * b + 2, 1], ax, ay, bx, by)
                far[b] = max(t0, t1, key)
            elif dropped_tall:
                far[b] = math.inf
            n_hits[b] = n


@njit(cache=True, inline="always")
def _hidden(px: float, py: float, pz: float, qx: float, qy: float, qz: float, faces: np.ndarray, n_bins: int,
            hit_f: np.ndarray, n_hits: np.ndarray) -> bool:
    """The exact test of :func:`placeloc.geometry.rays.occluded` against the faces listed
    in q's azimuth bin."""
    dx = qx - px
    dy = qy - py
    length = math.sqrt(dx * dx + dy * dy)
    if length < 1e-9:
        return False
    b = int((math.atan2(dy, dx) + math.pi) * (n_bins / (2.0 * math.pi)))
    if b >= n_bins:
        b = n_bins - 1
    return occluded(px, py, pz, qx, qy, qz, faces, hit_f[b], n_hits[b])


@njit(cache=True)
def visible_pieces_at(px: float, py: float, pz: float, segs: np.ndarray, faces: np.ndarray, tall: np.ndarray,
                      dirs: np.ndarray, hit_key: np.ndarray, hit_f: np.ndarray, n_hits: np.ndarray, far: np.ndarray,
                      coarse_far: np.ndarray, pieces: np.ndarray) -> int:
    """Write the visible pieces of ``segs`` seen from (px, py, pz) into ``pieces`` (rows x0 y0
    z0 x1 y1 z1, world) and return their number (at most ``len(pieces)``)."""
    nb = hit_key.shape[0]
    depth_lists(px, py, faces, tall, dirs, hit_key, hit_f, n_hits, far)
    ncb = coarse_far.shape[0]
    per = nb // ncb
    for c in range(ncb):
        m = 0.0
        for b in range(c * per, (c + 1) * per):
            if far[b] > m:
                m = far[b]
        coarse_far[c] = m
    step = math.radians(SAMPLE_DEG)
    cbinw = 2.0 * math.pi / ncb
    npieces = 0
    for s in range(segs.shape[0]):
        ax = segs[s, 0] - px
        ay = segs[s, 1] - py
        az = segs[s, 2] - pz
        ex = segs[s, 3] - segs[s, 0]
        ey = segs[s, 4] - segs[s, 1]
        ez = segs[s, 5] - segs[s, 2]
        ll = math.sqrt(ex * ex + ey * ey + ez * ez)
        if ll < 1e-12:
            continue
        # whole-segment rejection: nearer plan point farther than every full-height wall of its span
        e2 = ex * ex + ey * ey
        t0 = 0.0 if e2 < 1e-18 else min(max(-(ax * ex + ay * ey) / e2, 0.0), 1.0)
        rmin = math.sqrt((ax + t0 * ex) ** 2 + (ay + t0 * ey) ** 2)
        ta = math.atan2(ay, ax)
        tb = math.atan2(ay + ey, ax + ex)
        d = tb - ta
        if d > math.pi:
            d -= 2.0 * math.pi
        elif d < -math.pi:
            d += 2.0 * math.pi
        ca = (ta + math.pi) / cbinw
        cb = ca + d / cbinw
        worst = 0.0
        for k in range(int(math.floor(min(ca, cb))), int(math.floor(max(ca, cb))) + 1):
            v = coarse_far[k % ncb]
            if v > worst:
                worst = v
        if rmin - CLEARANCE_M > worst:
            continue
        if e2 < 1e-18:
            # vertical (corners, door jambs): one plan ray for the whole segment, solved exactly
            npieces = _vertical_pieces(px, py, pz, segs, s, faces, nb, hit_f, n_hits, pieces, npieces)
            continue
        # samples every `step` of view angle
        t = 0.0
        prev_vis = not _hidden(px, py, pz, segs[s, 0], segs[s, 1], segs[s, 2], faces, nb, hit_f, n_hits)
        start = 0.0 if prev_vis else -1.0
        while t < 1.0:
            qx = ax + t * ex
            qy = ay + t * ey
            qz = az + t * ez
            # the view direction turns at |q x e| / |q|^2 per unit t
            cx_ = qy * ez - qz * ey
            cy_ = qz * ex - qx * ez
            cz_ = qx * ey - qy * ex
            rate = math.sqrt(cx_ * cx_ + cy_ * cy_ + cz_ * cz_) / max(qx * qx + qy * qy + qz * qz, 1e-6)
            t_next = min(1.0, t + min(MAX_DT, max(step / max(rate, 1e-9), 1e-6)))
            vis = not _hidden(px, py, pz, px + ax + t_next * ex, py + ay + t_next * ey, pz + az + t_next * ez,
                              faces, nb, hit_f, n_hits)
            if vis != prev_vis:
                # bisect the change between t and t_next
                lo = t
                hi = t_next
                for _ in range(REFINE):
                    mid = 0.5 * (lo + hi)
                    vm = not _hidden(px, py, pz, px + ax + mid * ex, py + ay + mid * ey, pz + az + mid * ez,
                                     faces, nb, hit_f, n_hits)
                    if vm == prev_vis:
                        lo = mid
                    else:
                        hi = mid
                edge = 0.5 * (lo + hi)
                if vis:
                    start = edge
                elif npieces < pieces.shape[0] and edge > start:
                    _put(pieces, npieces, segs, s, start, edge)
                    npieces += 1
                prev_vis = vis
            t = t_next
        if prev_vis and npieces < pieces.shape[0] and start < 1.0:
            _put(pieces, npieces, segs, s, start, 1.0)
            npieces += 1
    return npieces


@njit(cache=True)
def _vertical_pieces(px: float, py: float, pz: float, segs: np.ndarray, s: int, faces: np.ndarray, n_bins: int,
                     hit_f: np.ndarray, n_hits: np.ndarray, pieces: np.ndarray, npieces: int) -> int:
    """Visible pieces of the vertical segment ``s``: every point of it shares one plan ray,
    so each listed face that ray crosses hides one interval of heights (the test of
    :func:`_hidden`, solved for the height instead of sampled)."""
    qx = segs[s, 0]
    qy = segs[s, 1]
    za = segs[s, 2]
    zb = segs[s, 5]
    dx = qx - px
    dy = qy - py
    length = math.sqrt(dx * dx + dy * dy)
    lo_z = min(za, zb)
    hi_z = max(za, zb)
    if length < 1e-9:
        if npieces < pieces.shape[0]:
            _put(pieces, npieces, segs, s, 0.0, 1.0)
            npieces += 1
        return npieces
    b = int((math.atan2(dy, dx) + math.pi) * (n_bins / (2.0 * math.pi)))
    if b >= n_bins:
        b = n_bins - 1
    tmax = 1.0 - CLEARANCE_M / length
    n = 0
    cut_lo = np.empty(n_hits[b])
    cut_hi = np.empty(n_hits[b])
    for i in range(n_hits[b]):
        f = hit_f[b, i]
        t, u = ray_segment(px, py, dx, dy, faces[f, 0], faces[f, 1], faces[f, 2], faces[f, 3])
        if t <= 1e-9 or t >= tmax or u < 0.0 or u > 1.0:
            continue
        # z(t) = pz + t (qz - pz) within [z0, z1]  <=>  qz within [pz + (z0 - pz) / t, pz + (z1 - pz) / t]
        cut_lo[n] = pz + (faces[f, 4] - pz) / t
        cut_hi[n] = pz + (faces[f, 5] - pz) / t
        n += 1
    order = np.argsort(cut_lo[:n])
    z = lo_z  # lowest height not yet decided
    for k in range(n):
        c0 = cut_lo[order[k]]
        c1 = cut_hi[order[k]]
        if c1 < z:
            continue
        if c0 > z and npieces < pieces.shape[0]:
            top = min(c0, hi_z)
            if top > z:
                _put_z(pieces, npieces, qx, qy, z, top)
                npieces += 1
        z = max(z, c1)
        if z >= hi_z:
            break
    if z < hi_z and npieces < pieces.shape[0]:
        _put_z(pieces, npieces, qx, qy, z, hi_z)
        npieces += 1
    return npieces


@njit(cache=True, inline="always")
def _put_z(pieces: np.ndarray, i: int, x: float, y: float, z0: float, z1: float) -> None:
    pieces[i, 0] = x
    pieces[i, 1] = y
    pieces[i, 2] = z0
    pieces[i, 3] = x
    pieces[i, 4] = y
    pieces[i, 5] = z1


@njit(cache=True, inline="always")
def _put(pieces: np.ndarray, i: int, segs: np.ndarray, s: int, t0: float, t1: float) -> None:
    for a in range(3):
        pieces[i, a] = segs[s, a] + t0 * (segs[s, 3 + a] - segs[s, a])
        pieces[i, 3 + a] = segs[s, a] + t1 * (segs[s, 3 + a] - segs[s, a])


def tall_faces(segments: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """True for faces that span the model's whole height (floor to the highest point): such
    a face hides everything behind it."""
    faces = np.asarray(faces, float).reshape(-1, 6)
    segments = np.asarray(segments, float).reshape(-1, 6)
    zs = np.concatenate([segments[:, [2, 5]].ravel(), faces[:, 4:6].ravel()])
    if zs.size == 0:
        return np.zeros(0, dtype=np.bool_)
    return (faces[:, 4] <= zs.min() + 1e-6) & (faces[:, 5] >= zs.max() - 1e-6)


def bin_directions(n_bins: int = N_BINS) -> np.ndarray:
    """(2 n_bins + 1, 2) unit plan directions at every half bin: row 2 b is bin b's lower
    edge (azimuth -pi + b 2 pi / n_bins), row 2 b + 1 its centre."""
    th = -math.pi + np.arange(2 * n_bins + 1) * math.pi / n_bins
    return np.ascontiguousarray(np.stack([np.cos(th), np.sin(th)], axis=1))


def max_pieces(n_segments: int) -> int:
    """Room for the visible pieces of one position (a segment seen through several gaps
    splits into several pieces)."""
    return 8 * n_segments + 64


def visible_pieces(segments: np.ndarray, faces: np.ndarray, position: np.ndarray) -> np.ndarray:
    """The visible pieces (N, 6) of ``segments`` from the 3-D ``position`` (module docstring)."""
    segs = np.ascontiguousarray(segments, np.float64).reshape(-1, 6)
    fc = np.ascontiguousarray(faces, np.float64).reshape(-1, 6)
    key = np.zeros((N_BINS, MAX_HITS))
    hf = np.zeros((N_BINS, MAX_HITS), np.int64)
    nh = np.zeros(N_BINS, np.int64)
    far = np.zeros(N_BINS)
    pieces = np.zeros((max_pieces(len(segs)), 6))
    n = visible_pieces_at(float(position[0]), float(position[1]), float(position[2]), segs, fc, tall_faces(segs, fc),
                          bin_directions(),
                          key, hf, nh, far, np.zeros(N_BINS // COARSE), pieces)
    return pieces[:n].copy()
