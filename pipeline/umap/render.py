"""Render binary line images of a wireframe from many poses, straight into packed bits.

One numba kernel per block of poses: each segment is moved into camera coordinates,
clipped at the near plane, projected, clipped to the image (Liang-Barsky), and walked one
pixel at a time. With hidden-line removal each pixel's 3-D point (perspective-correct) is
tested against the vertical wall faces: hidden when the plan ray camera -> point crosses a
face strictly before the point at a height inside that face. Geometry conventions are
those of :mod:`placeloc.geometry`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange
from placeloc.geometry import Camera
from placeloc.geometry.bitimage import n_words, pack_into
from placeloc.geometry.rays import occluded


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
            ax = segs[s, 0] - px
            ay = segs[s, 1] - py
            az = segs[s, 2] - pz
            bx = segs[s, 3] - px
            by = segs[s, 4] - py
            bz = segs[s, 5] - pz
            za = ax * fx + ay * fy
            zb = bx * fx + by * fy
            if za < near and zb < near:
                continue
            # near-plane clip in 3-D (world offsets), keeping the visible part
            if za < near:
                t = (near - za) / (zb - za)
                ax += t * (bx - ax)
                ay += t * (by - ay)
                az += t * (bz - az)
                za = near
            elif zb < near:
                t = (near - zb) / (za - zb)
                bx += t * (ax - bx)
                by += t * (ay - by)
                bz += t * (az - bz)
                zb = near
            ua = cx + focal * (ax * rx + ay * ry) / za
            va = cy - focal * az / za
            ub = cx + focal * (bx * rx + by * ry) / zb
            vb = cy - focal * bz / zb
            # Liang-Barsky clip of the 2-D segment to the pixel area
            du = ub - ua
            dv = vb - va
            s0 = 0.0
            s1 = 1.0
            ok = True
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
                        ok = False
                        break
                else:
                    r = q / p
                    if p < 0.0:
                        if r > s1:
                            ok = False
                            break
                        if r > s0:
                            s0 = r
                    else:
                        if r < s0:
                            ok = False
                            break
                        if r < s1:
                            s1 = r
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


def render_block(item: tuple) -> np.ndarray:
    """Executor work item: (segments, faces, poses, (W, H, hfov), near, hidden) -> packed block."""
    segments, faces, poses, cam, near, hidden = item
    return render_packed(segments, faces, poses, Camera(*cam), near, hidden)
