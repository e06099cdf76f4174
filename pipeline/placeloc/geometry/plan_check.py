"""The one geometry validator for floor plans: every plan the floor-plan loader builds a
model from (a YAML plan, a ZInD home, a generated home) and every plan the ZInD importer
writes passes through :func:`check_plan` first.

It refuses, naming the file, the element and the fix: a coordinate or height that is not a
finite number (NaN, infinity, a string, a bool); a polygon with fewer than three distinct
points, no area, or edges that cross or touch (a self-intersecting outline: inside and
outside are no longer defined); a ceiling not above its floor; a camera height, door height
or window that is not above the floor. A leaf (it imports only :mod:`placeloc.core.errors`),
so the loader and the importer need not import each other.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from placeloc.core.errors import ModelError
from placeloc.core.params import text_number_hint


def number(value: Any, source: str, what: str, *, positive: bool = False) -> float:
    """``value`` as a finite float (a positive one with ``positive``), else a ModelError
    naming ``what``. A bool or a string is not a number here, as in a config."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok:
        raise ModelError(f"{source}: {what} = {value!r} is not a finite number{text_number_hint(value)}; write it as a "
                         "number (metres)")
    if positive and value <= 0:
        raise ModelError(f"{source}: {what} = {value!r} must be above 0")
    return float(value)


def point(value: Any, source: str, what: str) -> np.ndarray:
    """``[x, y]`` as two finite floats."""
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ModelError(f"{source}: {what} = {value!r} is not a point [x, y]; write two numbers (metres)")
    return np.array([number(v, source, f"{what}[{i}]") for i, v in enumerate(value)])


def polygon(value: Any, source: str, what: str) -> np.ndarray:
    """A simple polygon of at least three distinct finite points with a non-zero area, as an
    (n, 2) float array (the points as given; repeated consecutive points are allowed and
    ignored by the checks)."""
    if not isinstance(value, (list, tuple)) or len(value) < 3:
        raise ModelError(f"{source}: {what} must be a list of at least three [x, y] points")
    pts = np.stack([point(p, source, f"{what}[{i}]") for i, p in enumerate(value)])
    distinct = pts[np.any(pts != np.roll(pts, 1, axis=0), axis=1)]
    if len(distinct) < 3:
        raise ModelError(f"{source}: {what} has fewer than three distinct points; a room or block needs an area")
    span = float(np.hypot(*(distinct.max(0) - distinct.min(0))))
    d = distinct - distinct[0]
    far = d[np.argmax(np.hypot(d[:, 0], d[:, 1]))]
    if np.abs(d[:, 0] * far[1] - d[:, 1] * far[0]).max() <= 1e-9 * span * span:
        raise ModelError(f"{source}: {what} has zero area (its points lie on one line); fix its coordinates")
    crossing = _first_crossing(distinct)
    if crossing is not None:
        i, j = crossing
        n = len(distinct)
        raise ModelError(f"{source}: {what} is self-intersecting: its edge {distinct[i].tolist()} -> "
                         f"{distinct[(i + 1) % n].tolist()} meets the edge {distinct[j].tolist()} -> "
                         f"{distinct[(j + 1) % n].tolist()}; an outline must not cross or touch itself (fix the order "
                         "of its points, or split it into rooms)")
    return pts


def _first_crossing(pts: np.ndarray) -> tuple[int, int] | None:
    """The first pair of edges (i, j), i < j, that meet where they must not: non-adjacent
    edges that share any point, or adjacent edges that fold back over each other."""
    n = len(pts)
    a, b = pts, np.roll(pts, -1, axis=0)
    scale = float(np.abs(pts).max()) or 1.0
    eps = 1e-12 * scale * scale

    def orient(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
        v = (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])
        return np.where(np.abs(v) <= eps, 0.0, np.sign(v))

    def on_segment(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
        """r on the closed segment p-q, given the three are collinear."""
        return ((np.minimum(p[..., 0], q[..., 0]) <= r[..., 0]) & (r[..., 0] <= np.maximum(p[..., 0], q[..., 0]))
                & (np.minimum(p[..., 1], q[..., 1]) <= r[..., 1]) & (r[..., 1] <= np.maximum(p[..., 1], q[..., 1])))

    i, j = np.triu_indices(n, k=1)
    p1, q1, p2, q2 = a[i], b[i], a[j], b[j]
    d1, d2, d3, d4 = orient(p2, q2, p1), orient(p2, q2, q1), orient(p1, q1, p2), orient(p1, q1, q2)
    meet = ((d1 * d2 < 0) & (d3 * d4 < 0)) | ((d1 == 0) & on_segment(p2, q2, p1)) | ((d2 == 0) & on_segment(p2, q2, q1)) \
        | ((d3 == 0) & on_segment(p1, q1, p2)) | ((d4 == 0) & on_segment(p1, q1, q2))
    adjacent = (j == i + 1) | ((i == 0) & (j == n - 1))
    # Adjacent edges share a vertex by construction; they are wrong only when they fold back
    # (collinear, pointing opposite ways: a spike of zero width).
    e1, e2 = q1 - p1, q2 - p2
    collinear = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) <= eps
    folds = adjacent & collinear & ((e1 * e2).sum(1) < 0)
    bad = np.flatnonzero((meet & ~adjacent) | folds)
    return (int(i[bad[0]]), int(j[bad[0]])) if len(bad) else None


