"""Panoramas as whole queries: equirectangular line images of the map at every grid
position, the query panorama's line image, and scores over every yaw at once.

A 360 degree query with unknown heading is compared whole with the map's panoramic line
image at each grid position, the heading searched as a circular shift of columns (one
column = 360 / width degrees), instead of cutting pinhole views and keeping the best single
one (blank-wall views match sparse views anywhere).

Equirectangular convention (that of :func:`placeloc.geometry.equirect_to_pinhole`): column
u shows azimuth ``pi - 2 pi (u + 0.5) / W`` relative to the heading (centre column = the
heading, azimuth growing to the left), row v elevation ``pi / 2 - pi (v + 0.5) / H``. The
database is rendered at heading 0; a query taken at heading ``psi`` is that image rolled by
``k = psi W / 360`` columns (``query[:, u] = db[:, u - k]``).

Two scores, both over all (position, shift) pairs:

- ``iou``: eq. (1) of the UMap paper (intersection over union of line pixels, the database
  dilated by the tolerance), as for pinhole queries;
- ``chamfer``: a truncated distance-transform score that lets unseen map lines and clutter
  cost little: the mean of ``max(0, 1 - d / tau)`` over the map's line pixels (d = distance
  to the nearest query line pixel: how much of the map is seen) and over the query's line
  pixels (d = distance to the nearest map line: how much of what is seen is map), averaged.
  Optionally split by direction: vertical map lines (wall corners, door jambs) only count
  against vertical query lines and the rest against the rest.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numba import njit, prange
from placeloc.geometry import Camera, equirect_to_pinhole
from placeloc.geometry.rays import ray_segment
from placeloc.umap.bits import _popcount64, n_words, pack

# ------------------------------------------------------------------ rendering the map

@njit(cache=True)
def _angle_to_col(az: float, width: int) -> float:
    return ((math.pi - az) / (2.0 * math.pi) % 1.0) * width - 0.5


@njit(cache=True)
def _hidden(px: float, py: float, pz: float, qx: float, qy: float, qz: float, faces: np.ndarray, cand: np.ndarray,
            ncand: int) -> bool:
    """The hidden-line test of :mod:`placeloc.umap.render` against candidate faces only."""
    dx = qx - px
    dy = qy - py
    length = math.sqrt(dx * dx + dy * dy)
    if length < 1e-9:
        return False
    tmax = 1.0 - 0.005 / length  # the point's own wall (and walls meeting at it): 5 mm clear
    for k in range(ncand):
        f = cand[k]
        t, u = ray_segment(px, py, dx, dy, faces[f, 0], faces[f, 1], faces[f, 2], faces[f, 3])
        if t <= 1e-9 or t >= tmax or u < 0.0 or u > 1.0:
            continue
        z = pz + t * (qz - pz)
        if faces[f, 4] <= z <= faces[f, 5]:
            return True
    return False


@njit(parallel=True, cache=True)
def _render_equirect(segs: np.ndarray, vertical: np.ndarray, faces: np.ndarray, poses: np.ndarray, width: int, height: int,
                     hidden: bool, which: int, out: np.ndarray) -> None:
    """``which``: 0 every segment, 1 only vertical ones, 2 only the others."""
    nf = faces.shape[0]
    step = 2.0 * math.pi / width
    for v in prange(poses.shape[0]):
        px = poses[v, 0]
        py = poses[v, 1]
        pz = poses[v, 2]
        head = math.radians(poses[v, 3])
        img = np.zeros(height * width, dtype=np.uint8)
        # faces per column: a face can only hide points whose azimuth lies in its angular span
        counts = np.zeros(width, dtype=np.int64)
        lists = np.empty((width, max(nf, 1)), dtype=np.int64)
        if hidden:
            for f in range(nf):
                a0 = math.atan2(faces[f, 1] - py, faces[f, 0] - px) - head
                a1 = math.atan2(faces[f, 3] - py, faces[f, 2] - px) - head
                c0 = _angle_to_col(a0, width)
                c1 = _angle_to_col(a1, width)
                lo = min(c0, c1)
                hi = max(c0, c1)
                if hi - lo > width / 2.0:  # the span wraps around the seam
                    lo, hi = hi, lo + width
                for c in range(int(math.floor(lo)) - 1, int(math.ceil(hi)) + 2):
                    cc = c % width
                    lists[cc, counts[cc]] = f
                    counts[cc] += 1
        for s in range(segs.shape[0]):
            if which == 1 and not vertical[s]:
                continue
            if which == 2 and vertical[s]:
                continue
            ax = segs[s, 0] - px
            ay = segs[s, 1] - py
            az = segs[s, 2] - pz
            ex = segs[s, 3] - segs[s, 0]
            ey = segs[s, 4] - segs[s, 1]
            ez = segs[s, 5] - segs[s, 2]
            ll = math.sqrt(ex * ex + ey * ey + ez * ez)
            if ll < 1e-9:
                continue
            # closest distance camera -> segment bounds the angular speed along it
            t0 = -(ax * ex + ay * ey + az * ez) / (ll * ll)
            t0 = min(max(t0, 0.0), 1.0)
            cxp = ax + t0 * ex
            cyp = ay + t0 * ey
            czp = az + t0 * ez
            dmin = max(math.sqrt(cxp * cxp + cyp * cyp + czp * czp), 0.05)
            n = min(int(math.ceil(2.0 * ll / dmin / step)) + 1, 20000)
            for i in range(n + 1):
                t = i / n
                qx = ax + t * ex
                qy = ay + t * ey
                qz = az + t * ez
                r = math.sqrt(qx * qx + qy * qy)
                azm = math.atan2(qy, qx) - head
                el = math.atan2(qz, r)
                fu = _angle_to_col(azm, width)
                iu = int(math.floor(fu + 0.5)) % width
                iv = int(math.floor((math.pi / 2.0 - el) / math.pi * height - 0.5 + 0.5))
                iv = min(max(iv, 0), height - 1)
                pix = iv * width + iu
                if img[pix]:
                    continue
                if hidden and counts[iu] > 0:
                    if _hidden(px, py, pz, px + qx, py + qy, pz + qz, faces, lists[iu], counts[iu]):
                        continue
                img[pix] = 1
        for w in range(out.shape[1]):
            word = np.uint64(0)
            base = w * 64
            for b in range(64):
                p = base + b
                if p < height * width and img[p]:
                    word |= np.uint64(1) << np.uint64(b)
            out[v, w] = word


def vertical_segments(segments: np.ndarray) -> np.ndarray:
    """True for segments within 10 degrees of vertical (wall corners, door jambs)."""
    d = np.asarray(segments, float).reshape(-1, 6)
    d = d[:, 3:6] - d[:, 0:3]
    return np.abs(d[:, 2]) >= np.cos(np.radians(10.0)) * np.maximum(np.linalg.norm(d, axis=1), 1e-12)


def render_panoramas(segments: np.ndarray, faces: np.ndarray, poses: np.ndarray, *, width: int, height: int,
                     hidden: bool, which: str = "all") -> np.ndarray:
    """Equirectangular line images of ``segments`` from each pose (x, y, z, heading): packed
    (V, n_words) uint64 (layout of :mod:`placeloc.umap.bits`). ``which``: ``all``, or only
    the ``vertical`` or ``other`` segments (for the direction-split score)."""
    poses = np.ascontiguousarray(poses, dtype=np.float64).reshape(-1, 4)
    segs = np.ascontiguousarray(segments, np.float64).reshape(-1, 6)
    out = np.zeros((len(poses), n_words(height, width)), dtype=np.uint64)
    if len(poses):
        _render_equirect(segs, vertical_segments(segs), np.ascontiguousarray(faces, np.float64).reshape(-1, 6), poses,
                         int(width), int(height), bool(hidden), {"all": 0, "vertical": 1, "other": 2}[which], out)
    return out


def render_panorama_block(item: tuple) -> np.ndarray:
    """Executor work item: (segments, faces, poses, width, height, hidden, which) -> packed block."""
    segments, faces, poses, width, height, hidden, which = item
    return render_panoramas(segments, faces, poses, width=width, height=height, hidden=hidden, which=which)


# ------------------------------------------------------------------ the query's line image

def _face_rays(u: np.ndarray, v: np.ndarray, cam: Camera, heading_deg: float, pitch_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """World azimuth and elevation of face pixels (the inverse of equirect_to_pinhole's sampling)."""
    X = (u - cam.cx) / cam.focal
    Y = (v - cam.cy) / cam.focal
    p = math.radians(pitch_deg)
    fz = np.cos(p) + Y * np.sin(p)
    up = np.sin(p) - Y * np.cos(p)
    return math.radians(heading_deg) - np.arctan2(X, fz), np.arctan2(up, np.hypot(X, fz))


# the six faces of a cube around the camera: four around, one up, one down
CUBE_FACES = ((0.0, 0.0), (90.0, 0.0), (180.0, 0.0), (270.0, 0.0), (0.0, 90.0), (0.0, -90.0))


def panorama_lines(pano: np.ndarray, *, face_px: int, min_length: float) -> list[np.ndarray]:
    """LSD segments of a grey equirectangular panorama, found on its six cube faces (where
    world lines are straight) and returned per face as (N, 4) pixel rows of a ``face_px``
    square 90 degree view; segments shorter than ``min_length`` face pixels are dropped."""
    from placeloc.umap.lines import detect_segments

    cam = Camera(face_px, face_px, 90.0)
    out = []
    for hd, pitch in CUBE_FACES:
        segs = detect_segments(equirect_to_pinhole(pano, hd, cam, pitch))
        out.append(segs[np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]) >= min_length])
    return out


