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
- ``ceiling_height`` and ``camera_height`` per panorama, in local units;
- ``internal``: polygons of wall blocks inside a room that are not part of its outline (a
  kitchen wall, a pillar), imported as full-height walls;
- ``is_primary``: primary panoramas give the rooms; every panorama gives a pose.

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

from placeloc.core.artifacts import atomic_open
from placeloc.core.errors import ModelError
from placeloc.core.safe_io import load_json, name_inside, read_input_text
from placeloc.geometry.plan_check import check_plan, number, point


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


def floors_of(path: str | Path) -> tuple[list[str], list[str]]:
    """(every floor of a ``zind_data.json``, those with a metric scale) in name order."""
    data = _read(Path(path))
    floors = sorted(data["merger"])
    return floors, [f for f in floors if data["scale_meters_per_coordinate"].get(f) is not None]


def _read(path: Path) -> dict[str, Any]:
    try:
        data = load_json(read_input_text(path, "ZInD file"), str(path))
        if not isinstance(data["merger"], dict) or not isinstance(data["scale_meters_per_coordinate"], dict):
            raise TypeError("merger and scale_meters_per_coordinate must be mappings")
    except (OSError, ValueError, KeyError, TypeError) as exc:  # ValueError: JSON syntax, depth, not a file
        raise ModelError(f"{path}: not a ZInD zind_data.json with 'merger' and 'scale_meters_per_coordinate' ({exc})") from exc
    return data


def _pick_floor(source: str, floors: list[str], scales: dict[str, Any], floor: str | None) -> str:
    if not floors:
        raise ModelError(f"{source}: the merger has no floors")
    if floor is not None:
        if floor not in floors:
            raise ModelError(f"{source}: no floor {floor!r}; the file has {', '.join(floors)}")
        if scales.get(floor) is None:
            raise ModelError(f"{source}: {floor} has no scale_meters_per_coordinate (uncalibrated); choose another floor")
        return floor
    calibrated = [f for f in floors if scales.get(f) is not None]
    if not calibrated:
        raise ModelError(f"{source}: no floor has a scale_meters_per_coordinate (uncalibrated tour); nothing to import")
    if len(calibrated) > 1:
        raise ModelError(f"{source}: the file has {len(calibrated)} floors ({', '.join(calibrated)}); choose one with "
                         "floor: (umap.floor in a config, --floor on the command line)")
    return calibrated[0]


def zind_home(path: str | Path, floor: str | None = None) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """(floor plan in the multi-room format, panoramas [{frame, image_path, x, y, z,
    heading_deg, primary, room}]) of one floor of a ``zind_data.json``. ``floor`` None: the
    file's only floor with a metric scale (an error naming the floors when there are several).

    Per complete room, the first primary panorama with a layout gives the room:
    ``layout_complete`` (else ``layout_raw``) vertices, its ``internal`` polygons (wall
    blocks not joined to the room's outline, as the kitchen wall of an L-shaped kitchen), its
    ``doors`` and ``openings`` (gaps, kept apart) and ``windows``, and the ceiling height.
    Every panorama, primary or secondary, gives a ground-truth pose; the plan's ``camera_z``
    is their median camera height in metres."""
    path = Path(path)
    source = str(path)
    data = _read(path)
    merger, scales = data["merger"], data["scale_meters_per_coordinate"]
    floor = _pick_floor(source, sorted(merger), scales, floor)
    metres = number(scales[floor], source, f"scale_meters_per_coordinate[{floor!r}]", positive=True)
    rooms: list[dict[str, Any]] = []
    doors: list[dict[str, Any]] = []
    openings: list[dict[str, Any]] = []
    windows: list[dict[str, Any]] = []
    panoramas: list[dict[str, Any]] = []

    def wall_items(items: Any, what: str, tr: dict[str, Any], cam_h: float, units: float) -> list[tuple]:
        out = []
        for a, b, bottom, top in _wdo(items, what, source):
            ends = _to_world(np.stack([a, b]), tr, metres)
            # (bottom, top) are heights relative to the camera; the floor is at -camera_height
            out.append((ends[0].round(4).tolist(), ends[1].round(4).tolist(), round((bottom + cam_h) * units, 4),
                        round((top + cam_h) * units, 4)))
        return out

    for cr_name in sorted(merger[floor]):
        room_done = False
        for pr_name in sorted(merger[floor][cr_name]):
            for pano_name in sorted(merger[floor][cr_name][pr_name]):
                pano = merger[floor][cr_name][pr_name][pano_name]
                where = f"{floor}/{cr_name}/{pr_name}/{pano_name}"
                try:
                    tr = pano["floor_plan_transformation"]
                    # scale, rotation, translation and heights: finite, and the lengths above 0
                    units = number(tr["scale"], source, f"{where} floor_plan_transformation.scale", positive=True) * metres
                    number(tr["rotation"], source, f"{where} floor_plan_transformation.rotation")
                    point(tr["translation"], source, f"{where} floor_plan_transformation.translation")
                    cam_h = number(pano.get("camera_height", 1.0), source, f"{where} camera_height", positive=True)
                    centre = _to_world(np.zeros((1, 2)), tr, metres)[0]
                    primary = bool(pano.get("is_primary", False))
                    panoramas.append({"frame": Path(pano["image_path"]).name, "image_path": pano["image_path"],
                                      "x": float(centre[0]), "y": float(centre[1]), "z": cam_h * units,
                                      "heading_deg": (-90.0 - float(tr["rotation"])) % 360.0, "primary": primary,
                                      "room": cr_name})
                    if room_done or not primary:
                        continue
                    layout = pano.get("layout_complete") or pano.get("layout_raw")
                    if not layout:
                        continue
                    poly = _to_world(np.asarray(layout["vertices"], float), tr, metres)
                    ceiling = number(pano["ceiling_height"], source, f"{where} ceiling_height", positive=True)
                    room = {"name": f"{cr_name} ({pano.get('label', '')})".strip(), "polygon": poly.round(4).tolist(),
                            "floor_z": 0.0, "ceiling_z": round(ceiling * units, 4)}
                    internal = [_to_world(np.asarray(v, float), tr, metres).round(4).tolist()
                                for v in (layout.get("internal") or []) if len(v) >= 3]
                    if internal:
                        room["internal"] = internal
                    rooms.append(room)
                    for key, into in (("doors", doors), ("openings", openings)):
                        for a, b, _bottom, top in wall_items(layout.get(key), f"{where} {key}", tr, cam_h, units):
                            into.append({"from": a, "to": b, "height": top})
                    for a, b, bottom, top in wall_items(layout.get("windows"), f"{where} windows", tr, cam_h, units):
                        windows.append({"from": a, "to": b, "sill": bottom, "top": top})
                    room_done = True
                except ModelError:
                    raise
                except (KeyError, TypeError, ValueError, IndexError) as exc:
                    raise ModelError(f"{source}: {where}: malformed panorama entry ({exc!r})") from exc
    if not rooms:
        raise ModelError(f"{source}: {floor} has no primary panorama with a layout; nothing to import")
    plan = {"floor_z": 0.0, "ceiling_z": max(r["ceiling_z"] for r in rooms),
            "camera_z": round(float(np.median([p["z"] for p in panoramas])), 4), "rooms": rooms,
            "doors": doors, "openings": openings, "windows": windows}
    check_plan(plan, source)  # the plan the importer writes is one the loader accepts: finite, simple, with an area
    return plan, panoramas


