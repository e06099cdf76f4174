"""Equirectangular (360 degree) line images: a wireframe rendered as a panorama from a pose,
and the LSD lines of a grey panorama drawn into one.

Convention (that of :func:`placeloc.geometry.equirect_to_pinhole`): column u shows azimuth
``pi - 2 pi (u + 0.5) / W`` relative to the heading (centre column = the heading, azimuth
growing to the left), row v elevation ``pi / 2 - pi (v + 0.5) / H``. A panorama taken at
heading ``psi`` is the one taken at heading 0 rolled by ``k = psi W / 360`` columns
(``img_psi[:, u] = img_0[:, u - k]``). Packed images hold 64 pixels per uint64 word,
row-major, pixel p in word p >> 6 at bit p & 63.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit, prange

from placeloc.core.images import ImageError, PanoramaCrop
from placeloc.geometry import Camera, equirect_to_pinhole
from placeloc.geometry.bitimage import n_words, pack_into
from placeloc.geometry.rays import face_terms, occluded_terms


def detect_segments(gray: np.ndarray) -> np.ndarray:
    """LSD segments of a grey image: (N, 4) float64 rows x0 y0 x1 y1 in its pixels."""
    found = cv2.createLineSegmentDetector().detect(gray)[0]
    return np.zeros((0, 4)) if found is None else found.reshape(-1, 4).astype(np.float64)  # (N,1,4) in 4.x


# ------------------------------------------------------------------ rendering the map

@njit(cache=True)
def _angle_to_col(az: float, width: int) -> float:
    return ((math.pi - az) / (2.0 * math.pi) % 1.0) * width - 0.5



# margins of the whole-segment hidden test (:func:`_segment_hidden`), far above float64 rounding:
# a segment culled with them has every sample hidden by the per-sample test too
CULL_SIN = 1e-9        # sine of the least angle a segment keeps inside a face's wedge
CULL_M = 1e-6          # metres, beyond the 5 mm clearance of the per-sample test


@njit(cache=True)
def _segment_hidden(ax: float, ay: float, az: float, bx: float, by: float, bz: float, faces: np.ndarray, px: float,
                    py: float, pz: float) -> bool:
    """:func:`_segment_hidden_among` every face."""
    return _segment_hidden_among(ax, ay, az, bx, by, bz, faces, px, py, pz, np.arange(faces.shape[0]), faces.shape[0])


@njit(cache=True)
def _segment_hidden_among(ax: float, ay: float, az: float, bx: float, by: float, bz: float, faces: np.ndarray,
                          px: float, py: float, pz: float, candidates: np.ndarray, n_candidates: int) -> bool:
    """True when one wall face (of the first ``n_candidates`` in ``candidates``) hides the
    whole segment a -> b (plan coordinates relative to the camera at (px, py, pz); heights
    absolute) from the camera: the face spans the line of sight's heights (from the camera's
    to the segment's), the segment lies wholly on the far side of the face's line, more than
    the per-sample test's 5 mm clearance beyond it, and inside the wedge of directions the
    face covers. Every sample of the segment then fails
    :func:`placeloc.geometry.rays.occluded`'s test only by being hidden (that test finds this
    face in its column list: the list covers the face's span and a column more), so skipping
    the segment draws the same pixels. Wedge and distance are convex: testing the two ends
    covers the points between. The renderer passes the faces listed for the column of a: a
    face that hides the segment holds a inside its wedge, so it is listed there, and the
    answer is the one over every face."""
    z_lo = min(pz, az, bz)
    z_hi = max(pz, az, bz)
    la = math.sqrt(ax * ax + ay * ay)
    lb = math.sqrt(bx * bx + by * by)
    if la < 1e-9 or lb < 1e-9:
        return False
    for k in range(n_candidates):
        f = candidates[k]
        if faces[f, 4] > z_lo or faces[f, 5] < z_hi:
            continue
        cx = faces[f, 0] - px
        cy = faces[f, 1] - py
        dx = faces[f, 2] - px
        dy = faces[f, 3] - py
        ex = dx - cx
        ey = dy - cy
        le = math.sqrt(ex * ex + ey * ey)
        if le < 1e-9:
            continue
        # signed distance of the camera from the face's line: away from it (the per-sample
        # test's crossing parameter must exceed 1e-9 of the way to the point)
        side_cam = (ex * (0.0 - cy) - ey * (0.0 - cx)) / le
        if abs(side_cam) <= max(CULL_M, 1e-6 * max(la, lb)):
            continue
        sa = (ex * (ay - cy) - ey * (ax - cx)) / le
        sb = (ex * (by - cy) - ey * (bx - cx)) / le
        lim = 0.005 + CULL_M
        if side_cam > 0.0:
            if sa > -lim or sb > -lim:
                continue
        elif sa < lim or sb < lim:
            continue
        # inside the wedge C..D seen from the camera: same turn as C -> D from C to the point
        # and from the point to D
        turn = 1.0 if cx * dy - cy * dx > 0.0 else -1.0
        lc = math.sqrt(cx * cx + cy * cy)
        ld = math.sqrt(dx * dx + dy * dy)
        if lc < 1e-9 or ld < 1e-9:
            continue
        if turn * (cx * ay - cy * ax) <= CULL_SIN * lc * la or turn * (ax * dy - ay * dx) <= CULL_SIN * la * ld:
            continue
        if turn * (cx * by - cy * bx) <= CULL_SIN * lc * lb or turn * (bx * dy - by * dx) <= CULL_SIN * lb * ld:
            continue
        return True
    return False


@njit(cache=True)
def orientation_bit(du: float, dv: float, bins: int) -> int:
    """The bit (1 << bin) of a line's direction (du, dv) in image pixels (columns right,
    rows down) among ``bins`` bins of 180 / bins degrees, bin 0 centred on the image's
    horizontal (bin b on b 180 / bins degrees); 1 when ``bins`` <= 1."""
    if bins <= 1:
        return 1
    theta = math.atan2(dv, du) % math.pi
    return 1 << (int(math.floor(theta * bins / math.pi + 0.5)) % bins)


@njit(cache=True)
def orientation_bits(du: np.ndarray, dv: np.ndarray, bins: int) -> np.ndarray:
    """:func:`orientation_bit` of each direction ``(du[i], dv[i])``, as uint8 (the query
    line image's samples)."""
    out = np.empty(len(du), np.uint8)
    for i in range(len(du)):
        out[i] = orientation_bit(du[i], dv[i], bins)
    return out


@njit(cache=True)
def orientation_bit_fast(du: float, dv: float, bins: int, bound_cos: np.ndarray, bound_sin: np.ndarray) -> int:
    """:func:`orientation_bit` without the arctangent (the renderer's inner loop): the
    direction turned into the upper half-plane counted against the bins' boundary directions
    ``(bound_cos[k], bound_sin[k])`` at (k + 1/2) 180 / bins degrees (equal but at exact ties:
    tested)."""
    if bins <= 1:
        return 1
    if dv < 0.0 or (dv == 0.0 and du < 0.0):
        du = -du
        dv = -dv
    k = 0
    while k < bins and bound_cos[k] * dv - bound_sin[k] * du >= 0.0:
        k += 1
    return 1 << (k % bins)


# The renderer reads a sample's pixel off the directions of the pixel edges around it,
# without its two arctangents, where that is certain to give the pixel the arctangents give:
# the sample's direction lies more than EDGE_SIN (sine of an angle) inside the edges of the
# pixel of the sample before it (or of a neighbour a few steps away). The arctangent path
# maps an angle to a column or row by a chain of rounded operations, each monotone and off
# the exact map by far less than 1e-11 pixel (headings up to EDGE_HEAD_MAX radians, the
# rounding of ``azimuth - heading`` included), and the library's arctangent is within a few
# units in the last place; an angle 1e-9 inside an edge is 2e-8 pixel (144 columns) inside,
# so both paths give the same pixel. Samples nearer an edge, and every sample of a heading
# beyond EDGE_HEAD_MAX, take the arctangent path.
EDGE_SIN = 1e-9
EDGE_HEAD_MAX = 1e3
EDGE_MOVES = 4          # pixels a certified test may step from the previous sample's


@njit(cache=True)
def column_faces(faces: np.ndarray, px: float, py: float, head: float, width: int, counts: np.ndarray,
                 lists: np.ndarray, order: np.ndarray) -> None:
    """The faces that can hide a point seen in each column from (px, py) at heading ``head``
    (radians): ``lists[c, :counts[c]]`` (``counts`` zeros, ``lists`` (width, F)), each face
    listed in the columns of its angular span and one more on either side, each list in the
    faces' order in ``order``."""
    for f in order:
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


@njit(cache=True)
def _col_of(qx: float, qy: float, head: float, width: int) -> int:
    """The column of the plan direction (qx, qy) at heading ``head`` (radians): the
    arctangent path."""
    azm = math.atan2(qy, qx) - head
    fu = _angle_to_col(azm, width)
    return int(math.floor(fu + 0.5)) % width


@njit(cache=True)
def _row_of(qz: float, r: float, height: int) -> int:
    """The row of the direction at height ``qz`` over plan distance ``r``: the arctangent
    path."""
    el = math.atan2(qz, r)
    iv = int(math.floor((math.pi / 2.0 - el) / math.pi * height - 0.5 + 0.5))
    return min(max(iv, 0), height - 1)


@njit(cache=True, inline="always")
def _col_certified(qx: float, qy: float, r: float, k: int, edge_x: np.ndarray, edge_y: np.ndarray, width: int) -> int:
    """The column of the plan direction (qx, qy) of length ``r`` when it lies more than
    EDGE_SIN inside the edges of column ``k`` or of one at most EDGE_MOVES columns from it,
    else -1. Column c spans the directions from edge c + 1 (``(edge_x, edge_y)[c + 1]``,
    clockwise) to edge c: the direction is inside when it is clockwise of edge c and
    anticlockwise of edge c + 1 (cross products; the span is narrower than a half turn)."""
    m = EDGE_SIN * r
    for _ in range(EDGE_MOVES + 1):
        hi = edge_x[k] * qy - edge_y[k] * qx
        if hi < -m:
            lo = edge_x[k + 1] * qy - edge_y[k + 1] * qx
            if lo > m:
                return k
            if lo < -m:
                k = k + 1 if k + 1 < width else 0
                continue
            return -1
        if hi > m:
            k = k - 1 if k > 0 else width - 1
            continue
        return -1
    return -1


@njit(cache=True, inline="always")
def _row_certified(qz: float, r: float, j: int, edge_x: np.ndarray, edge_y: np.ndarray, height: int) -> int:
    """The row of the direction (r, qz) (plan distance, height) when it lies more than
    EDGE_SIN inside the edges of row ``j`` or of one at most EDGE_MOVES rows from it, else
    -1; row j spans the elevations from edge j + 1 to edge j, the first and last row to the
    poles."""
    m = EDGE_SIN * (r + abs(qz))
    for _ in range(EDGE_MOVES + 1):
        if j > 0:
            hi = edge_x[j] * qz - edge_y[j] * r
            if not hi < -m:
                if hi > m:
                    j -= 1
                    continue
                return -1
        if j < height - 1:
            lo = edge_x[j + 1] * qz - edge_y[j + 1] * r
            if not lo > m:
                if lo < -m:
                    j += 1
                    continue
                return -1
        return j
    return -1


@njit(parallel=True, cache=True, nogil=True)
def _render_equirect(segs: np.ndarray, vertical: np.ndarray, faces: np.ndarray, poses: np.ndarray, width: int, height: int,
                     hidden: bool, which: int, bins: int, out: np.ndarray, masks: np.ndarray) -> None:
    """``which``: 0 every segment, 1 only vertical ones, 2 only the others. ``bins`` 0: the
    packed binary image into ``out``; ``bins`` >= 1: each pixel's bitmask of the
    :func:`orientation_bit` of the lines through it into ``masks`` (V, H W) uint8."""
    nf = faces.shape[0]
    step = 2.0 * math.pi / width
    bound = (np.arange(max(bins, 1)) + 0.5) * math.pi / max(bins, 1)
    bound_cos = np.cos(bound)
    bound_sin = np.sin(bound)
    # pixel edges' directions: column edge k at azimuth pi - 2 pi k / W from the heading (edge
    # W is edge 0), row edge j at elevation pi / 2 - pi j / H
    col_angle = math.pi - 2.0 * math.pi * np.arange(width + 1) / width
    col_cos = np.cos(col_angle)
    col_sin = np.sin(col_angle)
    row_angle = math.pi / 2.0 - math.pi * np.arange(height + 1) / height
    row_x = np.cos(row_angle)
    row_y = np.sin(row_angle)
    for v in prange(poses.shape[0]):
        px = poses[v, 0]
        py = poses[v, 1]
        pz = poses[v, 2]
        head = math.radians(poses[v, 3])
        certify_cols = abs(head) <= EDGE_HEAD_MAX
        ch = math.cos(head)
        sh = math.sin(head)
        edge_x = col_cos * ch - col_sin * sh
        edge_y = col_sin * ch + col_cos * sh
        img = np.zeros(height * width, dtype=np.uint8)
        # faces per column: a face can only hide points whose azimuth lies in its angular span
        counts = np.zeros(width, dtype=np.int64)
        lists = np.empty((width, max(nf, 1)), dtype=np.int64)
        terms = np.empty((max(nf, 1), 6))
        if hidden:
            face_terms(px, py, faces, terms)
            # nearest first: the hidden-line test stops at the first face beyond the point
            column_faces(faces, px, py, head, width, counts, lists, np.argsort(terms[:nf, 5]))
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
            # the column of the segment's first end: where its whole-segment hidden test finds
            # every face that could hide it whole, and where the certified tests start
            ia = _col_of(ax, ay, head, width)
            if hidden and _segment_hidden_among(ax, ay, segs[s, 2], ax + ex, ay + ey, segs[s, 5], faces, px, py, pz,
                                                lists[ia], counts[ia]):
                continue
            # closest distance camera -> segment bounds the angular speed along it
            t0 = -(ax * ex + ay * ey + az * ez) / (ll * ll)
            t0 = min(max(t0, 0.0), 1.0)
            cxp = ax + t0 * ex
            cyp = ay + t0 * ey
            czp = az + t0 * ez
            dmin = max(math.sqrt(cxp * cxp + cyp * cyp + czp * czp), 0.05)
            n = min(int(math.ceil(2.0 * ll / dmin / step)) + 1, 20000)
            iu = ia   # the previous sample's pixel: where the certified tests start
            iv = -1
            for i in range(n + 1):
                t = i / n
                qx = ax + t * ex
                qy = ay + t * ey
                qz = az + t * ez
                r = math.sqrt(qx * qx + qy * qy)
                if certify_cols and iu >= 0:
                    iu = _col_certified(qx, qy, r, iu, edge_x, edge_y, width)
                else:
                    iu = -1
                if iu < 0:
                    iu = _col_of(qx, qy, head, width)
                if iv >= 0:
                    iv = _row_certified(qz, r, iv, row_x, row_y, height)
                if iv < 0:
                    iv = _row_of(qz, r, height)
                pix = iv * width + iu
                bit = 1
                if bins > 1:
                    # the image's tangent along the segment, exactly: u = -(W / 2 pi) azimuth,
                    # v = -(H / pi) elevation (+ constants)
                    rr = max(r, 1e-9)
                    du = -width / (2.0 * math.pi) * (qx * ey - qy * ex) / (rr * rr)
                    dv = -height / math.pi * (rr * ez - qz * (qx * ex + qy * ey) / rr) / (rr * rr + qz * qz)
                    bit = orientation_bit_fast(du, dv, bins, bound_cos, bound_sin)
                if img[pix] & bit:
                    continue
                if hidden and counts[iu] > 0:
                    if occluded_terms(px, py, pz, px + qx, py + qy, pz + qz, faces, terms, lists[iu], counts[iu]):
                        continue
                img[pix] |= bit
        if bins >= 1:
            masks[v, :] = img
        else:
            pack_into(img, height * width, out[v])


def vertical_segments(segments: np.ndarray) -> np.ndarray:
    """True for segments within 10 degrees of vertical (wall corners, door jambs)."""
    d = np.asarray(segments, float).reshape(-1, 6)
    d = d[:, 3:6] - d[:, 0:3]
    return np.abs(d[:, 2]) >= np.cos(np.radians(10.0)) * np.maximum(np.linalg.norm(d, axis=1), 1e-12)


def render_panoramas(segments: np.ndarray, faces: np.ndarray, poses: np.ndarray, *, width: int, height: int,
                     hidden: bool, which: str = "all", orientation_bins: int = 0) -> np.ndarray:
    """Equirectangular line images of ``segments`` from each pose (x, y, z, heading): packed
    (V, n_words) uint64 (layout of :mod:`placeloc.geometry.bitimage`). ``which``: ``all``, or only
    the ``vertical`` or ``other`` segments (for the direction-split score). ``orientation_bins``
    >= 1: instead (V, H, W) uint8, each pixel the bitmask of the :func:`orientation_bit` s of
    the lines drawn through it (their image direction there, exact from the segment); the
    pixels with a nonzero mask are those of the packed image."""
    poses = np.ascontiguousarray(poses, dtype=np.float64).reshape(-1, 4)
    segs = np.ascontiguousarray(segments, np.float64).reshape(-1, 6)
    bins = int(orientation_bins)
    if not 0 <= bins <= 8:
        raise ValueError(f"orientation_bins must lie in 0..8 (one bit each in a uint8), not {bins}")
    out = np.zeros((0 if bins else len(poses), n_words(height, width)), dtype=np.uint64)
    masks = np.zeros((len(poses) if bins else 0, height * width), dtype=np.uint8)
    if len(poses):
        _render_equirect(segs, vertical_segments(segs), np.ascontiguousarray(faces, np.float64).reshape(-1, 6), poses,
                         int(width), int(height), bool(hidden), {"all": 0, "vertical": 1, "other": 2}[which], bins, out,
                         masks)
    return masks.reshape(-1, height, width) if bins else out


def render_panorama_block(item: tuple) -> np.ndarray:
    """Executor work item: (segments, faces, poses, width, height, hidden, which) -> packed block."""
    segments, faces, poses, width, height, hidden, which = item
    return render_panoramas(segments, faces, poses, width=width, height=height, hidden=hidden, which=which)


# ------------------------------------------------------------------ the query's line image

@dataclass(frozen=True)
class Coverage:
    """The part of an equirectangular panorama its photo covers, as fractions of the
    panorama's width and height: columns ``left`` .. ``left + width`` (wrapping at 1), rows
    ``top`` .. ``top + height`` (row 0 straight up). The whole sphere is (0, 0, 1, 1)."""

    left: float
    top: float
    width: float
    height: float


WHOLE = Coverage(0.0, 0.0, 1.0, 1.0)
COVERAGE_MARGIN_DEG = 1.0    # lines within this of a crop's edge are the edge of the fill, not of the scene


def whole_panorama(gray: np.ndarray, crop: PanoramaCrop, path: str = "") -> tuple[np.ndarray, Coverage]:
    """A partial 360 degree photo (a photo sphere stored cropped, ``crop`` from its GPano
    metadata) placed in its whole equirectangular panorama at the photo's own scale, the
    rest filled with the photo's mean grey (no edges there), and the part it covers. The
    photo may have been resized since its metadata was written, if evenly."""
    h, w = gray.shape[:2]
    scale = w / crop.width
    if abs(h - crop.height * scale) > max(2.0, 0.01 * h):
        raise ImageError(f"{path}: the image is {w}x{h} but its Photo Sphere metadata (GPano) says the crop is "
                         f"{crop.width}x{crop.height}: it was resized unevenly or cropped again; export it anew")
    full_w = max(2, int(round(crop.full_width * scale)))
    full_h = full_w // 2
    # a crop that is a sliver of its panorama (or metadata that says so) would ask for a canvas
    # many times the photo: refused as decoding refuses an image larger than the memory
    from placeloc.core.safe_io import memory_budget

    budget = memory_budget() // 4
    if full_w * full_h * gray.itemsize > budget:
        raise ImageError(f"{path}: its Photo Sphere metadata (GPano) places the {w}x{h} photo in a {full_w}x{full_h} "
                         f"panorama, more than a quarter of the memory available ({budget * 4 / 2**20:.0f} MB); check "
                         "the metadata (FullPanoWidthPixels, CroppedAreaImageWidthPixels) or resize the photo")
    top = min(int(round(crop.top * scale)), max(0, full_h - h))
    rows = min(h, full_h - top)
    canvas = np.full((full_h, full_w), int(round(float(gray.mean()))), gray.dtype)
    cols = (int(round(crop.left * scale)) + np.arange(min(w, full_w))) % full_w
    canvas[top:top + rows, cols] = gray[:rows, :len(cols)]
    return canvas, Coverage(crop.left / crop.full_width, crop.top / crop.full_height, crop.width / crop.full_width,
                            crop.height / crop.full_height)


def _covered(az: np.ndarray, el: np.ndarray, coverage: Coverage) -> np.ndarray:
    """Which directions (the image's azimuth and elevation) lie inside ``coverage`` by more
    than :data:`COVERAGE_MARGIN_DEG`."""
    fu = (math.pi - az) / (2.0 * math.pi) % 1.0
    fv = (math.pi / 2.0 - el) / math.pi
    mv, mu = COVERAGE_MARGIN_DEG / 180.0, COVERAGE_MARGIN_DEG / 360.0
    inside = (fv >= coverage.top + mv) & (fv <= coverage.top + coverage.height - mv)
    if coverage.width < 1.0:
        inside &= ((fu - coverage.left) % 1.0 >= mu) & ((fu - coverage.left) % 1.0 <= coverage.width - mu)
    return inside


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


# CLAHE's tile, in face pixels (:func:`equalized`): OpenCV's default grid of 8 x 8 tiles on
# the default 256-pixel face, not tuned. A tile spans 11 degrees (half a metre of wall at
# 2.5 m): local, so that a bright window does not set the contrast of the wall around it
EQUALIZE_TILE_PX = 32


def equalized(face: np.ndarray, clip: float) -> np.ndarray:
    """A grey 8-bit image with its contrast equalised locally (CLAHE: tiles of
    :data:`EQUALIZE_TILE_PX` pixels, each tile's histogram clipped at ``clip`` times its
    mean bin before equalising, so that flat, noisy areas are not stretched without
    bound). Why: LSD keeps a pixel only where the gradient passes a fixed threshold (about 5
    grey levels at its defaults), so a junction of two surfaces painted alike (a white wall
    under a white ceiling) is missed whatever its length, while a busy kitchen's edges are
    found; equalised, a faint junction's contrast is raised toward its tile's range."""
    face = face if face.dtype == np.uint8 else np.clip(face, 0, 255).astype(np.uint8)
    tiles = max(1, round(max(face.shape[:2]) / EQUALIZE_TILE_PX))
    return cv2.createCLAHE(clipLimit=float(clip), tileGridSize=(tiles, tiles)).apply(face)


def panorama_lines(pano: np.ndarray, *, face_px: int, min_length: float, equalize_clip: float = 0.0) -> list[np.ndarray]:
    """LSD segments of a grey equirectangular panorama, found on its six cube faces (where
    world lines are straight) and returned per face as (N, 4) pixel rows of a ``face_px``
    square 90 degree view; segments shorter than ``min_length`` face pixels are dropped.
    ``equalize_clip`` > 0: each face's contrast is first equalised locally at that clip
    limit (:func:`equalized`)."""
    cam = Camera(face_px, face_px, 90.0)
    out = []
    for hd, pitch in CUBE_FACES:
        face = equirect_to_pinhole(pano, hd, cam, pitch)
        segs = detect_segments(equalized(face, equalize_clip) if equalize_clip > 0 else face)
        out.append(segs[np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]) >= min_length])
    return out


