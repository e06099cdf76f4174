"""Synthetic omnidirectional (equirectangular) video of a textured building, with poses.

``generate(out_dir, seed, frames=..., ...)`` renders two runs over the same building:

- ``mapping/``: the camera walks a closed loop through rooms and corridors at ``step``
  metres per frame; more frames than one lap revisit places (loop closures).
- ``test/``: an unseen run over the same loop, offset sideways by ``test_offset`` metres,
  walked in the opposite direction, under different lighting and with other movers.

Each run writes ``frame_00000.png`` ... (8-bit grey, ``width`` x ``width/2``) and
``poses.csv`` (``frame,x,y,heading``; metres, radians).

Rendering is vectorised ray casting: per image column a 2-D DDA walk through an
occupancy grid (cell ``cell`` m) finds the wall; per pixel the elevation decides wall,
floor or ceiling, and textures are looked up in a bank of procedural panels (posters,
shapes, noise, and a few repeated brick/tile panels so that some places look alike).
Moving people are vertical cylinders; lighting differs per run (gain, gamma, a smooth
spatial illumination field) and every frame gets sensor noise. Optionally
(``seam_ghost``) the frames carry the ghosting of a two-lens camera's stitching seams.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

WALL_H = 3.0      # ceiling height, m
CAM_H = 1.5       # camera height, m
TEX_PX_PER_M = 40  # texture resolution
PANEL_W = 1.5     # wall panel width, m: one texture per panel


def _layout(kind: str) -> tuple[list[tuple[float, float, float, float]], list[tuple[float, float]]]:
    """Free-space rectangles (x0, y0, x1, y1) and the closed loop's waypoints."""
    if kind == "small":
        # One 8 x 6 m room with a pillar block in the middle: a 16 m loop around it.
        rects = [(0, 0, 8, 6)]
        loop = [(1.5, 1.5), (6.5, 1.5), (6.5, 4.5), (1.5, 4.5)]
        return rects, loop
    if kind == "building":
        # Four rooms on the corners of a square, joined by corridors into a ring, plus
        # a long corridor wing: a loop of about 150 m.
        rects = [(0, 0, 10, 8), (30, 0, 40, 8), (30, 26, 40, 34), (0, 26, 10, 34),
                 (10, 3, 30, 5.5), (34, 8, 36.5, 26), (10, 28.5, 30, 31), (3.5, 8, 6, 26),
                 (14, 5.5, 16.5, 16), (14, 16, 26, 22), (23.5, 22, 26, 28.5)]
        loop = [(2, 2), (8, 4.2), (32, 4.2), (35.2, 6), (35.2, 28), (38, 32), (32, 30), (24.7, 29.7),
                (24.7, 19), (15.2, 19), (15.2, 6), (12, 4.2), (8, 4.2), (4.7, 6), (4.7, 28), (2, 32),
                (8, 29.7), (24.7, 29.7), (24.7, 19), (15.2, 19), (15.2, 6), (8, 4.2)]
        return rects, loop
    raise ValueError(f"layout {kind!r} is not known; choose small or building")


def loop_length(layout: str) -> float:
    """Length (m) of one lap of ``layout``'s closed loop."""
    pts = np.array(_layout(layout)[1], float)
    return float(np.linalg.norm(np.roll(pts, -1, 0) - pts, axis=1).sum())


def _grid(rects: list, cell: float, pillar: bool) -> tuple[np.ndarray, float]:
    xs = [r[2] for r in rects] + [r[3] for r in rects]
    size = int(math.ceil((max(xs) + 2) / cell))
    occ = np.ones((size, size), bool)  # occ[ix, iy]; the world starts at -1 m
    for x0, y0, x1, y1 in rects:
        occ[int(round((x0 + 1) / cell)):int(round((x1 + 1) / cell)), int(round((y0 + 1) / cell)):int(round((y1 + 1) / cell))] = False
    if pillar:  # the small room's central block, so the loop goes around something
        occ[int(round(3.2 / cell)):int(round(6.8 / cell)), int(round(3.2 / cell)):int(round(4.8 / cell))] = True
    return occ, -1.0