def panorama_line_image(pano: np.ndarray, *, width: int, height: int, face_px: int, min_length: float,
                        split: bool = False) -> np.ndarray:
    """Binary equirectangular line image (``height`` x ``width``) of a grey panorama's LSD
    lines (see :func:`panorama_lines`). ``split``: a (2, H, W) pair instead, the lines that
    are vertical in the world (vertical on an upright face, through the nadir/zenith on the
    floor/ceiling faces) and the rest."""
    cam = Camera(face_px, face_px, 90.0)
    img = np.zeros((2 if split else 1, height, width), np.uint8)
    for (hd, pitch), segs in zip(CUBE_FACES, panorama_lines(pano, face_px=face_px, min_length=min_length)):
        for x0, y0, x1, y1 in segs:
            n = int(math.ceil(2.0 * math.hypot(x1 - x0, y1 - y0))) + 1
            t = np.linspace(0.0, 1.0, n)
            az, el = _face_rays(x0 + t * (x1 - x0), y0 + t * (y1 - y0), cam, hd, pitch)
            u = np.floor(((math.pi - az) / (2 * math.pi) % 1.0) * width).astype(np.int64) % width
            v = np.clip(np.floor((math.pi / 2 - el) / math.pi * height).astype(np.int64), 0, height - 1)
            ch = 0
            if split:
                if pitch == 0.0:  # upright face: vertical world lines are vertical in the image
                    vert = abs(x1 - x0) <= math.tan(math.radians(10.0)) * abs(y1 - y0)
                else:  # up/down face: vertical world lines run through the image centre
                    c = (face_px - 1) / 2.0
                    dx, dy = x1 - x0, y1 - y0
                    dist = abs(dx * (c - y0) - dy * (c - x0)) / max(math.hypot(dx, dy), 1e-9)
                    vert = dist <= 0.05 * face_px
                ch = 0 if vert else 1
            img[ch, v, u] = 1
    return img if split else img[0]


