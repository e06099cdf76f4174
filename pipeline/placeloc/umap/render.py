"""Render binary line images of a wireframe from many poses, straight into packed bits.

One numba kernel per block of poses: each segment is moved into camera coordinates,
clipped at the near plane, projected, clipped to the image (Liang-Barsky), and walked one
pixel at a time. With hidden-line removal each pixel's 3-D point (perspective-correct) is
tested against the vertical wall faces: hidden when the plan ray camera -> point crosses a
face strictly before the point at a height inside that face. Geometry conventions are
those of :mod:`placeloc.geometry`.

That per-pixel test (:func:`render_packed`) is kept as the reference. The fast renderer,
:func:`render_grid`, finds the visible pieces of every segment once per grid position
(:mod:`placeloc.geometry.visibility`: a 1-D depth buffer over the azimuth, valid for the
vertical walls of a floor plan) and draws them, with no further test, into the views of
every heading at that position; the lines are thickened (the tolerance of eq. (1)) with
bit shifts on the packed rows, so the stored database is the dilated one and there is no
second, undilated copy.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, prange

from placeloc.geometry import Camera
from placeloc.geometry.bitimage import POOL_PX, n_words, pack_into
from placeloc.geometry.rays import occluded
from placeloc.geometry.visibility import (
    COARSE,
    MAX_HITS,
    N_BINS,
    bin_directions,
    max_pieces,
    tall_faces,
    visible_pieces_at,
)


@njit(cache=True, inline="always")
def _to_near(px: float, py: float, pz: float, zp: float, qx: float, qy: float, qz: float, zq: float,
             near: float) -> tuple:
    """End p moved along p-q to the near plane (depth ``zp`` below it, ``zq`` above)."""
    t = (near - zp) / (zq - zp)
    return px + t * (qx - px), py + t * (qy - py), pz + t * (qz - pz), near


@njit(cache=True, inline="always")
def _near_clip(ax: float, ay: float, az: float, za: float, bx: float, by: float, bz: float, zb: float,
               near: float) -> tuple:
    """Clip the camera-relative segment a-b (depths ``za``, ``zb``) at the near plane,
    keeping the visible part; the caller has dropped segments wholly behind it."""
    if za < near:
        ax, ay, az, za = _to_near(ax, ay, az, za, bx, by, bz, zb, near)
    elif zb < near:
        bx, by, bz, zb = _to_near(bx, by, bz, zb, ax, ay, az, za, near)
    return ax, ay, az, za, bx, by, bz, zb


@njit(cache=True, inline="always")
def _screen_clip(ua: float, va: float, du: float, dv: float, width: int, height: int) -> tuple:
    """Liang-Barsky clip of the 2-D segment ``(ua, va) + s (du, dv)`` to the pixel area:
    ``(inside, s0, s1)``."""
    s0 = 0.0
    s1 = 1.0
    for k in range(4):
        if k == 0:
            p, q = -du, ua + 0.5
        elif k == 1:
            p, q = du, (width - 0.5) - ua
        elif k == 2:
            p, q = -dv, va + 0.5
        else:
            p, q = dv, (height - 0.5) - va
        if abs(p) < 1e-12:
            if q < 0.0:
                return False, s0, s1
        else:
            r = q / p
            if p < 0.0:
                if r > s1:
                    return False, s0, s1
                if r > s0:
                    s0 = r
            else:
                if r < s0:
                    return False, s0, s1
                if r < s1:
                    s1 = r
    return True, s0, s1


@njit(cache=True, inline="always")
def _segment_on_screen(seg: np.ndarray, px: float, py: float, pz: float, fx: float, fy: float, rx: float, ry: float,
                       near: float, focal: float, cx: float, cy: float, width: int, height: int) -> tuple:
    """Segment ``seg`` (x0 y0 z0 x1 y1 z1, world) seen from (px, py, pz) looking along
    (fx, fy): moved into camera offsets, clipped at the near plane, projected and clipped to
    the pixel area. Returns ``(inside, ua, va, du, dv, s0, s1, ax, ay, az, za, bx, by, bz,
    zb)``: the visible screen part is ``(ua, va) + s (du, dv)`` for s in [s0, s1]; a/b are
    the clipped end points relative to the camera and za/zb their depths (for a
    perspective-correct point along the segment)."""
    ax = seg[0] - px
    ay = seg[1] - py
    az = seg[2] - pz
    bx = seg[3] - px
    by = seg[4] - py
    bz = seg[5] - pz
    za = ax * fx + ay * fy
    zb = bx * fx + by * fy
    if za < near and zb < near:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, ax, ay, az, za, bx, by, bz, zb
    ax, ay, az, za, bx, by, bz, zb = _near_clip(ax, ay, az, za, bx, by, bz, zb, near)
    ua = cx + focal * (ax * rx + ay * ry) / za
    va = cy - focal * az / za
    du = cx + focal * (bx * rx + by * ry) / zb - ua
    dv = cy - focal * bz / zb - va
    inside, s0, s1 = _screen_clip(ua, va, du, dv, width, height)
    return inside, ua, va, du, dv, s0, s1, ax, ay, az, za, bx, by, bz, zb


@njit(parallel=True, cache=True)
def _render(segs: np.ndarray, faces: np.ndarray, poses: np.ndarray, width: int, height: int, focal: float,
            cx: float, cy: float, near: float, hidden: bool, out: np.ndarray) -> None:
    nseg = segs.shape[0]
    nfaces = faces.shape[0]
    half = math.atan((width / 2.0 + 1.0) / focal)  # half horizontal FOV plus a pixel of slack
    for v in prange(poses.shape[0]):
        px = poses[v, 0]
        py = poses[v, 1]
        pz = poses[v, 2]
        h = math.radians(poses[v, 3])
        fx = math.cos(h)
        fy = math.sin(h)
        rx = fy
        ry = -fx
        img = np.zeros(height * width, dtype=np.uint8)
        # Faces that can hide something: not wholly behind the camera nor wholly outside
        # one side of the horizontal frustum wedge (the camera->point ray lies inside it).
        fidx = np.empty(nfaces, dtype=np.int64)
        nf = 0
        if hidden:
            cl = math.cos(half)
            sl = math.sin(half)
            for f in range(nfaces):
                z0 = (faces[f, 0] - px) * fx + (faces[f, 1] - py) * fy
                z1 = (faces[f, 2] - px) * fx + (faces[f, 3] - py) * fy
                if z0 < 0.0 and z1 < 0.0:
                    continue
                x0 = (faces[f, 0] - px) * rx + (faces[f, 1] - py) * ry
                x1 = (faces[f, 2] - px) * rx + (faces[f, 3] - py) * ry
                # signed distances to the right and left wedge planes (positive = outside)
                if x0 * cl - z0 * sl > 0.0 and x1 * cl - z1 * sl > 0.0:
                    continue
                if -x0 * cl - z0 * sl > 0.0 and -x1 * cl - z1 * sl > 0.0:
                    continue
                fidx[nf] = f
                nf += 1
        for s in range(nseg):
            ok, ua, va, du, dv, s0, s1, ax, ay, az, za, bx, by, bz, zb = _segment_on_screen(
                segs[s], px, py, pz, fx, fy, rx, ry, near, focal, cx, cy, width, height)
            if not ok:
                continue
            npx = int(math.ceil(max(abs(du), abs(dv)) * (s1 - s0))) + 1
            for k in range(npx + 1):
                sc = s0 + (s1 - s0) * k / npx
                iu = int(math.floor(ua + sc * du + 0.5))
                iv = int(math.floor(va + sc * dv + 0.5))
                if iu < 0 or iu >= width or iv < 0 or iv >= height:
                    continue
                pix = iv * width + iu
                if img[pix]:
                    continue
                if hidden and nf > 0:
                    # screen parameter -> 3-D parameter (1/depth is linear on screen)
                    t = (sc / zb) / ((1.0 - sc) / za + sc / zb)
                    qx = px + ax + t * (bx - ax)
                    qy = py + ay + t * (by - ay)
                    qz = pz + az + t * (bz - az)
                    if occluded(px, py, pz, qx, qy, qz, faces, fidx, nf):
                        continue
                img[pix] = 1
        pack_into(img, height * width, out[v])


def render_packed(segments: np.ndarray, faces: np.ndarray, poses: np.ndarray, cam: Camera,
                  near: float = 0.05, hidden: bool = True) -> np.ndarray:
    """Line images of ``segments`` seen from each pose: (V, n_words) uint64, see :mod:`placeloc.geometry.bitimage`."""
    poses = np.ascontiguousarray(poses, dtype=np.float64).reshape(-1, 4)
    out = np.zeros((len(poses), n_words(cam.height, cam.width)), dtype=np.uint64)
    if len(poses):
        _render(np.ascontiguousarray(segments, np.float64).reshape(-1, 6), np.ascontiguousarray(faces, np.float64).reshape(-1, 6),
                poses, cam.width, cam.height, cam.focal, cam.cx, cam.cy, float(near), bool(hidden), out)
    return out


# ------------------------------------------------------------------ the fast renderer

@njit(cache=True)
def _draw_pieces(pieces: np.ndarray, n: int, px: float, py: float, pz: float, heading_deg: float, width: int, height: int,
                 focal: float, cx: float, cy: float, near: float, nwr: int, rows: np.ndarray) -> None:
    """Draw ``pieces[:n]`` (already visible) from one pose into ``rows`` (height x nwr
    words, bit u & 63 of word u >> 6 of a row = column u), exactly as :func:`_render` walks
    a segment without hidden-line removal."""
    h = math.radians(heading_deg)
    fx = math.cos(h)
    fy = math.sin(h)
    rx = fy
    ry = -fx
    for s in range(n):
        ok, ua, va, du, dv, s0, s1, _, _, _, _, _, _, _, _ = _segment_on_screen(
            pieces[s], px, py, pz, fx, fy, rx, ry, near, focal, cx, cy, width, height)
        if not ok:
            continue
        npx = int(math.ceil(max(abs(du), abs(dv)) * (s1 - s0))) + 1
        for k in range(npx + 1):
            sc = s0 + (s1 - s0) * k / npx
            iu = int(math.floor(ua + sc * du + 0.5))
            iv = int(math.floor(va + sc * dv + 0.5))
            if iu < 0 or iu >= width or iv < 0 or iv >= height:
                continue
            rows[iv * nwr + (iu >> 6)] |= np.uint64(1) << np.uint64(iu & 63)


@njit(cache=True, inline="always")
def _grow_row(src: np.ndarray, dst: np.ndarray, base: int, nwr: int) -> None:
    """dst row = src row OR its shifts by one column either way (one step of dilation)."""
    one = np.uint64(1)
    top = np.uint64(63)
    for j in range(nwr):
        w = src[base + j]
        v = w | (w << one) | (w >> one)
        if j > 0:
            v |= src[base + j - 1] >> top
        if j + 1 < nwr:
            v |= src[base + j + 1] << top
        dst[base + j] = v


@njit(cache=True)
def _dilate_pack(rows: np.ndarray, grown: np.ndarray, half_widths: np.ndarray, width: int, height: int, nwr: int,
                 out_row: np.ndarray, band: np.ndarray, pooled_row: np.ndarray) -> None:
    """OR of the rows shifted by dy and widened by ``half_widths[dy + t]`` columns (the
    elliptic structuring element of cv2.dilate), packed into the flat layout of
    :mod:`placeloc.geometry.bitimage`; and its 8 x 8 cells (on when any pixel is: see
    :func:`placeloc.umap.bits.pool_or`) into ``pooled_row`` when that is not empty."""
    t = (half_widths.shape[0] - 1) // 2
    kmax = 0
    for i in range(half_widths.shape[0]):
        kmax = max(kmax, half_widths[i])
    n = height * nwr
    grown[0, :n] = rows[:n]
    for k in range(1, kmax + 1):
        for y in range(height):
            _grow_row(grown[k - 1], grown[k], y * nwr, nwr)
    last_mask = np.uint64(0xFFFFFFFFFFFFFFFF)
    if width % 64:
        last_mask = (np.uint64(1) << np.uint64(width % 64)) - np.uint64(1)
    out_row[:] = 0
    nwords = out_row.shape[0]
    pool = pooled_row.shape[0] > 0
    if pool:
        band[:] = 0
    for y in range(height):
        for j in range(nwr):
            v = np.uint64(0)
            for dy in range(-t, t + 1):
                yy = y + dy
                if 0 <= yy < height:
                    v |= grown[half_widths[dy + t], yy * nwr + j]
            if j == nwr - 1:
                v &= last_mask
            if v == 0:
                continue
            if pool:
                band[(y // POOL_PX) * nwr + j] |= v
            pos = y * width + 64 * j
            wi = pos >> 6
            sh = pos & 63
            out_row[wi] |= v << np.uint64(sh)
            if sh > 0 and wi + 1 < nwords:
                out_row[wi + 1] |= v >> np.uint64(64 - sh)
    if pool:
        # a cell of 8 columns never straddles two words (64 = 8 x 8)
        pooled_row[:] = 0
        cw = (width + POOL_PX - 1) // POOL_PX
        cell_mask = np.uint64((1 << POOL_PX) - 1)
        for cy in range((height + POOL_PX - 1) // POOL_PX):
            for cx in range(cw):
                c0 = cx * POOL_PX
                if (band[cy * nwr + (c0 >> 6)] >> np.uint64(c0 & 63)) & cell_mask:
                    p = cy * cw + cx
                    pooled_row[p >> 6] |= np.uint64(1) << np.uint64(p & 63)


@njit(parallel=True, cache=True)
def _render_grid(segs: np.ndarray, faces: np.ndarray, tall: np.ndarray, positions: np.ndarray, headings: np.ndarray,
                 starts: np.ndarray, rows_out: np.ndarray, width: int, height: int, focal: float, cx: float, cy: float,
                 near: float, hidden: bool, half_widths: np.ndarray, dirs: np.ndarray, n_pieces_max: int, n_hits_max: int,
                 out: np.ndarray, pooled: np.ndarray) -> None:
    nwr = (width + 63) // 64
    kmax = 0
    for i in range(half_widths.shape[0]):
        kmax = max(kmax, half_widths[i])
    nb = (dirs.shape[0] - 1) // 2
    n_pos = positions.shape[0]
    # scratch arrays once per chunk of positions, not per position (large allocations are slow)
    n_chunks = min(n_pos, 256)
    for c in prange(n_chunks):
        key = np.empty((nb, n_hits_max))
        hf = np.empty((nb, n_hits_max), np.int64)
        nh = np.zeros(nb, np.int64)
        far = np.empty(nb)
        coarse = np.empty(nb // COARSE)
        pieces = np.empty((n_pieces_max, 6))
        rows = np.empty(height * nwr, np.uint64)
        grown = np.empty((kmax + 1, height * nwr), np.uint64)
        band = np.empty(((height + POOL_PX - 1) // POOL_PX) * nwr, np.uint64)
        for g in range(c * n_pos // n_chunks, (c + 1) * n_pos // n_chunks):
            px = positions[g, 0]
            py = positions[g, 1]
            pz = positions[g, 2]
            if hidden:
                n = visible_pieces_at(px, py, pz, segs, faces, tall, dirs, key, hf, nh, far, coarse, pieces)
            else:
                n = segs.shape[0]
                pieces[:n] = segs
            for v in range(starts[g], starts[g + 1]):
                rows[:] = 0
                _draw_pieces(pieces, n, px, py, pz, headings[v], width, height, focal, cx, cy, near, nwr, rows)
                _dilate_pack(rows, grown, half_widths, width, height, nwr, out[rows_out[v]], band,
                             pooled[rows_out[v]] if pooled.shape[0] else pooled[0:0, 0])


def dilation_half_widths(tolerance_px: int) -> np.ndarray:
    """Per row offset dy = -t..t, the half width of cv2's elliptic (2t+1)-square
    structuring element, which is what :func:`render_grid` thickens lines with."""
    import cv2

    t = int(tolerance_px)
    if t <= 0:
        return np.zeros(1, np.int64)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * t + 1, 2 * t + 1))
    out = np.zeros(2 * t + 1, np.int64)
    for i, row in enumerate(k):
        on = np.flatnonzero(row)
        hw = (len(on) - 1) // 2
        if len(on) == 0 or on[0] != t - hw or on[-1] != t + hw or len(on) != on[-1] - on[0] + 1:
            raise ValueError(f"the elliptic kernel of tolerance {t} has a row that is not a centred run: {row}")
        out[i] = hw
    return out


def render_grid(segments: np.ndarray, faces: np.ndarray, poses: np.ndarray, cam: Camera, *, near: float, hidden: bool,
                tolerance_px: int, pooled: bool = False) -> Any:
    """Line images of ``segments`` from each pose, lines thickened by ``tolerance_px`` (as
    cv2.dilate with the elliptic kernel would): (V, n_words) uint64 in the order of
    ``poses``. Hidden lines are removed once per distinct position (module docstring).
    ``pooled``: also return their 8 x 8 cell images (:func:`placeloc.umap.bits.pool_or`)."""
    poses = np.ascontiguousarray(poses, dtype=np.float64).reshape(-1, 4)
    out = np.zeros((len(poses), n_words(cam.height, cam.width)), dtype=np.uint64)
    cells = np.zeros((len(poses) if pooled else 0, n_words(-(-cam.height // POOL_PX), -(-cam.width // POOL_PX))), np.uint64)
    if not len(poses):
        return (out, cells) if pooled else out
    segs = np.ascontiguousarray(segments, np.float64).reshape(-1, 6)
    fc = np.ascontiguousarray(faces, np.float64).reshape(-1, 6)
    positions, inverse = np.unique(poses[:, :3], axis=0, return_inverse=True)
    order = np.argsort(inverse.ravel(), kind="stable")
    starts = np.searchsorted(inverse.ravel()[order], np.arange(len(positions) + 1))
    _render_grid(segs, fc, tall_faces(segs, fc), positions, np.ascontiguousarray(poses[order, 3]), starts.astype(np.int64),
                 order.astype(np.int64), cam.width, cam.height, cam.focal, cam.cx, cam.cy, float(near),
                 bool(hidden and len(fc) > 0), dilation_half_widths(tolerance_px), bin_directions(N_BINS), max(max_pieces(len(segs)), len(segs)),
                 MAX_HITS, out, cells)
    return (out, cells) if pooled else out


def render_grid_block(item: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Executor work item: (segments, faces, poses, (W, H, hfov), near, hidden, tolerance_px)
    -> (packed block, its packed 8 x 8 cell images)."""
    segments, faces, poses, cam, near, hidden, tol = item
    return render_grid(segments, faces, poses, Camera(*cam), near=near, hidden=hidden, tolerance_px=tol, pooled=True)