def _texture_bank(rng: np.random.Generator, n: int, h: int, w: int) -> np.ndarray:
    """Procedural grey panels; the first three are repetitive (bricks, tiles, stripes)."""
    bank = np.empty((n, h, w), np.float32)
    yy, xx = np.mgrid[0:h, 0:w]
    for k in range(n):
        if k == 0:  # bricks
            img = 150 + 20 * (((yy // 10) % 2 == 0) & ((xx + 12 * ((yy // 10) % 2)) % 24 < 22))
            img = img - 60 * (yy % 10 == 0)
        elif k == 1:  # tiles
            img = 170 - 80 * ((yy % 20 < 2) | (xx % 20 < 2))
        elif k == 2:  # stripes
            img = 120 + 60 * np.sin(xx / 3.0)
        else:
            img = rng.uniform(60, 200) + cv2.resize(rng.normal(0, 25, (h // 8 + 1, w // 8 + 1)).astype(np.float32), (w, h))
            img = np.asarray(img, np.float32)
            for _ in range(rng.integers(4, 10)):  # posters, shapes, blobs
                c = float(rng.uniform(0, 255))
                x0, y0 = int(rng.integers(0, w - 4)), int(rng.integers(0, h - 4))
                kind = rng.integers(0, 3)
                if kind == 0:
                    cv2.rectangle(img, (x0, y0), (x0 + int(rng.integers(4, w // 2)), y0 + int(rng.integers(4, h // 3))), c, -1)
                elif kind == 1:
                    cv2.circle(img, (x0, y0), int(rng.integers(3, w // 4)), c, -1)
                else:
                    pts = rng.integers(0, [w, h], (int(rng.integers(3, 6)), 2)).astype(np.int32)
                    cv2.fillPoly(img, [pts], c)
        bank[k] = cv2.GaussianBlur(np.asarray(img, np.float32), (0, 0), 0.8)
    return bank


class OmniWorld:
    """A building (occupancy grid + textures + movers) that renders equirectangular frames."""

    def __init__(self, layout: str = "building", seed: int = 0, cell: float = 0.25, n_textures: int = 48, movers: int = 6) -> None:
        self.rng = np.random.default_rng(seed)
        self.rects, self.loop = _layout(layout)
        self.cell = cell
        self.occ, self.origin = _grid(self.rects, cell, pillar=(layout == "small"))
        th, tw = int(WALL_H * TEX_PX_PER_M), int(PANEL_W * TEX_PX_PER_M)
        self.bank = _texture_bank(self.rng, n_textures, th, tw)
        # Panel -> texture: a hash of the panel's wall line and index; 25 % repetitive ones.
        self.panel_salt = int(self.rng.integers(1, 1 << 30))
        size = self.occ.shape[0] * cell
        fpx = int(size * 20)
        floor = cv2.resize(self.rng.normal(0, 18, (fpx // 6, fpx // 6)).astype(np.float32), (fpx, fpx)) + 110
        yy, xx = np.mgrid[0:fpx, 0:fpx]
        floor -= 50 * ((yy % 20 < 2) | (xx % 20 < 2))  # 1 m floor tiles
        self.floor = cv2.GaussianBlur(floor.astype(np.float32), (0, 0), 0.8)
        ceil = np.full((fpx, fpx), 200, np.float32) + 40 * (((yy // 40) % 3 == 0) & ((xx // 40) % 3 == 0))
        self.ceil = cv2.GaussianBlur(ceil, (0, 0), 1.0)
        self.n_movers = movers

    # -- geometry ---------------------------------------------------------------------
    def cast(self, px: float, py: float, ang: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """2-D DDA per ray: (distance, side 0/1 for x/y face, texture index)."""
        c = self.cell
        gx, gy = (px - self.origin) / c, (py - self.origin) / c
        dx, dy = np.cos(ang), np.sin(ang)
        ix = np.full(ang.shape, int(gx))
        iy = np.full(ang.shape, int(gy))
        with np.errstate(divide="ignore"):
            ddx = np.where(dx != 0, np.abs(1 / dx), np.inf)
            ddy = np.where(dy != 0, np.abs(1 / dy), np.inf)
        sx = np.where(dx < 0, -1, 1)
        sy = np.where(dy < 0, -1, 1)
        tx = np.where(dx < 0, (gx - ix) * ddx, (ix + 1 - gx) * ddx)
        ty = np.where(dy < 0, (gy - iy) * ddy, (iy + 1 - gy) * ddy)
        dist = np.zeros(ang.shape)
        side = np.zeros(ang.shape, np.int64)
        active = np.ones(ang.shape, bool)
        n = self.occ.shape[0]
        for _ in range(4 * n):
            if not active.any():
                break
            xstep = active & (tx < ty)
            ystep = active & ~(tx < ty)
            dist[xstep] = tx[xstep]
            ix[xstep] += sx[xstep]
            tx[xstep] += ddx[xstep]
            side[xstep] = 0
            dist[ystep] = ty[ystep]
            iy[ystep] += sy[ystep]
            ty[ystep] += ddy[ystep]
            side[ystep] = 1
            np.clip(ix, 0, n - 1, out=ix)
            np.clip(iy, 0, n - 1, out=iy)
            active &= ~self.occ[ix, iy]
        dist = dist * c
        hx, hy = px + dist * dx, py + dist * dy
        u = np.where(side == 0, hy, hx)
        line = np.where(side == 0, ix * 2 + (sx > 0), iy * 2 + (sy > 0))
        panel = np.floor(u / PANEL_W).astype(np.int64)
        h = (line * 73856093) ^ (panel * 19349663) ^ (side * 83492791) ^ self.panel_salt
        h = np.abs(h) % 1000
        nb = len(self.bank)
        tex = np.where(h < 250, h % 3, 3 + h % (nb - 3))
        uu = ((u - panel * PANEL_W) * TEX_PX_PER_M).astype(np.int64).clip(0, self.bank.shape[2] - 1)
        return np.maximum(dist, 1e-3), tex, uu

    def movers_at(self, t: float, run: int) -> np.ndarray:
        """(n, 2) mover positions at time t: people pacing along the loop's segments."""
        rng = np.random.default_rng(1000 + run)
        pos = []
        loop = np.array(self.loop, float)
        for _ in range(self.n_movers):
            i = int(rng.integers(0, len(loop)))
            a, b = loop[i], loop[(i + 1) % len(loop)]
            phase = rng.uniform(0, 2 * np.pi)
            s = 0.5 + 0.5 * np.sin(0.05 * t + phase)  # walking back and forth
            off = rng.normal(0, 0.6, 2)
            pos.append(a + s * (b - a) + off)
        return np.array(pos)

    def render(self, x: float, y: float, heading: float, width: int, lighting: dict[str, float], movers: np.ndarray,
               rng: np.random.Generator) -> np.ndarray:
        h = width // 2
        az = heading + np.pi - (np.arange(width) + 0.5) / width * 2 * np.pi  # left to right = decreasing azimuth
        el = np.pi / 2 - (np.arange(h) + 0.5) / h * np.pi
        dist, tex, uu = self.cast(x, y, az)
        tan_el = np.tan(el)[:, None]
        z = CAM_H + dist[None, :] * tan_el
        img = np.empty((h, width), np.float32)
        wall = (z >= 0) & (z <= WALL_H)
        zi = ((WALL_H - z) * TEX_PX_PER_M).astype(np.int64).clip(0, self.bank.shape[1] - 1)
        texb = np.broadcast_to(tex[None, :], z.shape)
        ub = np.broadcast_to(uu[None, :], z.shape)
        img[wall] = self.bank[texb[wall], zi[wall], ub[wall]]
        # Floor and ceiling: intersect with the planes z = 0 and z = WALL_H.
        dx, dy = np.cos(az)[None, :], np.sin(az)[None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(tan_el < 0, CAM_H / -tan_el, (WALL_H - CAM_H) / tan_el)
        r = np.broadcast_to(r, z.shape)
        wx = ((x + r * dx - self.origin) * 20).astype(np.int64).clip(0, self.floor.shape[0] - 1)
        wy = ((y + r * dy - self.origin) * 20).astype(np.int64).clip(0, self.floor.shape[1] - 1)
        fl = ~wall & (z < 0)
        ce = ~wall & (z > WALL_H)
        img[fl] = self.floor[wx[fl], wy[fl]]
        img[ce] = self.ceil[wx[ce], wy[ce]]
        depth = np.where(wall, dist[None, :] / np.maximum(np.cos(el)[:, None], 1e-3), r)
        # Movers: vertical cylinders r = 0.3 m, 1.7 m tall, striped clothes.
        for k, (mx, my) in enumerate(movers):
            ox, oy = mx - x, my - y
            along = ox * np.cos(az) + oy * np.sin(az)
            perp2 = ox * ox + oy * oy - along ** 2
            hit = (perp2 < 0.09) & (along > 0.3)
            if not hit.any():
                continue
            d = along - np.sqrt(np.maximum(0.09 - perp2, 0))
            zc = CAM_H + d[None, :] * tan_el
            m = hit[None, :] & (zc >= 0) & (zc <= 1.7) & (d[None, :] < dist[None, :])
            shade = 60 + 120 * ((np.floor(zc * 6) + k) % 2)
            img[m] = np.broadcast_to(shade, m.shape)[m]
            depth[m] = np.broadcast_to(d[None, :], m.shape)[m]
        # Lighting: a smooth spatial field (per run), gain/gamma, distance falloff, noise.
        field = 1 + lighting["field"] * np.sin(0.37 * x + lighting["phase"]) * np.cos(0.29 * y - lighting["phase"])
        img = img * lighting["gain"] * field / (1 + 0.02 * np.clip(depth, 0, 30))
        img = 255 * (np.clip(img, 0, 255) / 255) ** lighting["gamma"]
        img += rng.normal(0, lighting["noise"], img.shape)
        return np.clip(img, 0, 255).astype(np.uint8)


def speed_profile(frames: int, dwell: int = 0, dwell_every: int = 50, slow: float = 1.0, slow_frames: int = 0) -> np.ndarray:
    """Fraction of the walking step taken on arriving at each frame (frame 0's entry is unused).

    The pattern repeats: ``dwell_every`` frames of walking, then ``slow_frames`` frames at
    ``slow`` times the walking speed, then ``dwell`` frames standing still. With neither
    slow motion nor dwelling every entry is 1."""
    if not 0 < slow <= 1:
        raise ValueError(f"slow must lie in (0, 1] (a fraction of the walking speed), got {slow}")
    if dwell < 0 or slow_frames < 0 or dwell_every < 1:
        raise ValueError(f"need dwell >= 0, slow_frames >= 0 and dwell_every >= 1, got {dwell}, {slow_frames}, {dwell_every}")
    moving = np.ones(frames)
    if slow < 1 and slow_frames > 0:
        phase = np.arange(frames) % (dwell_every + slow_frames + dwell)
        moving[(phase >= dwell_every) & (phase < dwell_every + slow_frames)] = slow
        moving[phase >= dwell_every + slow_frames] = 0.0
    elif dwell > 0:  # written as before slow motion existed, so dwell-only paths stay bit-identical
        moving = ((np.arange(frames) % (dwell_every + dwell)) < dwell_every).astype(float)
    return moving


def loop_path(loop: list[tuple[float, float]], frames: int, step: float, offset: float = 0.0, reverse: bool = False,
              start: float = 0.0, jitter: float = 0.0, rng: np.random.Generator | None = None, dwell: int = 0,
              dwell_every: int = 50, slow: float = 1.0, slow_frames: int = 0, lap_offset: float = 0.0,
              lap_ramp: float = 5.0) -> np.ndarray:
    """(frames, 3) poses (x, y, heading) walking the closed polyline at ``step`` m per frame.

    ``dwell``: after every ``dwell_every`` frames of walking the camera stands still for
    ``dwell`` frames (a person stopping, as a hand-held or robot video does), so those
    frames see one place again and again. ``slow``/``slow_frames``: after every
    ``dwell_every`` frames of walking, ``slow_frames`` frames at ``slow`` times the walking
    speed (before any dwell); see :func:`speed_profile`.

    ``lap_offset``: revisits at a slightly different place. Lap k >= 1 (the path's k-th
    return past its start) is walked ``lap_offset`` metres to the side of the first lap,
    alternately left (odd k) and right (even k), so no lap retraces an earlier one; the
    sideways shift changes linearly over the first ``lap_ramp`` metres of each lap, so the
    camera drifts across instead of jumping."""
    pts = np.array(loop[::-1] if reverse else loop, float)
    seg = np.roll(pts, -1, axis=0) - pts
    seglen = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0], np.cumsum(seglen)])
    total = cum[-1]
    moving = speed_profile(frames, dwell, dwell_every, slow, slow_frames)
    walked = start * total + step * np.concatenate([[0.0], np.cumsum(moving[1:])])
    s = walked % total
    i = np.searchsorted(cum, s, side="right") - 1
    frac = (s - cum[i]) / seglen[i]
    xy = pts[i] + frac[:, None] * seg[i]
    d = seg[i] / seglen[i][:, None]
    normal = np.stack([-d[:, 1], d[:, 0]], 1)
    xy = xy + offset * normal
    if lap_offset:
        xy = xy + lap_shift(walked, total, lap_offset, lap_ramp)[:, None] * normal
    if jitter and rng is not None:
        xy = xy + rng.normal(0, jitter, xy.shape)
    heading = np.arctan2(d[:, 1], d[:, 0])
    return np.column_stack([xy, heading])


def lap_shift(walked: np.ndarray, total: float, lap_offset: float, lap_ramp: float) -> np.ndarray:
    """Sideways shift (m, along the path's left normal) at each arc length ``walked`` (not
    wrapped): 0 on lap 0, +``lap_offset`` on odd laps, -``lap_offset`` on even laps >= 2,
    reached linearly over the first ``lap_ramp`` metres of each lap."""
    if lap_ramp <= 0:
        raise ValueError(f"lap_ramp must be > 0 m, got {lap_ramp}")
    lap = np.floor(walked / total).astype(np.int64)
    target = np.where(lap == 0, 0.0, np.where(lap % 2 == 1, lap_offset, -lap_offset))
    before = np.where(lap <= 1, 0.0, np.where(lap % 2 == 1, -lap_offset, lap_offset))
    ramp = np.clip((walked - lap * total) / lap_ramp, 0.0, 1.0)
    return before + (target - before) * ramp


SEAM_BAND_DEG = 20.0  # overlap of two back-to-back fisheye lenses of about 200 deg each (190 deg gives 10)


def seam_weight(width: int, band_deg: float) -> np.ndarray:
    """Weight of the second lens's (ghost) image in each column of an equirectangular frame.

    A two-lens camera (lenses facing forward and backward) stitches its halves along two
    seams at azimuth heading +-90 deg; in this renderer's frames (column c looks at azimuth
    heading + pi - (c + 0.5) / width * 2 pi) those lie at x = width / 4 (left) and
    3 width / 4 (right), x measured from the frame's left edge in pixels. Around each seam
    both lenses see the scene over a band ``band_deg`` wide, and the camera feathers one
    into the other: here the second lens's weight rises as a raised cosine from 0 at the
    band's edges to 1/2 on the seam, w = sin^2(pi s) / 2 for s in [0, 1] across the band,
    so the frame is untouched outside the bands and the two images count equally on the
    seam. Every other column gets 0."""
    if not 0 < band_deg < 180:
        raise ValueError(f"seam_band must lie in (0, 180) degrees, got {band_deg}")
    x = np.arange(width) + 0.5
    band = band_deg / 360.0 * width
    w = np.zeros(width)
    for centre in (width / 4, 3 * width / 4):
        s = (x - (centre - band / 2)) / band
        inside = (s > 0) & (s < 1)
        w[inside] = 0.5 * np.sin(np.pi * s[inside]) ** 2
    return w


def ghost_seams(img: np.ndarray, shift_px: float, band_deg: float, gain: float = 1.0) -> np.ndarray:
    """Stitching-seam ghosting of an equirectangular uint8 frame.

    In each seam band (see :func:`seam_weight`) the frame is blended with a copy of itself
    moved ``shift_px`` pixels along azimuth (column c of the copy shows column c + shift_px
    of the frame, wrapping around; fractional shifts interpolate linearly) and scaled by
    ``gain`` (the second lens's exposure relative to the first): out = (1 - w) frame +
    w gain copy, rounded. The same structure is then imaged twice, ``shift_px`` apart, as
    parallax and calibration error leave it in real stitched video."""
    w = seam_weight(img.shape[1], band_deg)
    if not shift_px and gain == 1.0:
        return img.copy()
    cols = np.flatnonzero(w)
    f = img.astype(np.float64)
    lo = int(np.floor(shift_px))
    frac = shift_px - lo
    src = (cols + lo) % img.shape[1]
    copy = f[:, src]
    if frac:
        copy = (1 - frac) * copy + frac * f[:, (src + 1) % img.shape[1]]
    out = f.copy()
    out[:, cols] = (1 - w[cols]) * f[:, cols] + w[cols] * gain * copy
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def _render_chunk(args: tuple) -> None:
    """Worker: render frames [lo, hi) of one run (each frame's noise seeded by (seed, run, t))."""
    layout, seed, movers, folder, poses, lo, hi, width, lighting, run, seam = args
    world = OmniWorld(layout, seed, movers=movers)
    for t in range(lo, hi):
        x, y, hd = poses[t]
        rng = np.random.default_rng([seed, run, t])
        img = world.render(float(x), float(y), float(hd), width, lighting, world.movers_at(t, run), rng)
        if seam is not None:  # after the sensor noise: each lens's noisy image is stitched
            img = ghost_seams(img, *seam)
        cv2.imwrite(str(Path(folder) / f"frame_{t:05d}.png"), img)


def _write_run(layout: str, seed: int, movers: int, folder: Path, poses: np.ndarray, width: int, lighting: dict[str, float],
               run: int, workers: int, seam: tuple[float, float, float] | None = None) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    n = len(poses)
    step = max(1, -(-n // (4 * workers)))
    chunks = [(layout, seed, movers, str(folder), poses, lo, min(n, lo + step), width, lighting, run, seam)
              for lo in range(0, n, step)]
    if workers > 1 and len(chunks) > 1:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as pool:
            list(pool.map(_render_chunk, chunks))
    else:
        for c in chunks:
            _render_chunk(c)
    with open(folder / "poses.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "x", "y", "heading"])
        for t, (x, y, hd) in enumerate(poses):
            w.writerow([t, f"{x:.4f}", f"{y:.4f}", f"{hd:.5f}"])


def generate(out_dir: Path, seed: int = 0, frames: int = 40, test_frames: int | None = None, width: int = 480,
             layout: str = "building", step: float = 0.2, test_offset: float = 0.3, movers: int = 6, workers: int = 1,
             dwell: int = 0, slow: float = 1.0, slow_frames: int = 50, revisit_offset: float = 0.0,
             seam_ghost: float = 0.0, seam_band: float = SEAM_BAND_DEG, seam_gain: float = 1.0,
             **extra: Any) -> dict[str, Any]:
    """Render a mapping run and an unseen test run; return a summary (paths, sizes, loop length).

    Properties of real video the mapping run can be given (the test run keeps walking):

    - ``dwell`` > 0: the camera stands still for that many frames after every 50 frames of
      walking;
    - ``slow`` < 1: slow motion: after every 50 frames of walking, ``slow_frames`` frames at
      ``slow`` times the walking speed (``step``);
    - ``revisit_offset`` > 0: revisits at a slightly different place: every lap after the
      first is walked that many metres to the side (alternating sides).

    See :func:`loop_path`. A property of the camera, given to both runs:

    - ``seam_ghost`` > 0 (pixels) or ``seam_gain`` != 1: the stitching seams of a two-lens
      camera: in a band ``seam_band`` degrees wide around azimuth heading +-90 deg the frame
      is blended with a copy moved ``seam_ghost`` pixels along azimuth and scaled by
      ``seam_gain`` (see :func:`ghost_seams`).

    With the defaults the output is what it was before these options existed."""
    if extra:
        known = ("frames, test_frames, width, layout, step, test_offset, movers, workers, dwell, slow, slow_frames, revisit_offset, "
                 "seam_ghost, seam_band, seam_gain")
        raise TypeError(f"unknown omni parameter(s): {', '.join(extra)}; known: {known}")
    if width < 64 or width % 2:
        raise ValueError(f"width must be an even number >= 64 (height is width/2), got {width}")
    if frames < 2:
        raise ValueError(f"frames must be >= 2, got {frames}")
    out_dir = Path(out_dir)
    test_frames = frames if test_frames is None else test_frames
    world = OmniWorld(layout, seed, movers=movers)
    rng = np.random.default_rng(seed)
    if not 0 <= revisit_offset <= 0.6:
        raise ValueError(f"revisit_offset must lie in [0, 0.6] m (the corridors leave about 0.7 m beside the path), got {revisit_offset}")
    if not 0 <= seam_ghost <= width / 8:
        raise ValueError(f"seam_ghost must lie in [0, width/8 = {width / 8:g}] pixels (a shift along azimuth), got {seam_ghost}")
    if not 0.5 <= seam_gain <= 2:
        raise ValueError(f"seam_gain must lie in [0.5, 2] (the second lens's exposure relative to the first), got {seam_gain}")
    seam_weight(width, seam_band)  # checks the band
    seam = (float(seam_ghost), float(seam_band), float(seam_gain)) if seam_ghost or seam_gain != 1.0 else None
    mapping = loop_path(world.loop, frames, step, jitter=0.02, rng=rng, dwell=dwell, slow=slow, slow_frames=slow_frames,
                        lap_offset=revisit_offset)
    test = loop_path(world.loop, test_frames, step, offset=test_offset, reverse=True, start=0.37, jitter=0.02, rng=rng)
    light_map = {"gain": 1.0, "gamma": 1.0, "field": 0.15, "phase": 0.0, "noise": 2.0}
    light_test = {"gain": 0.85, "gamma": 1.15, "field": 0.25, "phase": 1.3, "noise": 3.0}
    _write_run(layout, seed, movers, out_dir / "mapping", mapping, width, light_map, 0, workers, seam)
    _write_run(layout, seed, movers, out_dir / "test", test, width, light_test, 1, workers, seam)
    length = loop_length(layout)
    walked = step * float(speed_profile(frames, dwell, slow=slow, slow_frames=slow_frames).sum())  # slow motion and dwelling walk less
    return {"mapping": str(out_dir / "mapping"), "test": str(out_dir / "test"), "frames": frames, "test_frames": test_frames,
            "size": f"{width}x{width // 2}", "loop_length_m": round(length, 1), "laps": round(walked / length, 2)}