def import_zind(path: str | Path, out_dir: str | Path, floor: str | None = None) -> dict[str, Any]:
    """Write ``floor_plan.yaml``, ``poses.csv`` (frame, x, y, z, heading_deg, primary) and
    ``rooms.csv`` (frame, room: a ``umap.room_hints`` file) of a ``zind_data.json`` under
    ``out_dir``: of ``floor`` when given or when the file has one
    floor with a scale, else of every such floor, each in ``out_dir/<floor>/``. Returns a
    short summary (per floor when there are several)."""
    out = Path(out_dir)
    if floor is None:
        _, calibrated = floors_of(path)
        if len(calibrated) > 1:
            # a floor's key comes from the JSON: it names a folder only as one plain name inside OUT
            folders = {f: name_inside(out, f, f"{path}: floor key") for f in calibrated}
            return {f: _write_floor(path, folders[f], f) for f in calibrated}
        if not calibrated:
            _pick_floor(str(path), floors_of(path)[0], {}, None)  # raises with the reason
        floor = calibrated[0]
    return _write_floor(path, out, floor)


def _write_floor(path: str | Path, out: Path, floor: str) -> dict[str, Any]:
    plan, panos = zind_home(path, floor)
    out.mkdir(parents=True, exist_ok=True)
    # written under a temporary name and renamed: a link at either name is replaced, not written through
    with atomic_open(out / "floor_plan.yaml") as f:
        f.write(yaml.safe_dump(plan, sort_keys=False))
    with atomic_open(out / "poses.csv", newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "x", "y", "z", "heading_deg", "primary"])
        for p in panos:
            w.writerow([p["frame"], f"{p['x']:.4f}", f"{p['y']:.4f}", f"{p['z']:.4f}", f"{p['heading_deg']:.2f}",
                        int(p["primary"])])
    # each panorama's room as ZInD's annotators placed it: a umap.room_hints file (empty where
    # its complete room gave the plan no room: none of its panoramas had a layout)
    names = {str(r["name"]).split(" (", 1)[0]: str(r["name"]) for r in plan["rooms"]}
    with atomic_open(out / "rooms.csv", newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "room"])
        w.writerows([p["frame"], names.get(str(p["room"]), "")] for p in panos)
    return {"floor": floor, "out": str(out), "rooms": len(plan["rooms"]),
            "internal walls": sum(len(r.get("internal", [])) for r in plan["rooms"]), "doors": len(plan["doors"]),
            "openings": len(plan["openings"]), "windows": len(plan["windows"]), "panoramas": len(panos),
            "primary": sum(p["primary"] for p in panos), "camera_z": plan["camera_z"]}