def _world_vertical(seg: np.ndarray, pitch_deg: float, face_px: int) -> bool:
    """Whether a cube face's segment is a vertical line of the world: vertical in the image
    on an upright face, through the image centre on the up and down faces."""
    x0, y0, x1, y1 = (float(c) for c in seg)
    if pitch_deg == 0.0:
        return abs(x1 - x0) <= math.tan(math.radians(10.0)) * abs(y1 - y0)
    c = (face_px - 1) / 2.0
    dx, dy = x1 - x0, y1 - y0
    return abs(dx * (c - y0) - dy * (c - x0)) / max(math.hypot(dx, dy), 1e-9) <= 0.05 * face_px


def directions(az: np.ndarray, el: np.ndarray) -> np.ndarray:
    """(..., 3) unit vectors of azimuths and elevations (radians): x at azimuth 0, y at 90
    degrees, z the zenith; the frame :func:`upright_rotation` turns."""
    c = np.cos(el)
    return np.stack([c * np.cos(az), c * np.sin(az), np.sin(el)], axis=-1)


def _turned(az: np.ndarray, el: np.ndarray, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = directions(az, el) @ rotation.T
    return np.arctan2(d[..., 1], d[..., 0]), np.arcsin(np.clip(d[..., 2], -1.0, 1.0))


# Levelling (:func:`upright_rotation`). The great circles of a panorama's world-vertical lines
# all pass through its zenith. A floor or ceiling line passes near it only where it runs near
# the camera's foot, and a family of such lines (planks, a hall runner) passes it at several
# offsets, not through one point, so the zenith is the point most lines pass near (a vote
# over candidate points, coarse then fine: LEVEL_VOTES), then the least-squares point of the
# lines within LEVEL_BAND_DEG of it. A least-squares fit over a wider band was pulled
# 4.8 degrees off by a plank floor under a level camera (a generated home's hallway).
LEVEL_BAND_DEG = 1.0
LEVEL_VOTES = ((1.0, 2.0), (0.25, 1.0))   # (step, band) in degrees: coarse over the whole reach, then fine
LEVEL_MIN_LINES = 4          # fewest lines through the zenith found to level by
LEVEL_MIN_SPREAD = 0.05      # least ratio of their normals' scatter, narrowest to widest direction
# Tilts below this are left as they are: on the 60 level panoramas of the development homes
# the tilt found scatters up to 0.29 deg (median 0.07), and turning a level panorama by its
# own noise changes nothing but which of two near-tied places a search ends on.
LEVEL_MIN_DEG = 0.5


def segment_normals(faces: list[np.ndarray], face_px: int, coverage: Coverage = WHOLE) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals of the great circles of the four side faces' segments (``faces`` as
    :func:`panorama_lines` gives them) and the angle each segment spans (radians), in the
    frame of :func:`directions`; segments spanning less than 0.5 degrees are dropped (their
    normal is noise), and those with an end outside ``coverage`` (a cropped photo's fill, by
    :data:`COVERAGE_MARGIN_DEG`). The up and down faces are left out: they hold what lies over and
    under the camera (a ceiling fan's blades, a lamp, rugs, sunlight stripes, the tripod),
    whose lines radiate from points near the poles, and world-vertical lines cross the side
    faces."""
    cam = Camera(face_px, face_px, 90.0)
    ends = []
    for (hd, pitch), segs in zip(CUBE_FACES, faces):
        if len(segs) and pitch == 0.0:
            az0, el0 = _face_rays(segs[:, 0], segs[:, 1], cam, hd, pitch)
            az1, el1 = _face_rays(segs[:, 2], segs[:, 3], cam, hd, pitch)
            inside = _covered(az0, el0, coverage) & _covered(az1, el1, coverage)
            ends.append((directions(az0[inside], el0[inside]), directions(az1[inside], el1[inside])))
    if not ends:
        return np.zeros((0, 3)), np.zeros(0)
    n = np.cross(np.concatenate([a for a, _ in ends]), np.concatenate([b for _, b in ends]))
    sin_span = np.linalg.norm(n, axis=1)
    keep = sin_span > math.sin(math.radians(0.5))
    return n[keep] / sin_span[keep, None], np.arcsin(np.minimum(sin_span[keep], 1.0))


def upright_rotation(normals: np.ndarray, spans: np.ndarray, *, max_tilt_deg: float) -> tuple[np.ndarray, float]:
    """The rotation that turns a panorama upright, and its tilt in degrees: the panorama's
    zenith found as the direction the great circles of its world-vertical lines pass
    through (``normals``, ``spans`` as :func:`segment_normals` gives them).

    Each candidate zenith (points on the tangent plane of the image's, first 1 degree apart
    within ``max_tilt_deg``, then 0.25 degrees apart around the best: :data:`LEVEL_VOTES`)
    earns each line's span times ``1 - (d / band)^2`` for a line whose great circle passes
    ``d`` < band from it; the best candidate is then polished to the direction least out of the planes
    of the lines within the band of it (the eigenvector of the least eigenvalue of ``sum w n
    n^T``, ``w`` the spans), twice. No turn (the identity and 0) where fewer than
    :data:`LEVEL_MIN_LINES` lines pass within the band, where they do not fix the zenith in
    both directions (their normals all alike: vertical lines seen in one direction only), or
    where the tilt is below :data:`LEVEL_MIN_DEG` (a level panorama's own scatter).
    The rotation is the least one taking the zenith found to (0, 0, 1), which leaves the
    heading as it was to first order."""
    if len(normals) < LEVEL_MIN_LINES or max_tilt_deg <= 0.0:
        return np.eye(3), 0.0
    centre, reach = np.zeros(2), math.tan(math.radians(max_tilt_deg))
    for step_deg, band_deg in LEVEL_VOTES:
        t = np.arange(-reach, reach + 1e-12, math.tan(math.radians(step_deg)))
        a, b = np.meshgrid(t, t)
        inside = np.hypot(a, b) <= reach
        cand = np.stack([a[inside] + centre[0], b[inside] + centre[1], np.ones(int(inside.sum()))], axis=1)
        off = np.abs(cand @ normals.T) / (np.linalg.norm(cand, axis=1, keepdims=True) * math.sin(math.radians(band_deg)))
        centre = cand[int(np.argmax((np.clip(1.0 - off * off, 0.0, None) * spans).sum(axis=1))), :2]
        reach = 1.5 * math.tan(math.radians(step_deg))
    up = np.array([centre[0], centre[1], 1.0]) / math.hypot(centre[0], centre[1], 1.0)
    band = math.sin(math.radians(LEVEL_BAND_DEG))
    for _ in range(2):
        near = np.abs(normals @ up) < band
        if int(near.sum()) < LEVEL_MIN_LINES:
            return np.eye(3), 0.0
        n, w = normals[near], spans[near]
        vals, vecs = np.linalg.eigh((n * w[:, None]).T @ n)
        if vals[1] < LEVEL_MIN_SPREAD * vals[2]:
            return np.eye(3), 0.0
        up = vecs[:, 0] if vecs[2, 0] >= 0 else -vecs[:, 0]
    tilt = math.degrees(math.acos(min(1.0, float(up[2]))))
    if tilt > max_tilt_deg or tilt < LEVEL_MIN_DEG:
        return np.eye(3), 0.0
    return axis_rotation(np.cross(up, [0.0, 0.0, 1.0]), tilt), tilt


def axis_rotation(axis: np.ndarray, angle_deg: float) -> np.ndarray:
    """The 3 x 3 rotation by ``angle_deg`` about ``axis`` (Rodrigues' formula)."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    a = math.radians(angle_deg)
    return np.eye(3) + math.sin(a) * k + (1.0 - math.cos(a)) * (k @ k)


def turn_panorama(img: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """An equirectangular image as a camera turned by ``rotation`` sees it: the pixel of
    direction d (the frame of :func:`directions`) shows what ``img`` shows at ``rotation @
    d`` (bilinear, columns wrapping). A level camera's panorama turned by a tilt about a
    horizontal axis is that of the camera tilted so; :func:`upright_rotation` of the result
    finds the same rotation back (tested)."""
    h, w = img.shape[:2]
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    az, el = _turned(math.pi - 2.0 * math.pi * u / w, math.pi / 2.0 - math.pi * v / h, rotation)
    fu = ((math.pi - az) / (2.0 * math.pi) % 1.0) * w - 0.5
    fv = (math.pi / 2.0 - el) / math.pi * h - 0.5
    return cv2.remap(img, fu.astype(np.float32), fv.astype(np.float32), cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)


def face_samples(segs: np.ndarray, cam: Camera, heading_deg: float, pitch_deg: float, width: int,
                 height: int, rotation: np.ndarray | None = None,
                 coverage: Coverage = WHOLE) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The equirectangular samples of a cube face's LSD segments (``segs`` (N, 4) face
    pixels, N >= 1), all at once: their pixel rows and columns, the curve's tangent
    (columns, rows) at each, and the segment each belongs to. ``rotation`` (3 x 3): each
    sample's direction turned by it (in the frame of :func:`directions`) before it is drawn.
    ``coverage``: only the samples inside it (a cropped photo's fill left out, by
    :data:`COVERAGE_MARGIN_DEG`), their tangents those of the whole segment.

    Each segment is sampled at ``ceil(2 length) + 1`` points as ``np.linspace(0, 1, n)``
    spaces them, its columns unwrapped across the seam (``np.unwrap``, period ``width``) and
    differentiated (``np.gradient``) within the segment alone: the same operations as one
    segment at a time, so the same numbers (tested against that loop; the same line images
    on 360 generated panoramas). Why: the loop was about 170 segments of Python a
    panorama, held the GIL, and took a 1024 x 512 panorama's line image 19.5 ms against
    12.6 now."""
    n = np.array([int(math.ceil(2.0 * math.hypot(x1 - x0, y1 - y0))) + 1 for x0, y0, x1, y1 in segs], np.int64)
    ends = np.cumsum(n)
    starts = ends - n
    total = int(ends[-1])
    seg = np.repeat(np.arange(len(n)), n)
    k = (np.arange(total) - starts[seg]).astype(np.float64)
    # np.linspace(0, 1, n): k * (1 / (n - 1)) + 0, its last sample exactly 1 (one sample: 0)
    step = 1.0 / np.maximum(n - 1, 1)
    t = k * step[seg] + 0.0
    t[ends[n > 1] - 1] = 1.0
    x0, y0, x1, y1 = (segs[seg, i] for i in range(4))
    az, el = _face_rays(x0 + t * (x1 - x0), y0 + t * (y1 - y0), cam, heading_deg, pitch_deg)
    inside = None if coverage == WHOLE else _covered(az, el, coverage)
    if rotation is not None:
        az, el = _turned(az, el, rotation)
    fu = ((math.pi - az) / (2 * math.pi) % 1.0) * width
    fv = (math.pi / 2 - el) / math.pi * height
    u = np.floor(fu).astype(np.int64) % width
    v = np.clip(np.floor(fv).astype(np.int64), 0, height - 1)
    # np.unwrap(fu, period=width) within each segment: its steps' corrections, summed from
    # the segment's start (only the few segments that cross the seam have any)
    dd = np.diff(fu)
    low, high = -width / 2.0, width / 2.0
    ddmod = np.mod(dd - low, width) + low
    ddmod[(ddmod == low) & (dd > 0)] = high
    correct = ddmod - dd
    correct[np.abs(dd) < high] = 0.0
    correct[starts[1:] - 1] = 0.0                 # from one segment's last sample to the next's first
    unwrapped = fu.copy()
    for j in np.unique(seg[1:][correct != 0.0]):
        a, b = starts[j], ends[j]
        unwrapped[a + 1:b] = fu[a + 1:b] + np.cumsum(correct[a:b - 1])
    du, dv = _segment_gradient(unwrapped, starts, ends), _segment_gradient(fv, starts, ends)
    if inside is not None:
        return v[inside], u[inside], du[inside], dv[inside], seg[inside]
    return v, u, du, dv, seg


def _segment_gradient(f: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """np.gradient of each segment's samples (unit spacing, edge order 1; 0 for one sample)."""
    out = np.empty_like(f)
    if len(f) > 2:
        out[1:-1] = (f[2:] - f[:-2]) / 2.0
    one = ends - starts == 1
    many = ~one
    a, b = starts[many], ends[many]
    out[a] = (f[a + 1] - f[a]) / 1.0
    out[b - 1] = (f[b - 1] - f[b - 2]) / 1.0
    out[starts[one]] = 0.0
    return out


def panorama_line_image(pano: np.ndarray, *, width: int, height: int, face_px: int, min_length: float,
                        split: bool = False, orientation_bins: int = 0) -> np.ndarray:
    """Binary equirectangular line image (``height`` x ``width``) of a grey panorama's LSD
    lines (see :func:`panorama_lines`; drawn by :func:`draw_line_image`, which says what
    ``split`` and ``orientation_bins`` give)."""
    return draw_line_image(panorama_lines(pano, face_px=face_px, min_length=min_length), face_px=face_px, width=width,
                           height=height, split=split, orientation_bins=orientation_bins)


def draw_line_image(faces: list[np.ndarray], *, face_px: int, width: int, height: int, split: bool = False,
                    orientation_bins: int = 0, rotation: np.ndarray | None = None,
                    coverage: Coverage = WHOLE) -> np.ndarray:
    """Binary equirectangular line image (``height`` x ``width``) of the cube faces' LSD
    segments ``faces`` (:func:`panorama_lines`). ``split``: a (2, H, W) pair instead, the
    lines that are vertical in the world (vertical on an upright face, through the
    nadir/zenith on the floor/ceiling faces) and the rest. ``orientation_bins`` >= 1: a
    uint8 image whose pixels hold the bitmask of the :func:`orientation_bit` s of the lines
    through them, each sample's direction the equirectangular curve's tangent there (central
    differences along the segment's samples), as :func:`render_panoramas` gives the map's.
    ``rotation``: every sample's direction turned by it first (:func:`upright_rotation`), so
    that a tilted panorama's lines are drawn where an upright camera would have seen them.
    ``coverage``: the part a cropped photo covers (:func:`whole_panorama`); nothing is drawn
    outside it."""
    cam = Camera(face_px, face_px, 90.0)
    bins = int(orientation_bins)
    img = np.zeros((2 if split else 1, height, width), np.uint8)
    for (hd, pitch), segs in zip(CUBE_FACES, faces):
        if not len(segs):
            continue
        v, u, du, dv, seg = face_samples(segs, cam, hd, pitch, width, height, rotation, coverage)
        if split:
            vertical = np.array([_world_vertical(s, pitch, face_px) for s in segs], bool)
            img[np.where(vertical[seg], 0, 1), v, u] = 1
        elif bins >= 1:
            np.bitwise_or.at(img[0], (v, u), orientation_bits(du, dv, bins))
        else:
            img[0, v, u] = 1
    return img if split else img[0]