def _items(plan: dict[str, Any], key: str, source: str, form: str) -> list[Any]:
    items = plan.get(key)
    if items is None:
        return []
    if not isinstance(items, list):
        raise ModelError(f"{source}: {key} must be a list of {form}")
    return items


def _gap_or_window(item: Any, source: str, what: str, heights: tuple[str, ...]) -> None:
    if not isinstance(item, dict):
        raise ModelError(f"{source}: {what} must be a mapping {{from: [x, y], to: [x, y], {', '.join(heights)}: ...}}")
    for end in ("from", "to"):
        if end not in item:
            raise ModelError(f"{source}: {what} needs {end}: [x, y]")
        point(item[end], source, f"{what}.{end}")
    values = {h: number(item[h], source, f"{what}.{h}", positive=h == "height") for h in heights if item.get(h) is not None}
    if "sill" in values and "top" in values and values["top"] <= values["sill"]:
        raise ModelError(f"{source}: {what}: top {values['top']} must be above sill {values['sill']}")


def check_plan(plan: Any, source: str = "floor plan") -> None:
    """Refuse a floor plan (outline or multi-room form, see :mod:`placeloc.geometry.floorplan`)
    whose numbers or polygons are not real geometry; the message names the element."""
    if not isinstance(plan, dict):
        raise ModelError(f"{source}: a floor plan must be a mapping with 'outline' or 'rooms'")
    floor_z = number(plan.get("floor_z", 0.0), source, "floor_z")
    ceiling_z = number(plan["ceiling_z"], source, "ceiling_z") if plan.get("ceiling_z") is not None else None
    if ceiling_z is not None and ceiling_z <= floor_z:
        raise ModelError(f"{source}: ceiling_z {ceiling_z} must be above floor_z {floor_z}")
    if plan.get("camera_z") is not None:
        number(plan["camera_z"], source, "camera_z (the camera's height above the floor)", positive=True)
    for i, door in enumerate(_items(plan, "doors", source, "{from: [x, y], to: [x, y], height: ...}")):
        _gap_or_window(door, source, f"doors[{i}]", ("height",))
    if "rooms" not in plan:
        if ceiling_z is None:
            raise ModelError(f"{source}: the floor plan needs ceiling_z (metres)")
        polygon(plan.get("outline"), source, "outline")
        for i, block in enumerate(_items(plan, "obstacles", source, "polygons [[[x, y], ...], ...]")):
            polygon(block, source, f"obstacles[{i}]")
        return
    rooms = plan["rooms"]
    if not isinstance(rooms, list) or not rooms:
        raise ModelError(f"{source}: rooms must be a non-empty list of {{polygon: [[x, y], ...], ceiling_z: ...}}")
    for i, item in enumerate(_items(plan, "openings", source, "{from: [x, y], to: [x, y], height: ...}")):
        _gap_or_window(item, source, f"openings[{i}]", ("height",))
    for i, item in enumerate(_items(plan, "windows", source, "{from: [x, y], to: [x, y], sill: ..., top: ...}")):
        _gap_or_window(item, source, f"windows[{i}]", ("sill", "top"))
    for r, room in enumerate(rooms):
        what = f"rooms[{r}]" + (f" ({room.get('name')})" if isinstance(room, dict) and room.get("name") else "")
        if not isinstance(room, dict) or "polygon" not in room:
            raise ModelError(f"{source}: {what} needs a polygon: [[x, y], ...]")
        polygon(room["polygon"], source, f"{what}.polygon")
        zf = number(room["floor_z"], source, f"{what}.floor_z") if room.get("floor_z") is not None else floor_z
        if room.get("ceiling_z") is None and ceiling_z is None:
            raise ModelError(f"{source}: {what} needs a ceiling_z (or give one for the whole plan)")
        zc = number(room["ceiling_z"], source, f"{what}.ceiling_z") if room.get("ceiling_z") is not None else ceiling_z
        if zc <= zf:
            raise ModelError(f"{source}: {what}: ceiling_z {zc} must be above floor_z {zf}")
        blocks = room.get("internal")
        if blocks is not None and not isinstance(blocks, list):
            raise ModelError(f"{source}: {what}.internal must be a list of polygons [[[x, y], ...], ...]")
        for j, block in enumerate(blocks or []):
            polygon(block, source, f"{what}.internal[{j}]")
