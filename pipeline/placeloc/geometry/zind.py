"""Import a home from the Zillow Indoor Dataset's ``zind_data.json`` (S. Cruz, W. Hutchcroft,
Y. Li, N. Khosravan, I. Boyadzhiev and S. B. Kang, "Zillow Indoor Dataset: Annotated Floor
Plans With 360 Panoramas and 3D Room Layouts", CVPR 2021) into the multi-room floor-plan
format of :mod:`placeloc.geometry.floorplan`, with the panoramas' ground-truth poses.

What is used of the published format (``merger`` -> floor -> complete room -> partial room
-> pano):

- ``layout_complete`` (else ``layout_raw``) of each complete room's primary panorama: the
  room polygon ``vertices`` and ``doors`` / ``openings`` / ``windows``, in the panorama's
  local frame, in units of the camera height (``camera_height`` is 1.0);
- each element of ``doors``, ``openings`` and ``windows`` is three pairs: the left and right
  ends on the wall, then (bottom, top) heights, read here relative to the camera (the
  floor at ``-camera_height``);
- ``floor_plan_transformation`` (translation, rotation in degrees, scale) takes local points
  to the floor's coordinates as ``p_global = (p_local @ R) * scale + translation`` with
  ``R = [[cos, sin], [-sin, cos]]``; the camera is the local origin;
- ``scale_meters_per_coordinate[floor]`` turns floor coordinates into metres (a floor
  without it cannot be imported);
- ``ceiling_height`` and ``camera_height`` per panorama, in local units.

The layout frame is left-handed relative to the panorama (its azimuth is ``atan2(-x, y)``,
the image centre looking along local +y), so y is flipped on import to get the right-handed
world of :mod:`placeloc.geometry`; the panorama's heading (the direction of its centre
column) is then ``-90 - rotation`` degrees.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from placeloc.geometry.floorplan import ModelError


def _to_world(local: np.ndarray, tr: dict[str, Any], metres: float) -> np.ndarray:
    r = math.radians(float(tr["rotation"]))
    rot = np.array([[math.cos(r), math.sin(r)], [-math.sin(r), math.cos(r)]])
    g = (np.asarray(local, float).reshape(-1, 2) @ rot) * float(tr["scale"]) + np.asarray(tr["translation"], float)
    g = g * metres
    g[:, 1] = -g[:, 1]
    return g


def _wdo(items: Any, what: str, source: str) -> list[tuple[np.ndarray, np.ndarray, float, float]]:
    flat = list(items or [])
    if len(flat) % 3:
        raise ModelError(f"{source}: {what} has {len(flat)} points; each element needs three (left, right, bottom/top)")
    out = []
    for i in range(0, len(flat), 3):
        out.append((np.asarray(flat[i], float), np.asarray(flat[i + 1], float), float(flat[i + 2][0]), float(flat[i + 2][1])))
    return out


def zind_home(path: str | Path, floor: str | None = None) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """(floor plan in the multi-room format, panoramas [{frame, image_path, x, y, z,
    heading_deg, primary}]) of one floor of a ``zind_data.json`` (the first floor by name
    when ``floor`` is None)."""
    path = Path(path)
    source = str(path)
    try:
        data = json.loads(path.read_text())
        merger = data["merger"]
        scales = data["scale_meters_per_coordinate"]
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ModelError(f"{source}: not a ZInD zind_data.json with 'merger' and 'scale_meters_per_coordinate' ({exc})") from exc
    floors = sorted(merger)
    if not floors:
        raise ModelError(f"{source}: the merger has no floors")
    floor = floor or floors[0]
    if floor not in merger:
        raise ModelError(f"{source}: no floor {floor!r}; the file has {', '.join(floors)}")
    metres = scales.get(floor)
    if metres is None:
        raise ModelError(f"{source}: {floor} has no scale_meters_per_coordinate (uncalibrated); choose another floor")
    metres = float(metres)
    rooms, openings, windows, panoramas = [], [], [], []
    for cr_name in sorted(merger[floor]):
        room_done = False
        for pr_name in sorted(merger[floor][cr_name]):
            for pano_name in sorted(merger[floor][cr_name][pr_name]):
                pano = merger[floor][cr_name][pr_name][pano_name]
                where = f"{floor}/{cr_name}/{pr_name}/{pano_name}"
                try:
                    tr = pano["floor_plan_transformation"]
                    units = float(tr["scale"]) * metres          # metres per local unit (camera height = 1)
                    cam_h = float(pano.get("camera_height", 1.0))
                    centre = _to_world(np.zeros((1, 2)), tr, metres)[0]
                    panoramas.append({"frame": Path(pano["image_path"]).name, "image_path": pano["image_path"],
                                      "x": float(centre[0]), "y": float(centre[1]), "z": cam_h * units,
                                      "heading_deg": (-90.0 - float(tr["rotation"])) % 360.0,
                                      "primary": bool(pano.get("is_primary", False))})
                    if room_done or not pano.get("is_primary", False):
                        continue
                    layout = pano.get("layout_complete") or pano.get("layout_raw")
                    if not layout:
                        continue
                    poly = _to_world(np.asarray(layout["vertices"], float), tr, metres)
                    rooms.append({"name": f"{cr_name} ({pano.get('label', '')})".strip(),
                                  "polygon": poly.round(4).tolist(), "floor_z": 0.0,
                                  "ceiling_z": round(float(pano["ceiling_height"]) * units, 4)})
                    for kind in ("doors", "openings"):
                        for a, b, _bottom, top in _wdo(layout.get(kind), f"{where} {kind}", source):
                            ends = _to_world(np.stack([a, b]), tr, metres)
                            openings.append({"from": ends[0].round(4).tolist(), "to": ends[1].round(4).tolist(),
                                             "height": round((top + cam_h) * units, 4)})
                    for a, b, bottom, top in _wdo(layout.get("windows"), f"{where} windows", source):
                        ends = _to_world(np.stack([a, b]), tr, metres)
                        windows.append({"from": ends[0].round(4).tolist(), "to": ends[1].round(4).tolist(),
                                        "sill": round((bottom + cam_h) * units, 4), "top": round((top + cam_h) * units, 4)})
                    room_done = True
                except (KeyError, TypeError, ValueError, IndexError) as exc:
                    raise ModelError(f"{source}: {where}: malformed panorama entry ({exc!r})") from exc
    if not rooms:
        raise ModelError(f"{source}: {floor} has no primary panorama with a layout; nothing to import")
    plan = {"floor_z": 0.0, "ceiling_z": max(r["ceiling_z"] for r in rooms), "rooms": rooms, "openings": openings,
            "windows": windows}
    return plan, panoramas


def import_zind(path: str | Path, out_dir: str | Path, floor: str | None = None) -> dict[str, Any]:
    """Write ``floor_plan.yaml`` and ``poses.csv`` (frame, x, y, z, heading_deg) for one
    floor of a ``zind_data.json`` under ``out_dir``; returns a short summary."""
    plan, panos = zind_home(path, floor)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "floor_plan.yaml").write_text(yaml.safe_dump(plan, sort_keys=False))
    with open(out / "poses.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "x", "y", "z", "heading_deg"])
        for p in panos:
            w.writerow([p["frame"], f"{p['x']:.4f}", f"{p['y']:.4f}", f"{p['z']:.4f}", f"{p['heading_deg']:.2f}"])
    return {"rooms": len(plan["rooms"]), "openings": len(plan["openings"]), "windows": len(plan["windows"]),
            "panoramas": len(panos)}
