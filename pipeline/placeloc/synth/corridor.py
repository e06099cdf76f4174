"""Synthetic building for UMap (``placeloc synth corridor OUT``).

A ~90 m corridor storey like the paper's O building 5F: point-symmetric about its centre
(doors and side alcoves repeat under a 180 deg turn, so a view at (x, y, h) has a twin at
(90 - x, 2.4 - y, h + 180)), broken only by a junction (cross corridor) at the centre.
Written under OUT:

- ``floor_plan.yaml`` (walls, doors) and ``wireframe.yaml`` (segments + wall faces built from it)
- ``images/frame_000.png ...``: a sensor sequence along the corridor with random steps of
  0.1-2.0 m, ray-cast with textured walls, tiled floor, ceiling lights, posters and
  furniture that are NOT in the wireframe, sensor noise and blur
- ``sensor.csv`` (frame, d laser distance to the side wall with noise, theta camera angle
  to the wall normal) and ``poses.csv`` (ground truth frame, x, y, z, heading_deg)
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml
from numba import njit, prange

from placeloc.geometry import Camera
from placeloc.geometry.floorplan import floor_plan_model
from placeloc.geometry.rays import ray_box, ray_range, ray_segment
from placeloc.synth.texture import value_noise

LENGTH = 90.0
WIDTH = 2.4
CEILING = 2.6


def building(length: float = LENGTH, width: float = WIDTH) -> dict[str, Any]:
    """The floor plan (a dict in the floor-plan YAML format of :mod:`placeloc.geometry.floorplan`)."""
    c = length / 2
    # Alcoves (side openings) on the y = 0 side; their 180 deg twins go on the y = width side.
    alcoves = [(9.0, 2.0, 1.4), (23.0, 1.6, 1.0), (36.0, 2.4, 1.4)]
    bottom = [[0.0, 0.0]]
    for x0, w, depth in alcoves:
        bottom += [[x0, 0.0], [x0, -depth], [x0 + w, -depth], [x0 + w, 0.0]]
    bottom.append([length, 0.0])
    top = [[length - x, width - y] for x, y in bottom]      # 180 deg twin, same order
    # junction: a cross corridor towards +y at the centre (breaks the symmetry)
    jw = 2.4
    top_pts = top
    # insert the junction in the y = width wall, walking from x = length down to 0
    out = bottom[:-1] + [[length, 0.0]]
    # A flag, and the walk includes the last corner (0, width): testing "no point above the
    # wall yet" (the top alcoves come first) and stopping before x < c had silently dropped
    # the junction, leaving the building fully point-symmetric (identical 180 deg twins).
    inserted = False
    for p in top_pts:
        if p[0] < c + jw / 2 and not inserted:
            out += [[c + jw / 2, width], [c + jw / 2, width + 6.0], [c - jw / 2, width + 6.0], [c - jw / 2, width]]
            inserted = True
        out.append(p)
    outline = _dedupe(out)
    doors = []
    for x in (4.0, 16.0, 30.0, 41.0):
        doors.append({"from": [x, 0.0], "to": [x + 0.9, 0.0], "height": 2.0})
        doors.append({"from": [length - x, width], "to": [length - x - 0.9, width], "height": 2.0})
    return {"floor_z": 0.0, "ceiling_z": CEILING, "outline": outline, "doors": doors}


def _dedupe(pts: list[list[float]]) -> list[list[float]]:
    out: list[list[float]] = []
    for p in pts:
        p = [round(float(p[0]), 4), round(float(p[1]), 4)]
        if not out or p != out[-1]:
            out.append(p)
    if out[0] == out[-1]:
        out.pop()
    return out


# ---------------------------------------------------------------- ray-cast renderer



@njit(parallel=True, cache=True)
def _raycast(pose: np.ndarray, width: int, height: int, focal: float, walls: np.ndarray, wall_s0: np.ndarray,
             doors: np.ndarray, posters: np.ndarray, boxes: np.ndarray, ceiling: float, out: np.ndarray) -> None:
    px, py, pz = pose[0], pose[1], pose[2]
    h = math.radians(pose[3])
    fx, fy = math.cos(h), math.sin(h)
    rx, ry = fy, -fx
    cx = (width - 1) / 2.0
    cy = (height - 1) / 2.0
    for v in prange(height):
        for u in range(width):
            a = (u - cx) / focal
            b = -(v - cy) / focal
            dx = fx + a * rx
            dy = fy + a * ry
            dz = b
            best = 1e9
            kind = 0  # 1 floor 2 ceiling 3 wall 4 box
            idx = -1
            if dz < -1e-9:
                best = (0.0 - pz) / dz
                kind = 1
            elif dz > 1e-9:
                best = (ceiling - pz) / dz
                kind = 2
            for w in range(walls.shape[0]):
                t, s = ray_segment(px, py, dx, dy, walls[w, 0], walls[w, 1], walls[w, 2], walls[w, 3])
                if t <= 1e-6 or t >= best or s < 0.0 or s > 1.0:
                    continue
                best = t
                kind = 3
                idx = w
            for k in range(boxes.shape[0]):
                # furniture: axis-aligned boxes
                t0 = ray_box(px, py, pz, dx, dy, dz, boxes[k], best)
                if t0 > 1e-6 and t0 < best:
                    best = t0
                    kind = 4
                    idx = k
            qx, qy, qz = px + best * dx, py + best * dy, pz + best * dz
            col = 0.5
            if kind == 1:
                # 0.5 m floor tiles with dark grout and mottling
                gu = qx / 0.5 - math.floor(qx / 0.5)
                gv = qy / 0.5 - math.floor(qy / 0.5)
                col = 0.45 + 0.12 * value_noise(qx, qy, 0.05, 3) + 0.08 * value_noise(qx, qy, 0.7, 4)
                if gu < 0.02 or gv < 0.02:
                    col = 0.25
            elif kind == 2:
                gu = qx / 0.6 - math.floor(qx / 0.6)
                gv = qy / 0.6 - math.floor(qy / 0.6)
                col = 0.78 + 0.05 * value_noise(qx, qy, 0.05, 5)
                if gu < 0.015 or gv < 0.015:
                    col = 0.6
                # ceiling light panels every 3 m on the corridor axis
                lx = qx / 3.0 - math.floor(qx / 3.0)
                if lx < 0.4 and 0.7 < qy < 1.7:
                    col = 1.0
            elif kind == 3:
                ax, ay = walls[idx, 0], walls[idx, 1]
                s = wall_s0[idx] + math.hypot(qx - ax, qy - ay)
                col = 0.66 + 0.16 * (value_noise(s, qz, 0.012, 7) - 0.5) + 0.10 * (value_noise(s, qz, 0.2, 8) - 0.5)
                # walls along x are lit more than walls along y, so corners show as edges
                wl = math.hypot(walls[idx, 2] - ax, walls[idx, 3] - ay)
                col *= 0.72 + 0.28 * abs(walls[idx, 2] - ax) / max(wl, 1e-9)
                if qz < 0.1:
                    col = 0.3 + 0.05 * value_noise(s, qz, 0.02, 9)
                for k in range(doors.shape[0]):
                    if doors[k, 0] == idx and doors[k, 1] <= s <= doors[k, 2] and qz <= doors[k, 3]:
                        col = 0.32 + 0.15 * value_noise(s * 4.0, qz * 0.3, 0.05, 11)
                        if abs(s - doors[k, 2] + 0.12) < 0.03 and abs(qz - 1.0) < 0.05:
                            col = 0.9  # door handle
                for k in range(posters.shape[0]):
                    if posters[k, 0] == idx and posters[k, 1] <= s <= posters[k, 2] and posters[k, 3] <= qz <= posters[k, 4]:
                        sd = int(posters[k, 5])
                        col = 0.15 + 0.8 * value_noise(s, qz, 0.06, sd)
                        if value_noise(s, qz, 0.15, sd + 1) > 0.6:
                            col = 0.95 - 0.5 * value_noise(s, qz, 0.02, sd + 2)
            elif kind == 4:
                col = 0.35 + 0.25 * boxes[idx, 6] + 0.1 * value_noise(qx + qy, qz, 0.04, 13)
                if abs(qz - boxes[idx, 5]) < 1e-3:
                    col = 0.55 + 0.25 * boxes[idx, 6]
            # distance fall-off of the light
            col *= 1.0 / (1.0 + 0.012 * best)
            out[v, u] = col


def render_view(pose: np.ndarray, cam: Camera, scene: dict[str, np.ndarray]) -> np.ndarray:
    out = np.zeros((cam.height, cam.width), dtype=np.float64)
    _raycast(np.asarray(pose, float), cam.width, cam.height, cam.focal, scene["walls"], scene["wall_s0"],
             scene["doors"], scene["posters"], scene["boxes"], CEILING, out)
    return out


def _scene(plan: dict[str, Any], rng: np.random.Generator) -> dict[str, np.ndarray]:
    model = floor_plan_model(plan)
    walls = model.faces[:, :4].copy()
    wall_s0 = np.zeros(len(walls))
    wall_s0[1:] = np.cumsum(np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1]))[:-1]
    doors = []
    for d in plan["doors"]:
        p, q = np.array(d["from"]), np.array(d["to"])
        for w, (ax, ay, bx, by) in enumerate(walls):
            a, e = np.array([ax, ay]), np.array([bx - ax, by - ay])
            L = np.hypot(*e)
            sp, sq = (p - a) @ e / L, (q - a) @ e / L
            off = abs(e[0] * (p - a)[1] - e[1] * (p - a)[0]) / L
            if off < 1e-6 and -1e-6 <= min(sp, sq) and max(sp, sq) <= L + 1e-6:
                doors.append([w, wall_s0[w] + min(sp, sq), wall_s0[w] + max(sp, sq), d["height"]])
    posters = []
    for w, (ax, ay, bx, by) in enumerate(walls):
        L = math.hypot(bx - ax, by - ay)
        for _ in range(int(L // 2.5)):
            s = rng.uniform(0.2, L - 1.2)
            pw, ph = rng.uniform(0.4, 1.0), rng.uniform(0.5, 0.9)
            z0 = rng.uniform(1.0, 1.5)
            s0 = wall_s0[w] + s
            if any(d[0] == w and d[1] - pw < s0 < d[2] for d in doors):
                continue
            posters.append([w, s0, s0 + pw, z0, z0 + ph, rng.integers(20, 10_000)])
    boxes = []
    for x in np.arange(6.0, LENGTH - 6.0, 7.0):   # benches and cabinets along the walls
        x = x + rng.uniform(-1.0, 1.0)
        if abs(x - LENGTH / 2) < 2.5:
            continue
        side = rng.integers(0, 2)
        bw, bd, bh = rng.uniform(0.8, 1.6), rng.uniform(0.3, 0.45), rng.uniform(0.45, 1.1)
        y0 = 0.0 if side == 0 else WIDTH - bd
        boxes.append([x, y0, 0.0, x + bw, y0 + bd, bh, rng.uniform(0, 1)])
    return {"walls": walls, "wall_s0": wall_s0, "doors": np.asarray(doors, float).reshape(-1, 4),
            "posters": np.asarray(posters, float).reshape(-1, 6), "boxes": np.asarray(boxes, float).reshape(-1, 7)}


def laser_distance(px: float, py: float, heading_deg: float, walls: np.ndarray) -> float:
    """Distance from (px, py) along ``heading_deg`` to the first wall (plan ray cast)."""
    return ray_range(px, py, heading_deg, walls)


def generate(out_dir: Path, seed: int = 0, frames: int = 50, start_x: float = 8.0, y: float = 1.6, z: float = 1.14,
             heading: float = 315.0, width: int = 320, height: int = 240, hfov_deg: float = 60.0,
             step_min: float = 0.1, step_max: float = 2.0, noise: float = 3.0, blur: float = 0.8,
             laser_noise_m: float = 0.01, **unknown: Any) -> dict[str, Any]:
    """Write the building, the sequence and its ground truth under ``out_dir``."""
    if unknown:
        raise TypeError(f"unknown corridor parameter(s) {', '.join(unknown)}; known: frames, start_x, y, z, heading, width, "
                        "height, hfov_deg, step_min, step_max, noise, blur, laser_noise_m")
    out_dir = Path(out_dir)
    (out_dir / "images").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    plan = {**building(), "camera_z": z}
    (out_dir / "floor_plan.yaml").write_text(yaml.safe_dump(plan, sort_keys=False))
    model = floor_plan_model(plan)
    (out_dir / "wireframe.yaml").write_text(yaml.safe_dump({"segments": model.segments.round(4).tolist(),
                                                            "faces": model.faces.round(4).tolist()}, sort_keys=False))
    scene = _scene(plan, rng)
    cam = Camera(width, height, hfov_deg)
    steps = rng.uniform(step_min, step_max, size=frames - 1)
    xs = start_x + np.concatenate([[0.0], np.cumsum(steps)])
    if xs[-1] > LENGTH - 2:
        raise ValueError(f"the sequence ends at x = {xs[-1]:.1f} m, beyond the corridor; use fewer frames or a smaller start_x")
    ys = y + rng.uniform(-0.03, 0.03, size=frames)
    # the laser points at the side wall the camera looks at (perpendicular to the corridor)
    h = heading % 360
    laser_heading = 270.0 if 180 < h < 360 else 90.0
    theta = abs(((h - laser_heading) + 180) % 360 - 180)
    with open(out_dir / "poses.csv", "w", newline="") as fp, open(out_dir / "sensor.csv", "w", newline="") as fs:
        wp, ws = csv.writer(fp), csv.writer(fs)
        wp.writerow(["frame", "x", "y", "z", "heading_deg"])
        ws.writerow(["frame", "d", "theta_deg"])
        for i, (x, yy) in enumerate(zip(xs, ys)):
            img = render_view(np.array([x, yy, z, heading]), cam, scene)
            img = np.clip(img * 255.0 + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8)
            if blur > 0:
                img = cv2.GaussianBlur(img, (0, 0), blur)
            name = f"frame_{i:03d}.png"
            cv2.imwrite(str(out_dir / "images" / name), img)
            d = laser_distance(x, yy, laser_heading, scene["walls"]) + rng.normal(0, laser_noise_m)
            wp.writerow([name, f"{x:.4f}", f"{yy:.4f}", f"{z:.4f}", f"{heading:.1f}"])
            ws.writerow([name, f"{d:.4f}", f"{theta:.1f}"])
    return {"out": str(out_dir), "frames": frames, "x_range_m": f"{xs[0]:.2f}..{xs[-1]:.2f}", "segments": len(model.segments),
            "faces": len(model.faces), "posters": len(scene["posters"]), "furniture": len(scene["boxes"])}
