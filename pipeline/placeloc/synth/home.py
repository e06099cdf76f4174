"""Synthetic empty homes with 360 degree panoramas (``placeloc synth home OUT``).

Built to fail the way real homes do for line-map localization: a hallway with several
bedrooms of nearly the same size and layout, a living room and a kitchen, all with the
same paint, so that

- many detected lines are not in the map: window blinds, kitchen cabinets and wardrobes,
  what stands on the kitchen counters (appliances, a dish rack, a sink under a window the
  map lacks) and the handles and panels of the cabinet doors,
  door leaves with panels (closed) or standing open against the wall, skirting boards just
  above the floor line, floor planks and tiles, sunlight patches cast through windows;
- many map lines are hardly visible: walls and ceiling are painted alike, so the
  wall/ceiling corners and the vertical room corners have little contrast.

Written under OUT:

- ``floor_plan.yaml``: the multi-room plan (rooms, openings, windows; the format of
  :mod:`placeloc.geometry.floorplan`), i.e. the map, without any of the clutter above;
- ``panoramas/pano_000.png ...``: grey equirectangular panoramas (2:1) at random free-space
  poses, with random headings, sensor noise and blur;
- ``poses.csv``: frame, x, y, z, heading_deg (ground truth);
- ``zind_data.json``: the same home and poses in the Zillow Indoor Dataset's format (one
  complete room per room, the layout in its primary panorama's frame: what
  ``placeloc import zind`` and ``umap.model: zind_data.json`` read);
- ``line_stats.json``: how much the panoramas' LSD lines and the map's lines agree at the
  true poses (share of detected line pixels on map lines, share of map line pixels
  detected), which :func:`generate` also returns and the CLI prints.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml
from numba import njit, prange

from placeloc.core.images import PanoramaCrop
from placeloc.geometry.floorplan import blocking_faces, floor_plan_model, free_space_mask, wall_distance
from placeloc.geometry.panorama import (
    axis_rotation,
    draw_line_image,
    panorama_lines,
    render_panoramas,
    turn_panorama,
)
from placeloc.geometry.polygons import point_in_polygon
from placeloc.geometry.rays import ray_box, ray_segment
from placeloc.geometry.zind import write_zind
from placeloc.synth.texture import cell_hash, value_noise

CEILING = 2.5
HALL_W = 1.4

# surface kinds of the ray caster
FLOOR, CEIL, WALL, BOX, LEAF = 1, 2, 3, 4, 5


def plan(rng: np.random.Generator, n_bedrooms: int = 3,
         things_rng: np.random.Generator | None = None, ceiling: float = CEILING) -> tuple[dict[str, Any], dict[str, Any]]:
    """A random home: (the floor plan in the multi-room format, the clutter that is not in
    the map). Bedrooms north of an east-west hallway, living room and kitchen south of it.

    With ``things_rng``, the kitchen's counters also hold what a real one holds at wall
    height (:func:`_kitchen_things`: appliances, a sink under a window, a dish rack, handles
    on the cabinet doors), drawn from that generator alone, so that everything else (the
    plan, the other clutter, and the draws of ``rng`` after it) is the home without them.
    ``ceiling``: every room's ceiling height in metres (the fans hang from it); it draws
    nothing from ``rng``, so another ceiling gives the same plan and poses."""
    rooms, openings, windows = [], [], []
    bed_w = [round(3.2 + rng.uniform(-0.15, 0.15), 2) for _ in range(n_bedrooms)]
    bed_d = round(3.4 + rng.uniform(-0.1, 0.1), 2)
    length = sum(bed_w)
    y0, y1 = 0.0, HALL_W
    rooms.append({"name": "hall", "polygon": [[0, y0], [length, y0], [length, y1], [0, y1]]})
    x = 0.0
    door_w = 0.85
    # boxes: furniture a camera keeps away from; fans and flat things (rugs, pictures) it may stand under or on
    clutter: dict[str, list] = {"boxes": [], "fans": [], "flat": [], "leaves": [], "blinds": [], "lamps": [],
                                "counters": [], "things": [], "thing_names": []}
    for i, w in enumerate(bed_w):
        rooms.append({"name": f"bedroom{i + 1}", "polygon": [[x, y1], [x + w, y1], [x + w, y1 + bed_d], [x, y1 + bed_d]]})
        dx = x + 0.3 + rng.uniform(0.0, 0.4)
        openings.append({"from": [round(dx, 3), y1], "to": [round(dx + door_w, 3), y1], "height": 2.05})
        wx = x + w / 2 - 0.7 + rng.uniform(-0.3, 0.3)
        windows.append({"from": [round(wx, 3), y1 + bed_d], "to": [round(wx + 1.4, 3), y1 + bed_d], "sill": 0.9, "top": 2.1})
        # a wardrobe against a side wall, opposite the door side
        ww, wd = rng.uniform(1.2, 1.8), 0.6
        clutter["boxes"].append([x + w - wd, y1 + bed_d - 0.2 - ww, 0.0, x + w, y1 + bed_d - 0.2, 2.1, 0.55 + 0.1 * rng.random(), 1.0])
        _door_leaf(clutter, rng, (dx, y1), (dx + door_w, y1), +1)
        # a bed against the window wall (its edges hide the floor line there), a fan over some
        bx = x + w / 2 + rng.uniform(-0.3, 0.1)
        clutter["boxes"].append([bx - 0.8, y1 + bed_d - 2.05, 0.0, bx + 0.8, y1 + bed_d - 0.05, 0.55, 0.62 + 0.1 * rng.random(), 0.0])
        if rng.random() < 0.5:
            _fan(clutter, x + w / 2 + rng.uniform(-0.2, 0.2), y1 + bed_d / 2 + rng.uniform(-0.2, 0.2), ceiling)
        # a chest of drawers against the east wall by the door (drawer lines at 0.3-1.0 m) and a
        # mirror above it (at wall height, where the map's lines are)
        clutter["boxes"].append([x + w - 0.45, y1 + 0.25, 0.0, x + w, y1 + 1.15, 1.0, 0.5, -0.25])
        clutter["flat"].append([x + w - 0.02, y1 + 0.35, 1.25, x + w, y1 + 1.05, 1.85, 0.7, 0.0])
        # a rug beside the bed and a picture on the west wall: lines the map does not have
        clutter["flat"].append([bx - 1.4, y1 + bed_d - 1.8, 0.0, bx - 0.85, y1 + bed_d - 0.6, 0.012, 0.35 + 0.2 * rng.random(), 0.0])
        py = y1 + bed_d / 2 + rng.uniform(-0.6, 0.2)
        clutter["flat"].append([x, py, 1.2, x + 0.02, py + 0.7, 1.7, 0.45 + 0.3 * rng.random(), 0.0])
        x += w
    liv_w = round(length * 0.6, 2)
    south = 4.2 + rng.uniform(-0.2, 0.2)
    rooms.append({"name": "living", "polygon": [[0, -south], [liv_w, -south], [liv_w, 0], [0, 0]]})
    rooms.append({"name": "kitchen", "polygon": [[liv_w, -south], [length, -south], [length, 0], [liv_w, 0]]})
    # a bonus room at the east end of the hallway, all white (walls, ceiling and carpet in
    # nearly one shade: few of its map lines are detected) with a ceiling fan and sunlight
    # striped by the blinds of its south window on the carpet: most of what is detected
    # there is clutter, as in the real home's bonus room
    bonus_w = round(3.4 + rng.uniform(-0.2, 0.2), 2)
    bonus_n = round(HALL_W + bed_d - rng.uniform(0.5, 1.0), 2)
    rooms.append({"name": "bonus", "polygon": [[length, 0], [length + bonus_w, 0], [length + bonus_w, bonus_n], [length, bonus_n]]})
    openings.append({"from": [length, 0.25], "to": [length, 0.25 + door_w], "height": 2.05})
    bwx = length + 0.6 + rng.uniform(0.0, 0.5)
    windows.append({"from": [round(bwx, 3), 0.0], "to": [round(bwx + 2.0, 3), 0.0], "sill": 0.7, "top": 2.2})
    _fan(clutter, length + bonus_w / 2 + rng.uniform(-0.2, 0.2), bonus_n / 2 + rng.uniform(-0.2, 0.2), ceiling)
    openings.append({"from": [1.0, 0.0], "to": [2.4, 0.0], "height": 2.3})                          # wide opening
    kd = liv_w + 0.5 + rng.uniform(0, 0.5)
    openings.append({"from": [round(kd, 3), 0.0], "to": [round(kd + door_w, 3), 0.0], "height": 2.05})
    _door_leaf(clutter, rng, (kd, 0.0), (kd + door_w, 0.0), -1)
    for wx in (0.8, liv_w - 2.6):
        windows.append({"from": [round(wx, 3), -south], "to": [round(wx + 1.8, 3), -south], "sill": 0.6, "top": 2.2})
    windows.append({"from": [length, round(-south + 1.0, 3)], "to": [length, round(-south + 2.2, 3)], "sill": 1.0, "top": 2.1})
    # an internal wall in the kitchen (in the map: a free-standing full-height block, as ZInD's
    # "internal" polygons), a sofa and a dining table in the living room, a fan over it
    iw = liv_w + 2.0 + rng.uniform(-0.3, 0.3)
    rooms[-1]["internal"] = [[[round(iw, 3), -2.7], [round(iw + 0.12, 3), -2.7], [round(iw + 0.12, 3), -1.3], [round(iw, 3), -1.3]]]
    clutter["boxes"].append([0.0, -south + 0.9, 0.0, 0.9, -south + 3.0, 0.8, 0.4, 0.0])
    tx, ty = liv_w / 2 + rng.uniform(-0.5, 0.5), -south / 2 + rng.uniform(-0.3, 0.3)
    clutter["boxes"].append([tx - 0.8, ty - 0.45, 0.72, tx + 0.8, ty + 0.45, 0.76, 0.35, 0.0])
    _fan(clutter, liv_w / 2 + rng.uniform(-0.4, 0.4), -south / 2 + rng.uniform(-0.4, 0.4), ceiling)
    clutter["flat"].append([tx - 1.3, ty - 1.0, 0.0, tx + 1.3, ty + 1.0, 0.012, 0.4 + 0.15 * rng.random(), 0.0])   # a rug
    ru = rng.uniform(0.5, length - 3.0)
    clutter["flat"].append([ru, 0.35, 0.0, ru + 2.4, HALL_W - 0.35, 0.012, 0.3 + 0.2 * rng.random(), 0.0])  # a hall runner
    # kitchen cabinets: counter runs along the south and east walls with wall cabinets above
    # them (door gaps every 0.6 m), a tiled splashback between, a tall fridge and a range
    # hood: a real kitchen's clutter stands at wall height, where the map's lines are
    k0 = liv_w + 0.1
    clutter["boxes"].append([k0, -south, 0.0, length - 0.1, -south + 0.6, 0.9, 0.45, 0.6])
    # the counter runs' fronts (from, to, the inward normal), where a cook stands
    clutter["counters"] += [[k0, -south + 0.6, length - 0.1, -south + 0.6, 0.0, 1.0],
                            [length - 0.6, -south + 2.35, length - 0.6, -0.9, -1.0, 0.0]]
    if things_rng is None:
        clutter["boxes"].append([k0, -south, 1.45, length - 0.1, -south + 0.35, 2.15, 0.5, 0.6])
    clutter["flat"].append([k0, -south, 0.9, length - 0.1, -south + 0.01, 1.45, 0.62, 0.3])        # splashback tiles
    hood = k0 + rng.uniform(0.6, 1.2)
    clutter["boxes"].append([hood, -south + 0.35, 1.6, hood + 0.6, -south + 0.55, 1.95, 0.3, 0.0])  # range hood
    clutter["boxes"].append([length - 0.6, -south + 2.35, 0.0, length, -0.9, 0.9, 0.45, 0.6])     # east counter
    clutter["boxes"].append([length - 0.35, -south + 2.35, 1.45, length, -0.9, 2.15, 0.5, 0.6])   # its wall cabinets
    clutter["boxes"].append([length - 0.7, -0.8, 0.0, length - 0.05, -0.1, 1.85, 0.75, 0.0])     # fridge
    clutter["boxes"].append([liv_w, -south + 1.0, 1.2, liv_w + 0.25, -south + 2.6, 2.0, 0.45, -0.2])  # open shelves
    clutter["flat"].append([k0 + 1.9, -south + 0.6, 0.0, k0 + 2.5, -south + 0.62, 0.85, 0.25, 0.0])  # oven front
    clutter["flat"].append([liv_w, -south + 2.9, 1.5, liv_w + 0.02, -south + 3.3, 1.9, 0.3, 0.0])    # a clock
    if things_rng is not None:
        _kitchen_things(clutter, things_rng, k0, length, south, hood, kd + door_w)
    # open shelves and a television at eye height in the living room (horizontal lines
    # between the floor line and the ceiling line)
    sx = liv_w - 1.6 + rng.uniform(-0.3, 0.3)
    clutter["boxes"].append([sx, -0.3, 0.0, sx + 1.0, -0.02, 1.9, 0.4, -0.38])                   # bookshelf
    clutter["flat"].append([0.0, -south + 1.4, 1.05, 0.03, -south + 2.5, 1.65, 0.15, 0.0])       # television
    # a radiator under each window (its fins are vertical lines), a ceiling lamp panel per room
    for w in windows:
        (ax, ay), (bx, by) = w["from"], w["to"]
        if abs(ay - by) < 1e-9:  # on an east-west wall: the radiator stands 0.1 m into the room
            inward = -1.0 if ay > 0 else 1.0
            y_a, y_b = sorted((ay, ay + 0.1 * inward))
            clutter["boxes"].append([min(ax, bx) + 0.1, y_a, 0.12, max(ax, bx) - 0.1, y_b, min(0.7, w["sill"] - 0.1), 0.88, 0.06])
    for r in rooms:
        (x0, y0), (x1, y1_) = np.min(r["polygon"], axis=0), np.max(r["polygon"], axis=0)
        cx, cy = (x0 + x1) / 2 + rng.uniform(-0.3, 0.3), (y0 + y1_) / 2 + rng.uniform(-0.3, 0.3)
        half = 0.3 if r["name"] != "kitchen" else 0.6
        clutter["lamps"].append([cx - half, cy - 0.3, cx + half, cy + 0.3])
    # blinds on most windows, sunlight through all of them
    for w in windows:
        if rng.random() < 0.75 or w["from"][0] >= length:   # the bonus room's window always has blinds
            clutter["blinds"].append([*w["from"], *w["to"], w["sill"], w["top"] - rng.uniform(0.0, 0.6)])
    fp = {"floor_z": 0.0, "ceiling_z": ceiling, "rooms": rooms, "openings": openings, "windows": windows}
    return fp, clutter


def floor_of_homes(rng: np.random.Generator, homes: int, bedrooms: int) -> dict[str, Any]:
    """A storey of ``homes`` random homes (:func:`plan`) side by side along x, 0.3 m of wall
    apart: the multi-room floor plan of a real-scale floor (several hundred segments), for
    benchmarks. Clutter is not kept."""
    rooms, openings, windows = [], [], []
    x0 = 0.0
    for h in range(homes):
        fp, _ = plan(rng, bedrooms)
        xs = [p[0] for r in fp["rooms"] for p in r["polygon"]]
        dx = x0 - min(xs)

        def moved(pts: list, dx: float = dx) -> list:
            return [[round(p[0] + dx, 4), p[1]] for p in pts]

        rooms += [{**r, "name": f"home{h + 1}-{r['name']}", "polygon": moved(r["polygon"])} for r in fp["rooms"]]
        openings += [{**o, "from": moved([o["from"]])[0], "to": moved([o["to"]])[0]} for o in fp["openings"]]
        windows += [{**w, "from": moved([w["from"]])[0], "to": moved([w["to"]])[0]} for w in fp["windows"]]
        x0 += max(xs) - min(xs) + 0.3
    return {"floor_z": 0.0, "ceiling_z": CEILING, "rooms": rooms, "openings": openings, "windows": windows}


def _fan(clutter: dict[str, list], cx: float, cy: float, ceiling: float = CEILING) -> None:
    """A ceiling fan: two crossed dark blades 1.2 m long just under the ceiling and its rod
    (boxes: a fan is axis-aligned here, which is all the line detector sees of it)."""
    z0 = ceiling - 0.32
    clutter["fans"].append([cx - 0.6, cy - 0.06, z0, cx + 0.6, cy + 0.06, z0 + 0.03, 0.3, 0.0])
    clutter["fans"].append([cx - 0.06, cy - 0.6, z0, cx + 0.06, cy + 0.6, z0 + 0.03, 0.3, 0.0])
    clutter["fans"].append([cx - 0.02, cy - 0.02, z0, cx + 0.02, cy + 0.02, ceiling, 0.35, 0.0])


# things that stand on a kitchen counter: (name, width along the run, depth, height, grey level)
COUNTER_THINGS = (("microwave", 0.5, 0.36, 0.29, 0.32), ("kettle", 0.17, 0.17, 0.24, 0.88), ("toaster", 0.28, 0.17, 0.19, 0.7),
                  ("knife block", 0.12, 0.2, 0.24, 0.3), ("bottle", 0.07, 0.07, 0.3, 0.15), ("bottle", 0.07, 0.07, 0.26, 0.85),
                  ("kitchen roll", 0.12, 0.12, 0.28, 0.95), ("coffee machine", 0.25, 0.3, 0.38, 0.2),
                  ("bread bin", 0.4, 0.25, 0.2, 0.6))
COUNTER_TOP = 0.9      # the counters' height (m)
DOOR_PITCH = 0.6       # the cabinets' door width (m): their gaps lie at multiples of it (the renderer's box pattern)


def _kitchen_things(clutter: dict[str, list], rng: np.random.Generator, k0: float, length: float, south: float,
                    hood: float, door_east: float) -> None:
    """What a real kitchen holds at wall height and the map lacks (sizes in metres), added to
    ``clutter["things"]``, each named in ``clutter["thing_names"]`` (rendered as boxes; never furniture a camera keeps away from: all of
    it stands on or against the counters, the wall cabinets and the fridge, inside their
    footprints): on the south run a cooktop under the hood, a sink under a window (its frame,
    a mullion and a transom, in a gap of the wall cabinets, which ``clutter["boxes"]`` holds
    split around it), a dish rack of upright plates, and appliances, bottles and a kitchen
    roll on the free counter top; on the east run more of them; handles on every cabinet
    door (a drawer line and a bar on the base cabinets, a bar at the foot of the wall
    cabinets' doors), and the fridge's handle and freezer line, jars on the fridge, a framed
    picture on the north wall between the door (its east jamb at ``door_east``) and the fridge."""
    names = clutter.setdefault("thing_names", [])

    def add(name: str, box: list[float]) -> None:
        clutter["things"].append([float(v) for v in box])
        names.append(name)

    ys, kx1 = -south, length - 0.1            # the south wall; the south run's east end
    top = COUNTER_TOP
    # the window over the sink, east of the oven front (at k0 + 1.9..2.5): 0.8 m wide, 1.05-1.95 m up,
    # its view outside darker than the sky (a garden), a white frame, a mullion and a transom
    wx0 = float(rng.uniform(k0 + 2.5, max(k0 + 2.5, kx1 - 0.85)))
    wx1 = wx0 + 0.8
    clutter["boxes"].append([k0, ys, 1.45, wx0 - 0.05, ys + 0.35, 2.15, 0.5, DOOR_PITCH])
    if kx1 - (wx1 + 0.05) >= 0.3:
        clutter["boxes"].append([wx1 + 0.05, ys, 1.45, kx1, ys + 0.35, 2.15, 0.5, DOOR_PITCH])
    outside = 0.5 + 0.15 * rng.random()
    add("window frame", [wx0, ys, 1.05, wx1, ys + 0.02, 1.95, 0.93, 0.0])                           # the frame
    add("window panes", [wx0 + 0.05, ys, 1.1, wx1 - 0.05, ys + 0.025, 1.9, outside, 0.0])          # the panes
    add("window mullion", [(wx0 + wx1) / 2 - 0.02, ys, 1.1, (wx0 + wx1) / 2 + 0.02, ys + 0.03, 1.9, 0.93, 0.0])   # mullion
    add("window transom", [wx0 + 0.05, ys, 1.58, wx1 - 0.05, ys + 0.03, 1.62, 0.93, 0.0])                     # transom
    # a roman blind half drawn down over the panes (its folds every 0.1 m: bright lines)
    drop = float(rng.uniform(0.2, 0.45))
    add("blind", [wx0 + 0.04, ys + 0.03, 1.9 - drop, wx1 - 0.04, ys + 0.04, 1.92, 0.6, -0.1])
    # a rail under the west wall cabinets with utensils hanging from it
    if wx0 - 0.05 - k0 > 1.0:
        r0 = float(rng.uniform(k0 + 0.1, wx0 - 0.95))
        add("rail", [r0, ys + 0.03, 1.37, r0 + 0.8, ys + 0.05, 1.39, 0.3, 0.0])
        for i in range(int(rng.integers(4, 7))):
            u = r0 + 0.08 + 0.13 * i
            add("utensil", [u, ys + 0.035, 1.37 - float(rng.uniform(0.18, 0.3)), u + 0.025, ys + 0.045, 1.37,
                           0.2 if rng.random() < 0.5 else 0.8, 0.0])
    # the sink (a dark steel basin in the counter top) and its tap
    add("sink", [wx0 + 0.1, ys + 0.08, top, wx1 - 0.1, ys + 0.52, top + 0.005, 0.3, 0.0])
    tap = (wx0 + wx1) / 2
    add("tap", [tap - 0.015, ys + 0.04, top, tap + 0.015, ys + 0.07, top + 0.3, 0.25, 0.0])
    add("tap", [tap - 0.015, ys + 0.04, top + 0.27, tap + 0.015, ys + 0.24, top + 0.3, 0.25, 0.0])
    # the cooktop under the hood (dark glass)
    add("cooktop", [hood, ys + 0.05, top, hood + 0.6, ys + 0.55, top + 0.01, 0.12, 0.0])
    # a dish rack west of the sink: a low tray and five white plates on edge (vertical lines)
    rack = wx0 - 0.5
    if rack > hood + 0.62:
        add("dish rack", [rack, ys + 0.12, top, rack + 0.45, ys + 0.44, top + 0.06, 0.4, 0.0])
        for i in range(5):
            px = rack + 0.06 + 0.07 * i
            add("plate", [px, ys + 0.16, top + 0.02, px + 0.012, ys + 0.4, top + 0.25, 0.92, 0.0])
    else:
        rack = wx0 - 0.02
    # appliances and bottles on the free stretches of counter top, in a random order
    free = [(k0 + 0.05, hood - 0.03), (hood + 0.63, rack - 0.03)]
    for a, b in free:
        _on_counter(add, rng, a, b, lambda u, v, d0, d1: (u, ys + d0, v, ys + d1), run_depth=0.6)
    # the east run (along y, its wall at x = length) and its wall cabinets' doors
    e0, e1 = ys + 2.35, -0.9
    _on_counter(add, rng, e0 + 0.05, e1 - 0.05, lambda u, v, d0, d1: (length - d1, u, length - d0, v), run_depth=0.6)
    # handles: base cabinets (a drawer line 0.2 m under the top, a bar on the drawer, a bar by
    # the door's edge), wall cabinets (a bar at the foot of each door, by its edge)
    for a, b, front, base_front, along_x in ((k0, kx1, ys + 0.35, ys + 0.6, True),
                                             (e0, e1, length - 0.35, length - 0.6, False)):
        for k in range(int(math.floor(a / DOOR_PITCH)), int(math.ceil(b / DOOR_PITCH))):
            d0, d1 = max(a, k * DOOR_PITCH), min(b, (k + 1) * DOOR_PITCH)
            if d1 - d0 < 0.25:
                continue
            mid = (d0 + d1) / 2
            edge = d0 + 0.05 if k % 2 else d1 - 0.05
            # a wall cabinet above the door: the east run's all along, the south run's but in
            # the gap over the sink's window
            wall_cabinet = not along_x or d1 <= wx0 - 0.05 + 1e-9 or d0 >= wx1 + 0.05 - 1e-9
            # (name, u0, u1 along the run, z0, z1, the door's face, grey, how far it stands proud)
            on_doors = [("handle", mid - 0.08, mid + 0.08, top - 0.13, top - 0.11, base_front, 0.22, 0.025),  # drawer's bar
                        ("handle", edge - 0.012, edge + 0.012, 0.42, 0.58, base_front, 0.22, 0.025)]          # door's bar
            if wall_cabinet:
                on_doors.append(("handle", edge - 0.012, edge + 0.012, 1.5, 1.63, front, 0.22, 0.025))
            # the drawer's line across the door, 0.2 m under the counter top, and each door's
            # raised centre panel (a shaker door: its four edges are lines the map lacks)
            on_doors += [("drawer line", d0 + 0.01, d1 - 0.01, top - 0.21, top - 0.2, base_front, 0.28, 0.004),
                         ("door panel", d0 + 0.07, d1 - 0.07, 0.18, top - 0.3, base_front, 0.38, 0.008)]
            if wall_cabinet:
                on_doors.append(("door panel", d0 + 0.07, d1 - 0.07, 1.53, 2.07, front, 0.42, 0.008))
            for name, u0, u1, z0, z1, face, grey, proud in on_doors:
                if along_x:
                    add(name, [u0, face, z0, u1, face + proud, z1, grey, 0.0])
                else:
                    add(name, [face - proud, u0, z0, face, u1, z1, grey, 0.0])
    # the splashback's tiles: grout rows every 0.15 m (the splashback's vertical joints are
    # its pattern), either side of the window
    for a, b in ((k0, wx0), (wx1, kx1)):
        if b - a > 0.05:
            for z in (1.05, 1.2, 1.35):
                add("grout", [a, ys, z, b, ys + 0.015, z + 0.01, 0.42, 0.0])
    # the fridge (x length-0.7..length-0.05, y -0.8..-0.1, its door facing west): a long handle
    # and the freezer door's line
    add("fridge handle", [length - 0.725, -0.26, 0.95, length - 0.7, -0.23, 1.6, 0.3, 0.0])
    add("freezer line", [length - 0.704, -0.79, 1.3, length - 0.7, -0.11, 1.31, 0.45, 0.0])
    for i in range(int(rng.integers(1, 4))):          # jars and boxes on top of the fridge
        y0 = -0.75 + 0.2 * i
        add("jar", [length - 0.6, y0, 1.85, length - 0.45, y0 + 0.15, 1.85 + float(rng.uniform(0.12, 0.3)),
                       0.25 if i % 2 else 0.85, 0.0])
    # a framed picture on the north wall (y = 0), between the door and the fridge; 2 mm off the
    # wall's plane, which the hall's side of the wall shares (a box face in it would show through)
    if length - 0.8 - door_east > 0.7:
        px = float(rng.uniform(door_east + 0.15, length - 1.35))
        add("picture frame", [px, -0.02, 1.25, px + 0.5, -0.002, 1.75, 0.25, 0.0])
        add("picture", [px + 0.05, -0.025, 1.3, px + 0.45, -0.002, 1.7, 0.5 + 0.4 * float(rng.random()), 0.0])


def _on_counter(add: Any, rng: np.random.Generator, a: float, b: float, place: Any, run_depth: float) -> None:
    """Stand :data:`COUNTER_THINGS` in a random order on the counter stretch [a, b] (along
    the run), 0.03-0.15 m apart, each 0.04-0.1 m from the wall; those that no longer fit are
    left out; each goes to ``add(name, box)``. ``place(u0, u1, d0, d1)`` -> the plan rectangle (x0, y0, x1, y1) of a thing
    spanning u0..u1 along the run and d0..d1 out from the wall."""
    u = a + float(rng.uniform(0.0, 0.15))
    for i in rng.permutation(len(COUNTER_THINGS)):
        name, w, d, h, grey = COUNTER_THINGS[int(i)]
        if u + w > b:
            continue
        d0 = float(rng.uniform(0.04, 0.1))
        x0, y0, x1, y1 = place(u, u + w, d0, min(d0 + d, run_depth - 0.04))
        add(name, [x0, y0, COUNTER_TOP, x1, y1, COUNTER_TOP + h, grey, 0.0])
        u += w + float(rng.uniform(0.03, 0.15))


def _door_leaf(clutter: dict[str, list], rng: np.random.Generator, a: tuple[float, float], b: tuple[float, float],
               side: int) -> None:
    """A door leaf in an opening on an east-west wall: closed in the opening (a panelled
    face) or open, turned 90 degrees against the wall inside the room on ``side`` (+1 north)."""
    if rng.random() < 0.4:
        clutter["leaves"].append([a[0], a[1] + 0.02 * side, b[0], b[1] + 0.02 * side, 1.0])     # closed: panels
    else:
        clutter["boxes"].append([a[0], a[1] + (0.0 if side > 0 else -0.82), 0.0, a[0] + 0.04,
                                 a[1] + (0.82 if side > 0 else 0.0), 2.0, 0.7, 0.0])




@njit(parallel=True, cache=True)
def _raycast(pose: np.ndarray, width: int, height: int, faces: np.ndarray, boxes: np.ndarray, leaves: np.ndarray,
             blinds: np.ndarray, windows: np.ndarray, sun: np.ndarray, rooms_floor: np.ndarray, rooms_xy: np.ndarray,
             rooms_white: np.ndarray, lamps: np.ndarray, ceiling: float, out: np.ndarray) -> None:
    px, py, pz = pose[0], pose[1], pose[2]
    head = math.radians(pose[3])
    for v in prange(height):
        el = math.pi / 2.0 - math.pi * (v + 0.5) / height
        for u in range(width):
            az = head + math.pi - 2.0 * math.pi * (u + 0.5) / width
            dx = math.cos(el) * math.cos(az)
            dy = math.cos(el) * math.sin(az)
            dz = math.sin(el)
            best = 1e9
            kind = 0
            idx = -1
            if dz < -1e-9:
                best = -pz / dz
                kind = FLOOR
            elif dz > 1e-9:
                best = (ceiling - pz) / dz
                kind = CEIL
            for f in range(faces.shape[0]):
                t, s = ray_segment(px, py, dx, dy, faces[f, 0], faces[f, 1], faces[f, 2], faces[f, 3])
                if t <= 1e-6 or t >= best or s < 0.0 or s > 1.0:
                    continue
                z = pz + t * dz
                if faces[f, 4] <= z <= faces[f, 5]:
                    best = t
                    kind = WALL
                    idx = f
            for f in range(leaves.shape[0]):
                t, s = ray_segment(px, py, dx, dy, leaves[f, 0], leaves[f, 1], leaves[f, 2], leaves[f, 3])
                if t <= 1e-6 or t >= best or s < 0.0 or s > 1.0:
                    continue
                if pz + t * dz <= 2.0:
                    best = t
                    kind = LEAF
                    idx = f
            for k in range(boxes.shape[0]):
                t0 = ray_box(px, py, pz, dx, dy, dz, boxes[k], best)
                if 1e-6 < t0 < best:
                    best = t0
                    kind = BOX
                    idx = k
            qx = px + best * dx
            qy = py + best * dy
            qz = pz + best * dz
            col = 0.8
            # an all-white room (walls, ceiling and carpet in nearly one shade): the room the
            # camera side of the hit point lies in, 5 cm back along the ray
            white = False
            hx = qx - 0.05 * dx / max(math.hypot(dx, dy), 1e-9)
            hy = qy - 0.05 * dy / max(math.hypot(dx, dy), 1e-9)
            for r in range(rooms_xy.shape[0]):
                if rooms_white[r] > 0 and rooms_xy[r, 0] <= hx <= rooms_xy[r, 2] and rooms_xy[r, 1] <= hy <= rooms_xy[r, 3]:
                    white = True
            if kind == FLOOR:
                style = 0
                for r in range(rooms_xy.shape[0]):
                    if rooms_xy[r, 0] <= qx <= rooms_xy[r, 2] and rooms_xy[r, 1] <= qy <= rooms_xy[r, 3]:
                        style = int(rooms_floor[r])
                if style == 1:    # wood planks along x, 0.14 m wide, staggered joints
                    row = math.floor(qy / 0.14)
                    col = 0.5 + 0.08 * cell_hash(int(row), int(math.floor(qx / 1.2 + 0.37 * row)), 21)
                    col += 0.04 * (value_noise(qx * 0.2, qy * 8.0, 0.05, 22) - 0.5)
                    if qy / 0.14 - row < 0.04:
                        col -= 0.05
                elif style == 2:  # tiles with grout
                    col = 0.62 + 0.04 * value_noise(qx, qy, 0.05, 23)
                    if qx / 0.45 - math.floor(qx / 0.45) < 0.025 or qy / 0.45 - math.floor(qy / 0.45) < 0.025:
                        col = 0.53
                elif style == 3:  # white carpet
                    col = 0.75 + 0.03 * value_noise(qx, qy, 0.02, 24)
                else:             # carpet
                    col = 0.55 + 0.06 * value_noise(qx, qy, 0.02, 24)
                # sunlight: the floor point sees the sky through a window along the sun direction
                # (the first wall the sun ray meets must be the window's)
                first = 1e9
                for f in range(faces.shape[0]):
                    t, s = ray_segment(qx, qy, sun[0], sun[1], faces[f, 0], faces[f, 1], faces[f, 2], faces[f, 3])
                    if t > 1e-6 and 0.0 <= s <= 1.0 and faces[f, 4] <= t * sun[2] <= faces[f, 5] and t < first:
                        first = t
                for w in range(windows.shape[0]):
                    ax, ay, bx, by = windows[w, 0], windows[w, 1], windows[w, 2], windows[w, 3]
                    t, s = ray_segment(qx, qy, sun[0], sun[1], ax, ay, bx, by)
                    if t > 0.0 and 0.0 <= s <= 1.0 and t <= first + 1e-3:
                        zz = t * sun[2]
                        if windows[w, 4] <= zz <= windows[w, 5]:
                            lit = True
                            for b in range(blinds.shape[0]):  # through the slats of a blind: stripes
                                if abs(blinds[b, 0] - ax) < 1e-6 and abs(blinds[b, 1] - ay) < 1e-6 and zz >= blinds[b, 5]:
                                    lit = (zz * 20.0) - math.floor(zz * 20.0) >= 0.6
                            if lit:
                                col = min(1.0, col * (1.7 if style != 3 else 1.25))
            elif kind == CEIL:
                col = 0.87 + 0.01 * value_noise(qx, qy, 0.3, 25)
                if white:
                    col = 0.85 + 0.01 * value_noise(qx, qy, 0.3, 25)
                for k in range(lamps.shape[0]):
                    if lamps[k, 0] <= qx <= lamps[k, 2] and lamps[k, 1] <= qy <= lamps[k, 3]:
                        col = 0.98
                        if min(qx - lamps[k, 0], lamps[k, 2] - qx, qy - lamps[k, 1], lamps[k, 3] - qy) < 0.03:
                            col = 0.7  # the lamp's rim
            elif kind == WALL:
                # one paint everywhere; faces along x a little brighter than along y (light from the south)
                ex = faces[idx, 2] - faces[idx, 0]
                ey = faces[idx, 3] - faces[idx, 1]
                along_x = abs(ex) / max(math.hypot(ex, ey), 1e-9)
                col = 0.78 + 0.04 * along_x + 0.012 * (value_noise(qx + qy, qz, 0.4, 26) - 0.5)
                if white:
                    col = 0.8 + 0.03 * along_x + 0.012 * (value_noise(qx + qy, qz, 0.4, 26) - 0.5)
                if qz < 0.09:                      # skirting board (white on white in a white room)
                    col = 0.93 if not white else 0.85
                    if qz > 0.08 and not white:
                        col = 0.7
                for w in range(windows.shape[0]):
                    ax, ay, bx, by = windows[w, 0], windows[w, 1], windows[w, 2], windows[w, 3]
                    lw = math.hypot(bx - ax, by - ay)
                    s = ((qx - ax) * (bx - ax) + (qy - ay) * (by - ay)) / max(lw * lw, 1e-9)
                    off = abs((qx - ax) * (by - ay) - (qy - ay) * (bx - ax)) / max(lw, 1e-9)
                    if off < 0.02 and 0.0 <= s <= 1.0 and windows[w, 4] <= qz <= windows[w, 5]:
                        m = 0.05 / max(lw, 1e-9)
                        if s < m or s > 1 - m or qz < windows[w, 4] + 0.05 or qz > windows[w, 5] - 0.05:
                            col = 0.95             # the frame
                        else:
                            col = 0.97 - 0.1 * value_noise(s * lw, qz, 0.3, 27)   # bright sky / outside
                            for b in range(blinds.shape[0]):
                                if abs(blinds[b, 0] - ax) < 1e-6 and abs(blinds[b, 1] - ay) < 1e-6 and qz >= blinds[b, 5]:
                                    slat = (qz * 20.0) - math.floor(qz * 20.0)
                                    col = 0.88 if slat < 0.7 else 0.62
            elif kind == LEAF:
                ax, ay = leaves[idx, 0], leaves[idx, 1]
                s = math.hypot(qx - ax, qy - ay)
                col = 0.9
                # two raised panels: their edges are lines the map does not have
                inset = 0.12 < s < 0.73 and (0.15 < qz < 0.95 or 1.1 < qz < 1.9)
                edge = inset and (abs(s - 0.12) < 0.02 or abs(s - 0.73) < 0.02 or abs(qz - 0.15) < 0.02
                                  or abs(qz - 0.95) < 0.02 or abs(qz - 1.1) < 0.02 or abs(qz - 1.9) < 0.02)
                if edge:
                    col = 0.72
                if abs(s - 0.72) < 0.03 and abs(qz - 1.0) < 0.03:
                    col = 0.3  # handle
            elif kind == BOX:
                base = boxes[idx, 6]
                col = base + 0.03 * value_noise(qx + qy, qz, 0.1, 28)
                if abs(qz - boxes[idx, 5]) < 1e-3:
                    col = base + 0.12
                if boxes[idx, 7] > 0.0:   # cabinet/wardrobe doors every 0.6 m: dark gaps
                    s = qx if abs(dy) > abs(dx) else qy
                    if (s / boxes[idx, 7]) - math.floor(s / boxes[idx, 7]) < 0.02:
                        col -= 0.2
                elif boxes[idx, 7] < 0.0:  # shelves every -b7 m: bright shelf edges over dark rows of books
                    pitch = -boxes[idx, 7]
                    if (qz / pitch) - math.floor(qz / pitch) < 0.06:
                        col += 0.35
            col *= 1.0 / (1.0 + 0.02 * best)
            out[v, u] = col


def render_panorama(pose: np.ndarray, scene: dict[str, np.ndarray], width: int, height: int) -> np.ndarray:
    """Grey equirectangular panorama (float, 0..1) of the home from ``pose`` (x, y, z, heading_deg)."""
    out = np.zeros((height, width))
    _raycast(np.asarray(pose, float), width, height, scene["faces"], scene["boxes"], scene["leaves"], scene["blinds"],
             scene["windows"], scene["sun"], scene["rooms_floor"], scene["rooms_xy"], scene["rooms_white"], scene["lamps"],
             float(scene["ceiling"]), out)
    return out


def scene_arrays(fp: dict[str, Any], clutter: dict[str, Any], rng: np.random.Generator) -> dict[str, np.ndarray]:
    model = floor_plan_model(fp)
    rooms_xy = np.array([[*np.min(r["polygon"], axis=0), *np.max(r["polygon"], axis=0)] for r in fp["rooms"]], float)
    styles = {"hall": 1, "living": 1, "kitchen": 2, "bonus": 3}
    rooms_floor = np.array([styles.get(r["name"], 0) for r in fp["rooms"]], float)
    rooms_white = np.array([r["name"] == "bonus" for r in fp["rooms"]], float)
    sun_az = math.radians(rng.uniform(210.0, 330.0))   # from the south: it shines through the south windows
    sun_el = math.radians(rng.uniform(25, 50))
    sun = np.array([math.cos(sun_az), math.sin(sun_az), math.tan(sun_el)])  # plan direction, rise per metre
    return {"faces": model.faces,
            "boxes": np.asarray(clutter["boxes"] + clutter["fans"] + clutter["flat"] + clutter.get("things", []),
                                float).reshape(-1, 8),
            "leaves": np.asarray(clutter["leaves"], float).reshape(-1, 5),
            "blinds": np.asarray(clutter["blinds"], float).reshape(-1, 6),
            "windows": np.array([[*w["from"], *w["to"], w["sill"], w["top"]] for w in fp["windows"]], float).reshape(-1, 6),
            "sun": sun, "rooms_floor": rooms_floor, "rooms_xy": rooms_xy, "rooms_white": rooms_white,
            "lamps": np.asarray(clutter["lamps"], float).reshape(-1, 4),
            "ceiling": np.float64(fp["ceiling_z"])}


# the figures of a real home (a held-out Zillow Indoor Dataset tour, 32 panoramas) the
# generator is built to match: detected line pixels on map lines, map line pixels detected,
# off-map detected pixels more than 60 degrees below the horizon
# (the real home re-measured: 26 %, the earlier 35 % counted the tripod's rim), and the lowest
# share on map lines of any one panorama (its kitchen: cabinets at wall height)
REAL_HOME_STATS = {"detected_on_map": 0.43, "map_detected": 0.66, "off_map_below_60": 0.26, "detected_on_map_lowest": 0.20}


# how the line statistics' detected lines are found: as the real home's were, LSD on the
# photos as they are, not as localize finds them (umap.panorama.equalize_clip, 1 by default,
# equalises each face's contrast first and detects more of the map's lines)
LINES_AS_MEASURED = "LSD on the photos as they are (8 px or longer, contrast not equalised), as the real home's were measured"


def line_agreement(query_lines: np.ndarray, map_lines: np.ndarray) -> tuple[float, float, float]:
    """(share of detected line pixels within one pixel of a map line, share of map line
    pixels within one pixel of a detected line, share of the detected pixels off the map
    that lie more than 60 degrees below the horizon) of two equirectangular binary images
    of the same size."""
    near = np.ones((3, 3), np.uint8)
    q, m = (query_lines > 0).astype(np.uint8), (map_lines > 0).astype(np.uint8)
    on = q & cv2.dilate(m, near)
    on_map = float(on.sum()) / max(int(q.sum()), 1)
    found = float((m & cv2.dilate(q, near)).sum()) / max(int(m.sum()), 1)
    off = q & (1 - on)
    el = 90.0 - 180.0 * (np.arange(q.shape[0]) + 0.5) / q.shape[0]
    below = float(off[el < -60.0].sum()) / max(int(off.sum()), 1)
    return on_map, found, below


def doorway_poses(fp: dict[str, Any], clutter: dict[str, Any], rng: np.random.Generator, count: int) -> np.ndarray:
    """``count`` camera positions in doorways, as real tours photograph closets and
    bathrooms from the door: inside a door (an opening narrower than 1.2 m) whose leaf is
    not closed, 40-70 % along it (away from the hinge of an open leaf) and 0.02-0.12 m from the wall line (from the lintel face)
    on either side."""
    doors = []
    for o in fp["openings"]:
        a, b = np.asarray(o["from"], float), np.asarray(o["to"], float)
        closed = any(abs(lf[0] - a[0]) < 0.01 and abs(lf[1] - lf[3]) < 1e-6 and abs(lf[1] - a[1]) < 0.05
                     for lf in clutter["leaves"])
        if np.hypot(*(b - a)) < 1.2 and not closed:
            doors.append((a, b))
    out = []
    for i in range(count if doors else 0):
        a, b = doors[i % len(doors)]
        e = (b - a) / np.hypot(*(b - a))
        n = np.array([-e[1], e[0]]) * rng.choice([-1.0, 1.0])
        out.append(a + (b - a) * rng.uniform(0.4, 0.7) + n * rng.uniform(0.02, 0.12))
    return np.asarray(out, float).reshape(-1, 2)


def near_wall_poses(fp: dict[str, Any], clutter: dict[str, Any], rng: np.random.Generator, count: int, z: float,
                    rooms: tuple[str, ...] = ("kitchen", "bonus")) -> np.ndarray:
    """``count`` camera positions 0.4-0.6 m from a wall that spans the camera height ``z``,
    in the named rooms in turn (a real tour's kitchen camera stood 0.5 m from a wall, where
    the map's line image changes fastest with position), clear of the furniture by 0.15 m."""
    model = floor_plan_model(fp)
    walls = blocking_faces(model.faces, z)
    boxes = np.asarray(clutter["boxes"], float).reshape(-1, 8)
    out = []
    for i in range(count):
        poly = np.asarray(next(r["polygon"] for r in fp["rooms"] if r["name"] == rooms[i % len(rooms)]), float)
        cand = rng.uniform(poly.min(axis=0), poly.max(axis=0), size=(2000, 2))
        keep, _ = free_space_mask(cand, model, inside_only=True, wall_margin_m=0.4, z=z)
        d = wall_distance(cand, walls)
        keep &= (d <= 0.6) & point_in_polygon(cand, poly)
        for b in boxes:
            keep &= ~((cand[:, 0] > b[0] - 0.15) & (cand[:, 0] < b[3] + 0.15) & (cand[:, 1] > b[1] - 0.15) & (cand[:, 1] < b[4] + 0.15))
        if keep.any():
            out.append(cand[rng.choice(np.flatnonzero(keep))])
    return np.asarray(out, float).reshape(-1, 2)


def cabinet_poses(fp: dict[str, Any], clutter: dict[str, Any], rng: np.random.Generator, count: int,
                  z: float) -> np.ndarray:
    """``count`` kitchen camera positions beside the cabinets: 0.15-0.35 m in front of a
    counter run (the runs in turn), at least 0.3 m in from its ends, clear of the furniture in
    front of the run by 0.15 m and of the walls spanning the camera height ``z`` by 0.3 m.
    Why: a real tour's kitchen camera stood beside the cabinets, where counters, wall
    cabinets and appliances fill the view at wall height and only 20 % of its detected line
    pixels lie on map lines; cameras in the middle of the generated kitchens saw 31-41 %."""
    model = floor_plan_model(fp)
    counters = np.asarray(clutter.get("counters", []), float).reshape(-1, 6)
    boxes = np.asarray(clutter["boxes"], float).reshape(-1, 8)
    out = []
    for i in range(count if len(counters) else 0):
        a, b, n = counters[i % len(counters), :2], counters[i % len(counters), 2:4], counters[i % len(counters), 4:]
        length = float(np.hypot(*(b - a)))
        t = rng.uniform(0.3, max(0.3, length - 0.3), size=400) / max(length, 1e-9)
        cand = a + np.outer(t, b - a) + np.outer(rng.uniform(0.15, 0.35, size=400), n)
        keep, _ = free_space_mask(cand, model, inside_only=True, wall_margin_m=0.3, z=z)
        for box in boxes:
            corners = np.array([[box[0], box[1]], [box[0], box[4]], [box[3], box[1]], [box[3], box[4]]])
            if ((corners - a) @ n).max() <= 1e-6:
                continue   # behind the run's front: the counter and the cabinets the camera stands beside
            keep &= ~((cand[:, 0] > box[0] - 0.15) & (cand[:, 0] < box[3] + 0.15) & (cand[:, 1] > box[1] - 0.15)
                      & (cand[:, 1] < box[4] + 0.15))
        if keep.any():
            out.append(cand[rng.choice(np.flatnonzero(keep))])
    return np.asarray(out, float).reshape(-1, 2)


def room_name(fp: dict[str, Any], x: float, y: float) -> str:
    """The name of the room holding plan point (x, y) (a doorway: the nearest room's)."""
    polys = [np.asarray(r["polygon"], float) for r in fp["rooms"]]
    for r, poly in zip(fp["rooms"], polys):
        if point_in_polygon(np.array([[x, y]]), poly)[0]:
            return str(r["name"])
    d = [wall_distance(np.array([[x, y]]), np.column_stack([poly, np.roll(poly, -1, 0)]))[0] for poly in polys]
    return str(fp["rooms"][int(np.argmin(d))]["name"])


def photo_sphere_jpeg(gray: np.ndarray, crop: PanoramaCrop) -> bytes:
    """A JPEG (quality 95) of a cropped photo sphere with its Photo Sphere XMP metadata in an
    APP1 segment right after the start marker, as a phone stores it (the GPano properties
    :func:`placeloc.core.images.panorama_crop` reads)."""
    props = {"ProjectionType": "equirectangular", "FullPanoWidthPixels": crop.full_width,
             "FullPanoHeightPixels": crop.full_height, "CroppedAreaLeftPixels": crop.left,
             "CroppedAreaTopPixels": crop.top, "CroppedAreaImageWidthPixels": crop.width,
             "CroppedAreaImageHeightPixels": crop.height}
    xmp = ('<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
           '<rdf:Description rdf:about="" xmlns:GPano="http://ns.google.com/photos/1.0/panorama/" '
           + " ".join(f'GPano:{k}="{v}"' for k, v in props.items()) + "/></rdf:RDF></x:xmpmeta>").encode()
    payload = b"http://ns.adobe.com/xap/1.0/\x00" + xmp
    data = cv2.imencode(".jpg", gray, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    return data[:2] + b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload + data[2:]


def generate(out_dir: Path, seed: int = 0, panoramas: int = 20, width: int = 1024, bedrooms: int = 3, z: float = 1.5,
             noise: float = 2.0, blur: float = 0.7, stats_width: int = 256, doorway_share: float = 0.2,
             near_wall_share: float = 0.1, cabinet_share: float = 0.05, kitchen_things: bool = True,
             z_spread: float = 0.03, tilt_deg: float = 0.0, cover_low_deg: float = -90.0, cover_high_deg: float = 90.0,
             ceiling: float = CEILING, **unknown: Any) -> dict[str, Any]:
    """Write the home, its panoramas, their ground truth and the line statistics under
    ``out_dir``; ``doorway_share`` of the panoramas are taken in doorways (real tours: 6 of
    32 cameras within 0.12 m of a door's lintel face), ``near_wall_share`` 0.4-0.6 m from a
    wall in the kitchen and the bonus room (:func:`near_wall_poses`), ``cabinet_share`` (the
    last ones) in the kitchen beside the cabinets (:func:`cabinet_poses`; drawn from a
    generator of their own, so that the other panoramas are those of a home without them);
    ``kitchen_things``: the counters hold appliances, a sink under a window, a dish rack and
    handles on the doors (:func:`_kitchen_things`, from a generator of their own: the poses and
    the rooms outside the kitchen are those of the home without them). Each camera stands at
    ``z`` +- ``z_spread`` m (uniform; 0.03: a tripod's; 0.25 around 1.45: photos taken with a
    phone held by hand, each at its own height), the plan's ``camera_z`` at ``z``.
    ``tilt_deg`` > 0: each camera tilted by an angle uniform in 0..``tilt_deg`` about a
    horizontal axis of uniform direction (a hand-held 360 degree photo not quite level),
    drawn from a generator of its own (0: the level home, the same images), and
    ``poses.csv`` gains the columns ``tilt_deg`` and ``tilt_axis_deg`` (the axis's plan
    direction, degrees counterclockwise from the camera's heading). ``cover_low_deg`` /
    ``cover_high_deg`` other than -90 / 90: each panorama is stored as a photo sphere that
    covered only the elevations between them (a phone's sphere without its floor or ceiling
    cap): cropped to those rows, as JPEG (quality 95) with its Photo Sphere metadata
    (:func:`photo_sphere_jpeg`), named ``pano_NNN.jpg``. ``ceiling``: the rooms' ceiling
    height in metres, 2.3-3.5 (2.5 by default; another gives the same plan, poses and
    clutter, the fans hung from it)."""
    if unknown:
        raise TypeError(f"unknown home parameter(s) {', '.join(unknown)}; known: panoramas, width, bedrooms, z, z_spread, tilt_deg, "
                        "ceiling, cover_low_deg, cover_high_deg, noise, "
                        "blur, stats_width, doorway_share, near_wall_share, cabinet_share, kitchen_things")
    if not -90.0 <= cover_low_deg < cover_high_deg <= 90.0:
        raise ValueError(f"cover_low_deg {cover_low_deg} and cover_high_deg {cover_high_deg}: need -90 <= low < high <= 90")
    if not 2.3 <= ceiling <= 3.5:   # the doors, windows and wall cabinets reach 2.15-2.2 m
        raise ValueError(f"ceiling {ceiling}: give a height in metres between 2.3 and 3.5")
    out_dir = Path(out_dir)
    (out_dir / "panoramas").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    fp, clutter = plan(rng, bedrooms, things_rng=np.random.default_rng([seed, 2]) if kitchen_things else None,
                       ceiling=ceiling)
    fp["camera_z"] = z   # the tripod's height, as the ZInD importer writes it
    (out_dir / "floor_plan.yaml").write_text(yaml.safe_dump(fp, sort_keys=False))
    model = floor_plan_model(fp)
    scene = scene_arrays(fp, clutter, rng)
    lo, hi = np.min([np.min(r["polygon"], axis=0) for r in fp["rooms"]], axis=0), np.max([np.max(r["polygon"], axis=0) for r in fp["rooms"]], axis=0)
    # free-space poses, away from walls and out of the furniture
    cand = rng.uniform(lo, hi, size=(4000, 2))
    keep, _ = free_space_mask(cand, model, inside_only=True, wall_margin_m=0.5)
    boxes = np.asarray(clutter["boxes"], float).reshape(-1, 8)   # furniture (a camera may stand under a fan)
    for b in boxes:
        keep &= ~((cand[:, 0] > b[0] - 0.3) & (cand[:, 0] < b[3] + 0.3) & (cand[:, 1] > b[1] - 0.3) & (cand[:, 1] < b[4] + 0.3))
    n_door = int(round(doorway_share * panoramas))
    n_wall = int(round(near_wall_share * panoramas))
    n_cab = int(round(cabinet_share * panoramas))
    cabinets = cabinet_poses(fp, clutter, np.random.default_rng([seed, 1]), n_cab, z)
    cand = np.concatenate([np.concatenate([doorway_poses(fp, clutter, rng, n_door),
                                           near_wall_poses(fp, clutter, rng, n_wall, z),
                                           cand[keep]])[:panoramas - len(cabinets)], cabinets])
    if len(cand) < panoramas:
        raise ValueError(f"only {len(cand)} free-space poses found for {panoramas} panoramas; ask for fewer")
    height = width // 2
    sh = stats_width // 2
    on_map, found, below, where = [], [], [], []
    written = []
    tilt_rng = np.random.default_rng([seed, 3])
    with open(out_dir / "poses.csv", "w", newline="") as fpz:
        w = csv.writer(fpz)
        w.writerow(["frame", "x", "y", "z", "heading_deg", *(["tilt_deg", "tilt_axis_deg"] if tilt_deg > 0 else [])])
        for i, (x, y) in enumerate(cand):
            heading = float(rng.uniform(0, 360))
            zz = z + float(rng.uniform(-z_spread, z_spread))
            img = render_panorama(np.array([x, y, zz, heading]), scene, width, height)
            # the tripod's base right under the camera (a dark disk below -78 deg, its rim a circle of lines)
            img[int(height * (90 + 78) / 180):] *= 0.45
            tilt = (float(tilt_rng.uniform(0.0, tilt_deg)), float(tilt_rng.uniform(0.0, 360.0))) if tilt_deg > 0 else None
            turn = None
            if tilt:   # the camera's frame (azimuths from its heading) turned about a horizontal axis
                a = math.radians(tilt[1])
                turn = axis_rotation(np.array([math.cos(a), math.sin(a), 0.0]), tilt[0])
                img = turn_panorama(img, turn)
            img = np.clip(img * 255.0 + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8)
            if blur > 0:
                img = cv2.GaussianBlur(img, (0, 0), blur)
            if (cover_low_deg, cover_high_deg) == (-90.0, 90.0):
                name = f"pano_{i:03d}.png"
                cv2.imwrite(str(out_dir / "panoramas" / name), img)
            else:
                name = f"pano_{i:03d}.jpg"
                top, bottom = (int(round((90.0 - e) / 180.0 * height)) for e in (cover_high_deg, cover_low_deg))
                (out_dir / "panoramas" / name).write_bytes(
                    photo_sphere_jpeg(img[top:bottom], PanoramaCrop(width, height, 0, top, width, bottom - top)))
            w.writerow([name, f"{x:.4f}", f"{y:.4f}", f"{zz:.4f}", f"{heading:.2f}",
                        *([f"{tilt[0]:.3f}", f"{tilt[1]:.2f}"] if tilt else [])])
            written.append({"frame": name, "x": float(x), "y": float(y), "z": zz, "heading_deg": heading})
            # the statistics of the scene at the true pose: a tilted camera's lines drawn levelled by its known tilt
            q = draw_line_image(panorama_lines(img, face_px=width // 4, min_length=8.0), face_px=width // 4,
                                width=stats_width, height=sh, rotation=turn)
            m = render_panoramas(model.segments, model.faces, np.array([[x, y, zz, heading]]), width=stats_width, height=sh,
                                 hidden=True)
            bits = np.unpackbits(m.view(np.uint8), bitorder="little")[: sh * stats_width].reshape(sh, stats_width)
            a, b, c = line_agreement(q, bits)
            where.append(room_name(fp, float(x), float(y)))
            on_map.append(a)
            found.append(b)
            below.append(c)
    write_zind(fp, written, out_dir / "zind_data.json", image_dir="panoramas")
    stats = {"detected_on_map": float(np.median(on_map)), "map_detected": float(np.median(found)),
             "off_map_below_60": float(np.median(below)),
             "detected_on_map_range": [float(np.min(on_map)), float(np.max(on_map))],
             "map_detected_range": [float(np.min(found)), float(np.max(found))],
             "off_map_below_60_range": [float(np.min(below)), float(np.max(below))], "n_panoramas": len(cand),
             "detected_on_map_lowest": float(np.min(on_map)), "detected_on_map_each": [round(a, 4) for a in on_map],
             "detected_on_map_by_room": {r: float(np.median([a for a, w in zip(on_map, where) if w == r]))
                                         for r in sorted(set(where))},
             "rooms_of_panoramas": where, "near_wall_panoramas": min(n_wall, max(0, len(cand) - n_door)),
             "cabinet_panoramas": len(cabinets),
             "doorway_panoramas": min(n_door, len(cand)), "at": f"{stats_width}x{sh} equirectangular, within 1 px",
             "lines": LINES_AS_MEASURED,
             "real_home": REAL_HOME_STATS}
    (out_dir / "line_stats.json").write_text(json.dumps(stats, indent=2) + "\n")
    real = REAL_HOME_STATS
    return {"out": str(out_dir), "panoramas": len(cand), "in doorways": stats["doorway_panoramas"], "rooms": len(fp["rooms"]),
            "segments": len(model.segments), "faces": len(model.faces), "line statistics": LINES_AS_MEASURED,
            "detected line pixels on map lines (median; real home)": f"{stats['detected_on_map']:.0%} ({real['detected_on_map']:.0%})",
            "map line pixels detected (median; real home)": f"{stats['map_detected']:.0%} ({real['map_detected']:.0%})",
            "off-map pixels > 60 deg below the horizon (median; real home)":
                f"{stats['off_map_below_60']:.0%} ({real['off_map_below_60']:.0%})",
            "detected line pixels on map lines, lowest panorama (real home)":
                f"{stats['detected_on_map_lowest']:.0%} ({real['detected_on_map_lowest']:.0%})"}
