"""Plan (2-D) ray casting: the one ray/segment intersection kernel and what is built on it.

:func:`ray_segment` is a numba function callable from Python and from other numba kernels
(the database renderer's hidden-line test, the synthetic-building ray caster). Callers
apply their own acceptance window on the two parameters it returns, because they need
different ones (a laser accepts any hit in front, a hidden-line test only hits strictly
between the camera and the point).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(inline="always", cache=True)
def ray_segment(px: float, py: float, dx: float, dy: float, ax: float, ay: float, bx: float,
                by: float) -> tuple[float, float]:
    """Intersection of the ray p + t d with the segment a + u (b - a).

    Returns ``(t, u)``: the ray parameter (distance in units of |d|) and the segment
    parameter (in [0, 1] when the hit lies on the segment). A ray parallel to the segment
    returns ``(inf, -1)``, which no caller accepts."""
    ex = bx - ax
    ey = by - ay
    den = dx * ey - dy * ex
    if abs(den) < 1e-12:
        return math.inf, -1.0
    wx = ax - px
    wy = ay - py
    t = (wx * ey - wy * ex) / den
    u = (wx * dy - wy * dx) / den
    return t, u


@njit(inline="always", cache=True)
def ray_box(px: float, py: float, pz: float, dx: float, dy: float, dz: float, box: np.ndarray, t_max: float) -> float:
    """Slab test of the ray p + t d against an axis-aligned box (x0, y0, z0, x1, y1, z1):
    the entry parameter t in [0, t_max], or -1.0 when the ray misses it within that span."""
    t0 = 0.0
    t1 = t_max
    for a in range(3):
        o = px if a == 0 else (py if a == 1 else pz)
        d = dx if a == 0 else (dy if a == 1 else dz)
        lo = box[a]
        hi = box[a + 3]
        if abs(d) < 1e-12:
            if o < lo or o > hi:
                return -1.0
        else:
            ta = (lo - o) / d
            tb = (hi - o) / d
            if ta > tb:
                ta, tb = tb, ta
            t0 = max(t0, ta)
            t1 = min(t1, tb)
            if t0 > t1:
                return -1.0
    return t0


@njit(cache=True)
def occluded(px: float, py: float, pz: float, qx: float, qy: float, qz: float, faces: np.ndarray, candidates: np.ndarray,
             n_candidates: int) -> bool:
    """Hidden-line test: True when a vertical wall face hides 3-D point q from p.

    ``faces`` rows are (ax, ay, bx, by, z_low, z_high); only the first ``n_candidates``
    indices in ``candidates`` are tested. q is hidden when the plan ray p -> q crosses a face
    strictly before q at a height inside that face.
    """
    dx = qx - px
    dy = qy - py
    length = math.sqrt(dx * dx + dy * dy)
    if length < 1e-9:
        return False
    # The point's own wall (and walls meeting at it) cross at t ~ 1: keep 5 mm clear.
    tmax = 1.0 - 0.005 / length
    for k in range(n_candidates):
        f = candidates[k]
        t, u = ray_segment(px, py, dx, dy, faces[f, 0], faces[f, 1], faces[f, 2], faces[f, 3])
        if t <= 1e-9 or t >= tmax or u < 0.0 or u > 1.0:
            continue
        z = pz + t * (qz - pz)
        if faces[f, 4] <= z <= faces[f, 5]:
            return True
    return False


# Faces whose distance bound (:func:`face_terms`) stops a scan of :func:`occluded_terms`: the
# camera at least FAR_LINE_M from the face's line and the face within FAR_REACH_M of it.
# Under those bounds the rounding of the crossing's parameters moves the crossing by less
# than 1e-6 m (relative errors of a few 1e-16 scaled by |w| L / h <= 1e3 * 1e3 / 1e-3 m), far
# inside the 5 mm by which a hit must come before the point.
FAR_LINE_M = 1e-3
FAR_REACH_M = 1e3


@njit(cache=True)
def face_terms(px: float, py: float, faces: np.ndarray, out: np.ndarray) -> None:
    """The quantities of :func:`ray_segment` that depend on the ray's origin (px, py) and a
    face but not on the ray's direction, for every face: ``out[f]`` = (ex, ey, wx, wy, tn,
    near), the face's direction, the vector origin -> its first end and the crossing
    parameter's numerator, each computed by the same operations as there (so the same
    doubles), and ``near``: the square of a lower bound on the plan distance from the origin
    to the face (1 um under it), or -1 for a face too near the origin's line or too far for
    the bound to be used (see FAR_LINE_M)."""
    for f in range(faces.shape[0]):
        ex = faces[f, 2] - faces[f, 0]
        ey = faces[f, 3] - faces[f, 1]
        wx = faces[f, 0] - px
        wy = faces[f, 1] - py
        tn = wx * ey - wy * ex
        out[f, 0] = ex
        out[f, 1] = ey
        out[f, 2] = wx
        out[f, 3] = wy
        out[f, 4] = tn
        le = math.sqrt(ex * ex + ey * ey)
        lw = math.sqrt(wx * wx + wy * wy)
        near = -1.0
        if le > 0.0 and abs(tn) >= FAR_LINE_M * le and lw + le <= FAR_REACH_M:
            s = min(max(-(wx * ex + wy * ey) / (le * le), 0.0), 1.0)
            cx = wx + s * ex
            cy = wy + s * ey
            near = max(math.sqrt(cx * cx + cy * cy) - 1e-6, 0.0) ** 2
        out[f, 5] = near


@njit(cache=True, inline="always")  # called per sample: a call costs more than the test (20 us a render)
def occluded_terms(px: float, py: float, pz: float, qx: float, qy: float, qz: float, faces: np.ndarray,
                   terms: np.ndarray, candidates: np.ndarray, n_candidates: int) -> bool:
    """:func:`occluded` with the origin's face quantities computed once (``terms``: see
    :func:`face_terms` for this p), the same answer for every input: each face is tested
    with the same doubles, a face whose crossing parameter has the wrong sign is passed over
    before the division (which there gives t <= 0 and a rejection), and with the candidates
    in ascending order of their distance bound (``terms[:, 5]``, squared; -1 first) the scan
    stops at the first face at least as far as the point: a hit lies on the face 5 mm before
    the point, so nearer than it (by more than the rounding: see FAR_LINE_M), and no face
    after that one is nearer. The ray's length (a square root and a division) is taken only
    when a face gets past the sign test."""
    dx = qx - px
    dy = qy - py
    len2 = dx * dx + dy * dy
    reach2 = len2 if len2 <= FAR_REACH_M * FAR_REACH_M else math.inf
    tmax = 0.0
    have_tmax = False
    for k in range(n_candidates):
        f = candidates[k]
        if terms[f, 5] >= reach2:
            break
        ex = terms[f, 0]
        ey = terms[f, 1]
        den = dx * ey - dy * ex
        if abs(den) < 1e-12:
            continue
        tn = terms[f, 4]
        # t = tn / den: a quotient of operands of opposite signs (or a zero numerator) is
        # negative or zero after rounding too, so t <= 1e-9 rejects it there
        if tn == 0.0 or (tn < 0.0) != (den < 0.0):
            continue
        if not have_tmax:
            length = math.sqrt(len2)
            if length < 1e-9:   # (occluded returns False before any face)
                return False
            tmax = 1.0 - 0.005 / length
            have_tmax = True
        t = tn / den
        if t <= 1e-9 or t >= tmax:
            continue
        u = (terms[f, 2] * dy - terms[f, 3] * dx) / den
        if u < 0.0 or u > 1.0:
            continue
        z = pz + t * (qz - pz)
        if faces[f, 4] <= z <= faces[f, 5]:
            return True
    return False


@njit(cache=True)
def _first_hits(xy: np.ndarray, dx: float, dy: float, walls: np.ndarray, out: np.ndarray) -> None:
    for i in range(xy.shape[0]):
        best = math.inf
        for w in range(walls.shape[0]):
            t, u = ray_segment(xy[i, 0], xy[i, 1], dx, dy, walls[w, 0], walls[w, 1], walls[w, 2], walls[w, 3])
            if t > 1e-9 and 0.0 <= u <= 1.0 and t < best:
                best = t
        out[i] = best


def ray_ranges(xy: np.ndarray, angle_deg: float, walls: np.ndarray) -> np.ndarray:
    """Distance from each plan point along ``angle_deg`` (counter-clockwise from +x) to the
    first wall (``walls`` (F, >=4) rows x0 y0 x1 y1 ...); inf where no wall is hit. This is
    what a laser range finder in the plane measures."""
    h = math.radians(angle_deg)
    pts = np.ascontiguousarray(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
    w = np.ascontiguousarray(np.asarray(walls, dtype=np.float64).reshape(len(walls), -1)[:, :4])
    out = np.full(len(pts), np.inf)
    if len(pts) and len(w):
        _first_hits(pts, math.cos(h), math.sin(h), w, out)
    return out


def ray_range(x: float, y: float, angle_deg: float, walls: np.ndarray) -> float:
    """:func:`ray_ranges` for one point."""
    return float(ray_ranges(np.array([[x, y]]), angle_deg, walls)[0])