# ------------------------------------------------------------------ scores over every yaw

@njit(parallel=True, cache=True)
def _and_count_shifts(db: np.ndarray, q: np.ndarray, out: np.ndarray) -> None:
    for i in prange(db.shape[0]):
        for k in range(q.shape[0]):
            s = np.uint64(0)
            for j in range(q.shape[1]):
                s += _popcount64(db[i, j] & q[k, j])
            out[i, k] = s


def rolled_queries(query: np.ndarray) -> np.ndarray:
    """Packed copies of a (H, W) line image rolled by -k columns, k = 0..W-1: row k is the
    query seen as if taken at heading 0 when it was taken at heading k 360 / W."""
    w = query.shape[1]
    return pack(np.stack([np.roll(query, -k, axis=1) for k in range(w)]))


def iou_yaw_scores(db: np.ndarray, db_counts: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Eq. (1) (intersection over union) of every database panorama with the query at every
    column shift: (P, W) float64, entry (p, k) for the query taken at heading k 360 / W."""
    q = rolled_queries(query)
    lc = np.zeros((db.shape[0], q.shape[0]), dtype=np.int64)
    if db.shape[0]:
        _and_count_shifts(np.ascontiguousarray(db), q, lc)
    lc = lc.astype(np.float64)
    union = np.asarray(db_counts, np.float64)[:, None] + float(np.count_nonzero(query)) - lc
    return np.divide(lc, union, out=np.zeros_like(lc), where=union > 0)


def closeness(lines: np.ndarray, tau_px: float) -> np.ndarray:
    """``max(0, 1 - d / tau)`` with d the distance (pixels) to the nearest line pixel of a
    (..., H, W) binary image, wrapping around horizontally (a panorama has no left edge)."""
    lines = np.asarray(lines)
    lead = lines.shape[:-2]
    h, w = lines.shape[-2:]
    flat = lines.reshape(-1, h, w)
    pad = int(math.ceil(tau_px)) + 1
    out = np.zeros(flat.shape, np.float32)
    for i, img in enumerate(flat):
        wrapped = np.concatenate([img[:, -pad:], img, img[:, :pad]], axis=1)
        if not wrapped.any():
            continue
        d = cv2.distanceTransform((wrapped == 0).astype(np.uint8), cv2.DIST_L2, 5)[:, pad:pad + w]
        out[i] = np.maximum(0.0, 1.0 - d / tau_px)
    return out.reshape(*lead, h, w)


@njit(parallel=True, cache=True)
def _chamfer_shifts(db: np.ndarray, db_close: np.ndarray, q_close: np.ndarray, q_rows: np.ndarray, q_cols: np.ndarray,
                    width: int, out: np.ndarray) -> None:
    n_q = q_rows.shape[0]
    for i in prange(db.shape[0]):
        recall = np.zeros(width, dtype=np.float32)
        n_map = 0
        for j in range(db.shape[1]):
            word = db[i, j]
            if word == 0:
                continue
            for b in range(64):
                if (word >> np.uint64(b)) & np.uint64(1):
                    p = j * 64 + b
                    r = p // width
                    c = p % width
                    n_map += 1
                    # db column c is query column c + k (mod width): two runs without a modulo
                    for k in range(width - c):
                        recall[k] += q_close[r, c + k]
                    for k in range(width - c, width):
                        recall[k] += q_close[r, c + k - width]
        precision = np.zeros(width, dtype=np.float32)
        for m in range(n_q):
            r = q_rows[m]
            c = q_cols[m]
            # query column c is db column c - k (mod width)
            for k in range(c + 1):
                precision[k] += db_close[i, r, c - k]
            for k in range(c + 1, width):
                precision[k] += db_close[i, r, c - k + width]
        for k in range(width):
            rr = recall[k] / n_map if n_map > 0 else 0.0
            pp = precision[k] / n_q if n_q > 0 else 0.0
            out[i, k] = 0.5 * (rr + pp)


def chamfer_yaw_scores(db: np.ndarray, db_close: np.ndarray, query: np.ndarray, *, tau_px: float) -> np.ndarray:
    """The truncated chamfer score (module docstring) of every database panorama with the
    query at every column shift: (P, W) float64 in [0, 1]. ``db`` the undilated packed map
    line images, ``db_close`` their :func:`closeness` images (P, H, W)."""
    h, w = query.shape
    rows, cols = np.nonzero(query)
    out = np.zeros((db.shape[0], w))
    if db.shape[0]:
        _chamfer_shifts(np.ascontiguousarray(db), np.ascontiguousarray(db_close, np.float32),
                        closeness(query, tau_px).astype(np.float32), rows.astype(np.int64), cols.astype(np.int64), w, out)
    return out


def best_pose(scores: np.ndarray) -> tuple[int, int, float]:
    """(position row, column shift, score) of the best entry of a (P, W) score table."""
    i, k = np.unravel_index(int(np.argmax(scores)), scores.shape)
    return int(i), int(k), float(scores[i, k])