def write_zind(plan: dict[str, Any], panoramas: list[dict[str, Any]], path: str | Path, *,
               metres_per_coordinate: float = 0.01, image_dir: str = "panos") -> None:
    """Write a multi-room floor plan and its panoramas ({frame, x, y, z, heading_deg}) as a
    one-floor ``zind_data.json`` in the published format: the inverse of :func:`zind_home`
    (a generated home in the form real tours come in). Each room is a complete room whose
    primary panorama (the first panorama in it or nearest to it; a panorama without an
    image at its centre for a room nobody photographed) carries the layout in its local
    frame: vertices, internal polygons, doors (gaps narrower than 1.2 m), openings, windows
    on the room's edges, heights relative to the camera in camera heights."""
    from placeloc.geometry.polygons import on_edge as _on_edge
    from placeloc.geometry.polygons import point_in_polygon

    polys = [np.asarray(r["polygon"], float) for r in plan["rooms"]]
    cam_z = float(plan.get("camera_z") or np.median([p["z"] for p in panoramas]))

    def room_of(x: float, y: float) -> int:
        inside = [i for i, poly in enumerate(polys) if point_in_polygon(np.array([[x, y]]), poly)[0]]
        if inside:
            return inside[0]
        d = [min(np.hypot(*(np.array([x, y]) - q)) for q in np.linspace(poly, np.roll(poly, -1, 0), 20).reshape(-1, 2))
             for poly in polys]
        return int(np.argmin(d))

    def tr_of(x: float, y: float, heading: float, z: float) -> dict[str, Any]:
        # one local unit is the panorama's own camera height, as in the published data
        return {"translation": [x / metres_per_coordinate, -y / metres_per_coordinate], "rotation": (-90.0 - heading) % 360.0,
                "scale": z / metres_per_coordinate}

    def to_local(pts: Any, tr: dict[str, Any]) -> list[list[float]]:
        g = np.asarray(pts, float).reshape(-1, 2).copy()
        g[:, 1] = -g[:, 1]
        r = math.radians(tr["rotation"])
        rot = np.array([[math.cos(r), math.sin(r)], [-math.sin(r), math.cos(r)]])
        return (((g / metres_per_coordinate - tr["translation"]) / tr["scale"]) @ rot.T).round(6).tolist()

    by_room: dict[int, list[dict[str, Any]]] = {i: [] for i in range(len(polys))}
    for p in panoramas:
        by_room[room_of(p["x"], p["y"])].append(p)
    gaps = [("doors" if np.hypot(*(np.subtract(o["to"], o["from"]))) < 1.2 else "openings", o)
            for o in (plan.get("doors") or []) + (plan.get("openings") or [])]
    floor: dict[str, Any] = {}
    for i, (room, poly) in enumerate(zip(plan["rooms"], polys)):
        panos = by_room[i] or [{"frame": f"unphotographed_room_{i + 1:02d}.jpg", "x": float(poly[:, 0].mean()),
                                "y": float(poly[:, 1].mean()), "z": cam_z, "heading_deg": 0.0}]
        edges = list(zip(poly, np.roll(poly, -1, axis=0)))
        zc = float(room.get("ceiling_z", plan["ceiling_z"]))
        entries = {}
        for j, p in enumerate(panos):
            cz = float(p.get("z", cam_z))
            tr = tr_of(p["x"], p["y"], p["heading_deg"], cz)
            entry = {"label": room.get("name", f"room {i + 1}"), "is_primary": j == 0, "is_inside": True,
                     "is_ceiling_flat": True, "ceiling_height": zc / cz, "camera_height": 1.0, "floor_number": 1,
                     "image_path": f"{image_dir}/{p['frame']}", "floor_plan_transformation": tr}
            if j == 0:
                layout: dict[str, Any] = {"vertices": to_local(poly, tr), "doors": [], "openings": [], "windows": [],
                                          "internal": [to_local(b, tr) for b in room.get("internal") or []]}
                for kind, o in gaps:
                    if any(_on_edge(np.asarray(o["from"], float), np.asarray(o["to"], float), a, b) for a, b in edges):
                        layout[kind] += [*to_local([o["from"], o["to"]], tr), [-1.0, float(o["height"]) / cz - 1.0]]
                for wdw in plan.get("windows") or []:
                    if any(_on_edge(np.asarray(wdw["from"], float), np.asarray(wdw["to"], float), a, b) for a, b in edges):
                        layout["windows"] += [*to_local([wdw["from"], wdw["to"]], tr),
                                              [float(wdw["sill"]) / cz - 1.0, float(wdw["top"]) / cz - 1.0]]
                entry["layout_complete"] = layout
            entries[f"pano_{j + 1:02d}"] = entry
        floor[f"complete_room_{i + 1:02d}"] = {f"partial_room_{i + 1:02d}": entries}
    data = {"scale_meters_per_coordinate": {"floor_01": metres_per_coordinate}, "merger": {"floor_01": floor},
            "redraw": {}, "floorplan_to_redraw_transformation": {}}
    Path(path).write_text(json.dumps(data, indent=1))
