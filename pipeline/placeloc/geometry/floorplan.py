"""Building models: a 3-D wireframe (line segments) and optional wall faces, read from a
wireframe file (YAML/JSON/OBJ) or built from a floor plan (YAML); plan-space helpers
(inside test, distance to the nearest wall).

Wireframe YAML/JSON: either a list of segments ``[x0, y0, z0, x1, y1, z1]`` or a mapping
``{segments: [...], faces: [[x0, y0, x1, y1, z0, z1], ...]}``. OBJ: ``v x y z`` vertices
and ``l i j [k ...]`` polylines (1-based, negative indices relative); other records ignored.

Floor plan YAML (``outline`` key present)::

    floor_z: 0.0
    ceiling_z: 2.6
    outline: [[x, y], ...]           # free-space boundary, walls along its edges
    obstacles: [[[x, y], ...], ...]  # pillars / blocks inside (walls along their edges)
    doors: [{from: [x, y], to: [x, y], height: 2.0}, ...]   # door frames on a wall

From it we build floor and ceiling edges, wall corners (verticals at every vertex) and
door frames (two jambs and a lintel), and one vertical wall face per polygon edge.

Multi-room floor plan YAML (``rooms`` key present; the format the ZInD importer writes and
the one to use for a plan drawn by hand)::

    floor_z: 0.0                     # default for rooms that do not give their own
    ceiling_z: 2.6
    camera_z: 1.5                    # optional: the camera height above the floor (the grid's z)
    rooms:
      - name: kitchen
        polygon: [[x, y], ...]       # the room's walls, in metres, any orientation
        ceiling_z: 2.4               # floor_z / ceiling_z optional
        internal: [[[x, y], ...]]    # optional: wall blocks inside the room (a kitchen wall, a pillar)
    doors:                           # doors: real gaps in the wall under a lintel
      - {from: [x, y], to: [x, y], height: 2.0}
    openings:                        # openings (archways, open plan): gaps like doors, often ceiling-high
      - {from: [x, y], to: [x, y], height: 2.6}
    windows:                         # frames on the wall (the wall face stays opaque)
      - {from: [x, y], to: [x, y], sill: 0.9, top: 2.1}

Each room's polygon edges are walls with its own floor and ceiling height. A door or
opening on an edge (both ends within 1 cm of it) cuts the floor line and the wall face
there, leaves the wall face above it (if lower than the ceiling: the lintel) and adds its
two jambs and lintel. A wall shared by two rooms is drawn by both (the same pixels). Each
``internal`` polygon is a block of wall from floor to ceiling: its edges are wall faces
with their floor, ceiling and corner lines, and its inside is not free space. Grid
positions are free space when inside any room (outside its internal blocks) or in a
doorway: between the ends of a door or opening and at most ``GAP_DEPTH_M`` from its wall
line (real walls have a thickness, and each room's polygon stops at its own side).

Faces are vertical rectangles ``[x0, y0, x1, y1, z0, z1]`` (a wall from (x0, y0) to
(x1, y1), from height z0 to z1). That is what a floor plan gives, and it lets hidden-line
removal run as a cheap 2-D ray/segment test plus a height check. Floor and ceiling never
hide anything from a camera inside the storey, so they need no faces.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import yaml

from placeloc.core.errors import ModelError  # noqa: F401 - re-exported: placeloc.geometry.floorplan.ModelError
from placeloc.core.safe_io import load_json, load_yaml, read_input_text
from placeloc.geometry.plan_check import check_plan
from placeloc.geometry.plan_check import number as _finite
from placeloc.geometry.polygons import on_edge as _on_edge
from placeloc.geometry.polygons import point_in_polygon

# A wireframe of many thousand segments is a few MB of YAML; aliases and depth stay refused.
MAX_MODEL_BYTES = 64 << 20


@dataclass
class Model:
    segments: np.ndarray            # (N, 6) float64 x0 y0 z0 x1 y1 z1
    faces: np.ndarray               # (F, 6) float64 x0 y0 x1 y1 z0 z1
    polygons: list[np.ndarray] = field(default_factory=list)  # plan outlines, for plots and grid filtering
    source: str = ""
    rooms: bool = False             # polygons are rooms (inside = in any) rather than outline + obstacles
    camera_z: float | None = None   # the camera height the plan was drawn for (importer, generator), if known
    # (G, 4) door/opening ends x0 y0 x1 y1; an outline plan's doors too, which the plan pictures
    # draw as gaps but which are not cut out of its walls
    gaps: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    internal: list[np.ndarray] = field(default_factory=list)            # wall blocks inside rooms (ZInD "internal")
    room_names: list[str] = field(default_factory=list)                 # a multi-room plan's, one per polygon

    def inside(self, xy: np.ndarray) -> np.ndarray:
        """True for plan points inside the outline and outside every obstacle, or inside any
        room of a multi-room plan (no polygons: all True)."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        if not self.polygons:
            return np.ones(len(xy), dtype=bool)
        if self.rooms:
            ok = np.zeros(len(xy), dtype=bool)
            for poly in self.polygons:
                ok |= point_in_polygon(xy, poly)
            ok |= in_gaps(xy, self.gaps)
            for poly in self.internal:
                ok &= ~point_in_polygon(xy, poly)
            return ok
        ok = point_in_polygon(xy, self.polygons[0])
        for poly in self.polygons[1:]:
            ok &= ~point_in_polygon(xy, poly)
        return ok


# How far either side of a door or opening its gap counts as free space: a camera may stand
# in the doorway, inside the thickness of the wall between two rooms (real walls are
# 0.1-0.3 m thick; each room's polygon stops at its own side of the wall).
GAP_DEPTH_M = 0.25


def in_gaps(xy: np.ndarray, gaps: np.ndarray, depth_m: float = GAP_DEPTH_M) -> np.ndarray:
    """True for plan points in the doorway of any gap (x0, y0, x1, y1): between its two ends
    along the wall and at most ``depth_m`` from the wall line on either side."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    ok = np.zeros(len(xy), dtype=bool)
    for x0, y0, x1, y1 in np.asarray(gaps, float).reshape(-1, 4):
        e = np.array([x1 - x0, y1 - y0])
        length = float(np.hypot(*e))
        if length < 1e-9:
            continue
        e /= length
        d = xy - [x0, y0]
        along = d @ e
        across = np.abs(d[:, 0] * e[1] - d[:, 1] * e[0])
        ok |= (along >= 0) & (along <= length) & (across <= depth_m)
    return ok


def load_model(path: str | Path, floor: str | None = None, ceiling: float | None = None) -> Model:
    """The model in a wireframe (.yaml/.json/.obj), a floor plan (.yaml) or a Zillow Indoor
    Dataset ``zind_data.json`` (``floor`` picks one of its floors; see
    :mod:`placeloc.geometry.zind`). ``ceiling``: a floor plan's ceiling height in metres in
    place of its own, every room's (:func:`with_ceiling`; a wireframe has none to replace)."""
    path = Path(path)
    plan, data, text = _read_model(path, floor)
    if plan is not None:
        return floor_plan_model(with_ceiling(plan, ceiling), str(path))
    if ceiling is not None:
        raise ModelError(f"{path}: a wireframe has no ceiling height to replace; search ceiling heights with a floor "
                         "plan (rooms: or outline:), or leave umap.grid.ceilings empty")
    if path.suffix.lower() == ".obj":
        return _load_obj(path, text)
    if isinstance(data, list):
        data = {"segments": data}
    if not isinstance(data, dict) or "segments" not in data:
        raise ModelError(f"{path}: expected a floor plan with 'rooms:' (a list of {{name, polygon: [[x, y], ...], "
                         "ceiling_z}}, as in docs/umap.md) or one 'outline:', or a wireframe: a list of segments "
                         "[x0, y0, z0, x1, y1, z1] or a mapping with 'segments'")
    segs = _rows(data["segments"], 6, path, "segments", "[x0, y0, z0, x1, y1, z1]")
    faces = _rows(data.get("faces") or [], 6, path, "faces", "[x0, y0, x1, y1, z0, z1]")
    camera_z = data.get("camera_z")
    return Model(segs, faces, source=str(path),
                 camera_z=None if camera_z is None else _finite(camera_z, str(path), "camera_z", positive=True))


def _rows(items: Any, n: int, path: Path, key: str, form: str) -> np.ndarray:
    if not isinstance(items, list):
        raise ModelError(f"{path}: '{key}' must be a list of {form}")
    out = np.zeros((len(items), n))
    for i, row in enumerate(items):
        ok = isinstance(row, (list, tuple)) and len(row) == n and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in row)
        if not ok:
            raise ModelError(f"{path}: {key}[{i}] = {row!r} is malformed; each entry must be {form} (numbers, metres)")
        out[i] = row
    if not np.isfinite(out).all():
        raise ModelError(f"{path}: {key} contains NaN or infinite coordinates; fix the file")
    if key == "segments" and len(out) == 0:
        raise ModelError(f"{path}: the model has no segments; a wireframe needs at least one line")
    return out


def _load_obj(path: Path, text: str) -> Model:
    verts: list[list[float]] = []
    segs: list[list[float]] = []
    for ln, line in enumerate(text.splitlines(), 1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        try:
            if parts[0] == "v":
                verts.append([float(v) for v in parts[1:4]])
                if len(verts[-1]) != 3:
                    raise ValueError("needs x y z")
            elif parts[0] == "l":
                idx = [int(p.split("/")[0]) for p in parts[1:]]
                if len(idx) < 2:
                    raise ValueError("a line needs at least two vertices")
                idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                for a, b in zip(idx[:-1], idx[1:]):
                    if not (0 <= a < len(verts) and 0 <= b < len(verts)):
                        raise ValueError(f"vertex index out of range (have {len(verts)} vertices)")
                    segs.append(verts[a] + verts[b])
        except ValueError as exc:
            raise ModelError(f"{path}:{ln}: malformed OBJ record {line.strip()!r} ({exc}); fix or remove that line") from exc
    if not segs:
        raise ModelError(f"{path}: no 'l' (line) elements found; the OBJ wireframe needs line segments")
    bad = [i for i, v in enumerate(verts, 1) if not np.isfinite(v).all()]
    if bad:
        raise ModelError(f"{path}: vertex {bad[0]} ({verts[bad[0] - 1]}) is not finite (NaN or infinity); fix the file")
    return Model(np.asarray(segs, float), np.zeros((0, 6)), source=str(path))


def _poly(pts: Any, path: str, key: str) -> np.ndarray:
    arr = np.asarray(pts, dtype=float) if isinstance(pts, list) else None
    if arr is None or arr.ndim != 2 or arr.shape[1] != 2 or len(arr) < 3:
        raise ModelError(f"{path}: {key} must be a list of at least three [x, y] points")
    return arr


def load_plan(path: str | Path, floor: str | None = None) -> dict[str, Any] | None:
    """The floor plan in ``path`` as a mapping (a floor plan's YAML, or a ZInD home's floor
    ``floor`` imported, :func:`placeloc.geometry.zind.zind_home`), or None where the file
    holds a wireframe: what :func:`floor_plan_model` builds a model from."""
    return _read_model(Path(path), floor)[0]


def _read_model(path: Path, floor: str | None) -> tuple[dict[str, Any] | None, Any, str]:
    """(the floor plan mapping or None, the parsed file, its text) of a model file."""
    if not path.is_file():
        raise ModelError(f"{path}: model file not found; give a wireframe (.yaml/.json/.obj) or floor plan (.yaml)")
    text = read_input_text(path, "model file")
    if path.suffix.lower() == ".obj":
        return None, None, text
    try:
        data = load_json(text, str(path)) if path.suffix.lower() == ".json" else load_yaml(text, str(path), max_bytes=MAX_MODEL_BYTES)
    except (ValueError, yaml.YAMLError) as exc:  # ValueError: JSON syntax or depth
        raise ModelError(f"{path}: not valid {'JSON' if path.suffix.lower() == '.json' else 'YAML'}: {exc}") from exc
    if isinstance(data, dict) and "merger" in data:
        from placeloc.geometry.zind import zind_home  # here: ZInD homes are the rarer input

        return zind_home(path, floor)[0], data, text
    if isinstance(data, dict) and ("outline" in data or "rooms" in data):
        return data, data, text
    return None, data, text


def with_ceiling(plan: dict[str, Any], ceiling: float | None) -> dict[str, Any]:
    """``plan`` with every room's ceiling at ``ceiling`` metres (the plan's ``ceiling_z`` and
    each room's own), for a plan whose ceiling height is not known: a plan drawn by hand
    from a listing's drawing, searched over several (``umap.grid.ceilings``). None: the plan
    as it is."""
    if ceiling is None or not isinstance(plan, dict):
        return plan
    out = {**plan, "ceiling_z": float(ceiling)}
    if isinstance(plan.get("rooms"), list):
        out["rooms"] = [{**r, "ceiling_z": float(ceiling)} if isinstance(r, dict) and "ceiling_z" in r else r
                        for r in plan["rooms"]]
    return out


def scaled_plan(plan: dict[str, Any], scale: float) -> dict[str, Any]:
    """``plan`` (either format of the module docstring) with every plan position multiplied
    by ``scale`` (its outline, obstacles, rooms' polygons and internal blocks, and the ends
    of its doors, openings and windows); heights (floor, ceiling, camera, lintels, sills)
    as they were: a plan drawn from a listing's drawing at the wrong scale.

    Why heights stay: a world scaled by ``s`` in x, y *and* z looks the same from the
    camera's scaled position (every direction is kept), so a plan drawn ``s`` too large is the
    true home seen with its heights ``s`` too small. The ceiling search makes up most of it:
    the ceiling's lines, seen from a camera at ``z``, fall back where they were at a ceiling
    of ``z + s (c - z)`` (docs/umap.md, "A floor plan drawn at the wrong scale")."""
    s = float(scale)

    def xy(points: Any) -> list[list[float]]:
        return [[float(p[0]) * s, float(p[1]) * s] for p in points]

    out = dict(plan)
    if "outline" in plan:
        out["outline"] = xy(plan["outline"])
        if plan.get("obstacles"):
            out["obstacles"] = [xy(p) for p in plan["obstacles"]]
    if isinstance(plan.get("rooms"), list):
        out["rooms"] = [{**r, "polygon": xy(r["polygon"]),
                         **({"internal": [xy(p) for p in r["internal"]]} if r.get("internal") else {})}
                        for r in plan["rooms"]]
    for key in ("doors", "openings", "windows"):
        if plan.get(key):
            out[key] = [{**o, "from": xy([o["from"]])[0], "to": xy([o["to"]])[0]} for o in plan[key]]
    return out


def floor_plan_model(plan: dict[str, Any], source: str = "floor plan") -> Model:
    """Build the wireframe and wall faces of a floor plan (see the module docstring); the
    plan passes :func:`placeloc.geometry.plan_check.check_plan` first."""
    check_plan(plan, source)
    if "rooms" in plan:
        return rooms_model(plan, source)
    try:
        zf = float(plan.get("floor_z", 0.0))
        zc = float(plan["ceiling_z"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelError(f"{source}: floor plan needs numeric floor_z and ceiling_z ({exc})") from exc
    if zc <= zf:
        raise ModelError(f"{source}: ceiling_z {zc} must be above floor_z {zf}")
    polys = [_poly(plan["outline"], source, "outline")]
    polys += [_poly(p, source, f"obstacles[{i}]") for i, p in enumerate(plan.get("obstacles") or [])]
    segs, faces = [], []
    for poly in polys:
        for a, b in zip(poly, np.roll(poly, -1, axis=0)):
            segs.append([a[0], a[1], zf, b[0], b[1], zf])
            segs.append([a[0], a[1], zc, b[0], b[1], zc])
            segs.append([a[0], a[1], zf, a[0], a[1], zc])
            faces.append([a[0], a[1], b[0], b[1], zf, zc])
    doors: list[list[float]] = []
    for i, door in enumerate(plan.get("doors") or []):
        try:
            p, q = np.asarray(door["from"], float), np.asarray(door["to"], float)
            h = float(door.get("height", 2.0))
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelError(f"{source}: doors[{i}] needs from: [x, y], to: [x, y] and a numeric height ({exc})") from exc
        segs.append([p[0], p[1], zf, p[0], p[1], zf + h])
        segs.append([q[0], q[1], zf, q[0], q[1], zf + h])
        segs.append([p[0], p[1], zf + h, q[0], q[1], zf + h])
        doors.append([p[0], p[1], q[0], q[1]])
    camera_z = _num(plan, "camera_z", None, source, "the plan") if plan.get("camera_z") is not None else None
    # the doors' ends, for the plan pictures to draw as gaps in the outline (the wall face
    # stays: an outline's door is a frame on its wall, so free space and renders ignore them)
    return Model(np.asarray(segs, float), np.asarray(faces, float), polygons=polys, source=source, camera_z=camera_z,
                 gaps=np.asarray(doors, float).reshape(-1, 4))


def _num(d: dict[str, Any], key: str, default: float | None, source: str, what: str) -> float:
    try:
        v = d.get(key, default) if isinstance(d, dict) else None
        if v is None:
            raise KeyError(key)
        return float(v)
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelError(f"{source}: {what} needs a numeric {key} ({exc})") from exc


def rooms_model(plan: dict[str, Any], source: str = "floor plan") -> Model:
    """Wireframe and wall faces of a multi-room floor plan (see the module docstring)."""
    rooms = plan.get("rooms")
    if not isinstance(rooms, list) or not rooms:
        raise ModelError(f"{source}: rooms must be a non-empty list of {{polygon: [[x, y], ...], ceiling_z: ...}}")
    zf0 = float(plan.get("floor_z", 0.0))
    zc0 = plan.get("ceiling_z")
    openings = []
    for key in ("doors", "openings"):
        items = plan.get(key) or []
        if not isinstance(items, list):
            raise ModelError(f"{source}: {key} must be a list of {{from: [x, y], to: [x, y], height: ...}}")
        for i, o in enumerate(items):
            try:
                openings.append((np.asarray(o["from"], float).reshape(2), np.asarray(o["to"], float).reshape(2),
                                 _num(o, "height", 2.0, source, f"{key}[{i}]")))
            except (KeyError, TypeError, ValueError) as exc:
                raise ModelError(f"{source}: {key}[{i}] needs from: [x, y], to: [x, y] and a numeric height ({exc})") from exc
    camera_z = plan.get("camera_z")
    if camera_z is not None:
        camera_z = _num(plan, "camera_z", None, source, "the plan")
    windows = []
    for i, w in enumerate(plan.get("windows") or []):
        try:
            windows.append((np.asarray(w["from"], float), np.asarray(w["to"], float),
                            _num(w, "sill", None, source, f"windows[{i}]"), _num(w, "top", None, source, f"windows[{i}]")))
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelError(f"{source}: windows[{i}] needs from: [x, y], to: [x, y], sill and top ({exc})") from exc
    segs: list[list[float]] = []
    faces: list[list[float]] = []
    polys = []
    names = []
    internal = []
    for r, room in enumerate(rooms):
        what = f"rooms[{r}]" + (f" ({room.get('name')})" if isinstance(room, dict) and room.get("name") else "")
        if not isinstance(room, dict) or "polygon" not in room:
            raise ModelError(f"{source}: {what} needs a polygon: [[x, y], ...]")
        poly = _poly(room["polygon"], source, f"{what}.polygon")
        names.append(str(room.get("name") or f"room {r}"))
        zf = _num(room, "floor_z", zf0, source, what)
        zc = _num(room, "ceiling_z", zc0, source, what)
        if zc <= zf:
            raise ModelError(f"{source}: {what}: ceiling_z {zc} must be above floor_z {zf}")
        polys.append(poly)
        for a, b in zip(poly, np.roll(poly, -1, axis=0)):
            e = (b - a) / max(float(np.hypot(*(b - a))), 1e-12)
            length = float(np.hypot(*(b - a)))
            segs.append([a[0], a[1], zf, a[0], a[1], zc])             # corner
            segs.append([a[0], a[1], zc, b[0], b[1], zc])             # ceiling edge
            cuts = sorted((st, h) for p, q, h in openings if (st := _on_edge(p, q, a, b)) is not None)
            s0 = 0.0
            for (u0, u1), h in cuts:
                top = min(zf + h, zc)
                if u0 > s0:
                    p0, p1 = a + s0 * e, a + u0 * e
                    segs.append([p0[0], p0[1], zf, p1[0], p1[1], zf])
                    faces.append([p0[0], p0[1], p1[0], p1[1], zf, zc])
                p0, p1 = a + u0 * e, a + u1 * e
                segs.append([p0[0], p0[1], zf, p0[0], p0[1], top])     # jambs
                segs.append([p1[0], p1[1], zf, p1[0], p1[1], top])
                if top < zc - 1e-6:
                    segs.append([p0[0], p0[1], top, p1[0], p1[1], top])  # lintel
                    faces.append([p0[0], p0[1], p1[0], p1[1], top, zc])
                s0 = max(s0, u1)
            if s0 < length:
                p0 = a + s0 * e
                segs.append([p0[0], p0[1], zf, b[0], b[1], zf])
                faces.append([p0[0], p0[1], b[0], b[1], zf, zc])
            for p, q, sill, top in windows:
                st = _on_edge(p, q, a, b)
                if st is None:
                    continue
                p0, p1 = a + st[0] * e, a + st[1] * e
                lo, hi = max(sill + zf, zf), min(top + zf, zc)
                segs += [[p0[0], p0[1], lo, p1[0], p1[1], lo], [p0[0], p0[1], hi, p1[0], p1[1], hi],
                         [p0[0], p0[1], lo, p0[0], p0[1], hi], [p1[0], p1[1], lo, p1[0], p1[1], hi]]
        blocks = room.get("internal") or []
        if not isinstance(blocks, list):
            raise ModelError(f"{source}: {what}.internal must be a list of polygons [[[x, y], ...], ...]")
        for j, block in enumerate(blocks):
            poly_in = _poly(block, source, f"{what}.internal[{j}]")
            internal.append(poly_in)
            for a, b in zip(poly_in, np.roll(poly_in, -1, axis=0)):
                segs += [[a[0], a[1], zf, a[0], a[1], zc], [a[0], a[1], zc, b[0], b[1], zc], [a[0], a[1], zf, b[0], b[1], zf]]
                faces.append([a[0], a[1], b[0], b[1], zf, zc])
    _warn_unattached(source, plan, polys, openings, windows)
    gaps = np.array([[*p, *q] for p, q, _h in openings], float).reshape(-1, 4)
    return Model(np.asarray(segs, float), np.asarray(faces, float).reshape(-1, 6), polygons=polys, source=source, rooms=True,
                 camera_z=camera_z, gaps=gaps, internal=internal, room_names=names)


def label_points(polygons: Sequence[np.ndarray], inset_m: float = 0.25, step_m: float = 0.1) -> np.ndarray:
    """(R, 2): for each polygon the highest, then leftmost, point of a ``step_m`` lattice over
    it that lies inside at least ``inset_m`` from its edges (a polygon too thin for that:
    its lattice point farthest from the edges; none inside: its bounding box's centre):
    where a room's name is written on a plan, from its top left corner. Why there and not
    in the middle: the middle of a room is where cameras stand, and a name written there
    runs into their crosses and names.
    """
    out = np.zeros((len(polygons), 2))
    for i, poly in enumerate(polygons):
        poly = np.asarray(poly, float).reshape(-1, 2)
        lo, hi = poly.min(axis=0), poly.max(axis=0)
        out[i] = (lo + hi) / 2
        gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + step_m / 2, step_m), np.arange(lo[1], hi[1] + step_m / 2, step_m))
        pts = np.column_stack([gx.ravel(), gy.ravel()])
        pts = pts[point_in_polygon(pts, poly)]
        if not len(pts):
            continue
        d = segment_distances(pts, np.column_stack([poly, np.roll(poly, -1, axis=0)])).min(axis=1)
        ok = pts[d >= inset_m]
        if len(ok):
            out[i] = ok[np.lexsort((ok[:, 0], -ok[:, 1]))[0]]
        else:
            out[i] = pts[int(np.argmax(d))]
    return out


def rooms_at(xy: np.ndarray, polygons: Sequence[np.ndarray], names: Sequence[str]) -> list[str]:
    """The name of the room each plan point (P, 2) lies in (the first whose polygon holds
    it; "" outside every room or at NaN): how a person reads an answer off a floor plan."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    out = [""] * len(xy)
    ok = np.isfinite(xy).all(axis=1)
    for poly, name in zip(polygons, names):
        inside = np.zeros(len(xy), bool)
        if ok.any():
            inside[ok] = point_in_polygon(xy[ok], np.asarray(poly, float))
        for i in np.flatnonzero(inside):
            if not out[i]:
                out[i] = str(name)
    return out


_WARNED: set[tuple[Any, ...]] = set()  # each element of each plan warned about once a process


def _warn_unattached(source: str, plan: dict[str, Any], polys: list[np.ndarray], openings: list[Any],
                     windows: list[Any]) -> None:
    """Warn (once per element) about each door, opening or window that lies on no room's
    edge (both ends within 1 cm of one edge, as the walls are cut): it cuts no wall, draws
    no frame, and a door's or opening's doorway still counts as free space for the grid. A
    hand-drawn plan's door a few centimetres off its wall (a rounded coordinate, x and y
    swapped) otherwise goes unnoticed. Not an error: the plan still loads as it is."""
    import logging

    edges = [(a, b) for poly in polys for a, b in zip(poly, np.roll(poly, -1, axis=0))]
    named = [*((f"doors[{i}]", o) for i, o in enumerate(plan.get("doors") or [])),
             *((f"openings[{i}]", o) for i, o in enumerate(plan.get("openings") or []))]
    items = [(name, p, q) for (name, _), (p, q, _h) in zip(named, openings)]
    items += [(f"windows[{i}]", p, q) for i, (p, q, _s, _t) in enumerate(windows)]
    for name, p, q in items:
        key = (source, name, *p, *q)
        if key in _WARNED or any(_on_edge(p, q, a, b) is not None for a, b in edges):
            continue
        _WARNED.add(key)
        off = float(segment_distances(np.array([p, q]), np.array([[*a, *b] for a, b in edges])).max(axis=0).min())
        logging.getLogger("placeloc").warning(
            "%s: %s [%g, %g] -> [%g, %g] lies on no room's edge (its ends are at best %.2f m from one; both must be "
            "within 0.01 m): it cuts no wall%s; move it onto its wall", source, name, *p, *q, off,
            "" if name.startswith("windows") else " and its doorway still counts as free space")


def segment_distances(xy: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """(points, segments) plan distances from each point to each segment (rows x0 y0 x1 y1 ...)."""
    a, b = segments[:, 0:2], segments[:, 2:4]
    e = b - a
    ee = np.maximum((e * e).sum(1), 1e-12)
    p = np.asarray(xy, float)[:, None, :]
    t = np.clip(((p - a) * e).sum(2) / ee, 0, 1)
    return np.hypot(*(p - (a + t[..., None] * e)).transpose(2, 0, 1))


def wall_distance(xy: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Plan distance from each point to the nearest wall face (``faces`` rows x0 y0 x1 y1 ...)."""
    if len(faces) == 0:
        return np.full(len(xy), np.inf)
    out = np.full(len(xy), np.inf)
    for s in range(0, len(xy), 8192):  # chunks keep the (points x walls) temporaries small
        out[s:s + 8192] = segment_distances(xy[s:s + 8192], faces).min(1)
    return out


def blocking_faces(faces: np.ndarray, z: float | None) -> np.ndarray:
    """The wall faces a camera at height ``z`` cannot stand in: those spanning that height.
    A lintel (the wall above a door) starts above a standing camera and does not count, so a
    camera in a doorway is not "near a wall" because of it. ``z`` None: the faces that reach
    down to the lowest floor of the model."""
    faces = np.asarray(faces, float).reshape(-1, 6)
    if z is None:
        return faces[faces[:, 4] <= faces[:, 4].min(initial=0.0) + 1e-6] if len(faces) else faces
    return faces[(faces[:, 4] <= z) & (faces[:, 5] >= z)]


def free_space_mask(xy: np.ndarray, model: Model, *, inside_only: bool, wall_margin_m: float,
                    z: float | None = None) -> tuple[np.ndarray, list[str]]:
    """Which plan points are free space for camera poses, and the settings that did nothing.

    ``inside_only`` keeps points inside the plan (outline minus obstacles, or any room
    outside its internal blocks, or a doorway); ``wall_margin_m`` keeps points at least that
    far from every wall face that spans the camera height ``z`` (:func:`blocking_faces`:
    lintels above doorways do not count). A wireframe has no polygons, so ``inside_only``
    cannot apply, and without faces neither can the margin: each such case is returned as a
    sentence for the caller to warn with."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    keep = np.ones(len(xy), dtype=bool)
    notes: list[str] = []
    if inside_only:
        if model.polygons:
            keep &= model.inside(xy)
        else:
            notes.append(f"grid.inside_only does nothing for {model.source or 'this model'}: a wireframe has no room "
                         "polygons (give a floor plan, or set grid.inside_only: false)")
    if wall_margin_m > 0:
        if len(model.faces):
            keep &= wall_distance(xy, blocking_faces(model.faces, z)) >= wall_margin_m
        else:
            notes.append(f"grid.wall_margin_m does nothing for {model.source or 'this model'}: it has no wall faces "
                         "(add faces: [[x0, y0, x1, y1, z0, z1], ...] or use a floor plan)")
    return keep, notes


def model_bounds(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) plan corners of the model: its polygons, else its segments."""
    pts = np.concatenate(model.polygons) if model.polygons else model.segments.reshape(-1, 3)[:, :2]
    return pts.min(0), pts.max(0)


def plan_grid(model: Model, *, x: Any = None, y: Any = None, step_m: float = 0.25, z: float | None = None,
              headings: Any = (0.0,), inside_only: bool = True, wall_margin_m: float = 0.1) -> tuple[np.ndarray, list[str]]:
    """The camera pose grid over a model: (N, 4) rows x, y, z, heading (x slowest) and the
    notes of settings that did nothing.

    ``x``/``y`` None: the model's plan bounds at ``step_m`` (the first point half a step in);
    ``z`` None: the model's camera height (``camera_z`` of the plan). A grid that keeps no
    position of the model, or a z outside its storey, is a ValueError naming both."""
    from placeloc.geometry import pose_grid

    lo, hi = model_bounds(model)
    where = f"{model.source or 'the model'} (plan x {lo[0]:.2f}..{hi[0]:.2f} m, y {lo[1]:.2f}..{hi[1]:.2f} m)"
    if z is None:
        if model.camera_z is None:
            raise ValueError(f"{model.source or 'the model'} gives no camera height (camera_z): set grid.z to the "
                             "camera's height above the floor in metres, or add camera_z to the plan")
        z = float(model.camera_z)
    if len(model.faces):
        zlo, zhi = float(model.faces[:, 4].min()), float(model.faces[:, 5].max())
        if not zlo < z < zhi:
            raise ValueError(f"grid z {z} m lies outside the storey of {where}: floor {zlo} m, ceiling {zhi} m; set "
                             "grid.z to the camera height above the floor (or leave it out to use the plan's camera_z)")
    explicit = x is not None and y is not None
    if x is None:
        x = [float(lo[0]) + step_m / 2, float(hi[0]), step_m]
    if y is None:
        y = [float(lo[1]) + step_m / 2, float(hi[1]), step_m]
    poses = pose_grid(list(x), list(y), z, list(headings))
    keep, notes = free_space_mask(poses[:, :2], model, inside_only=inside_only, wall_margin_m=wall_margin_m, z=z)
    if explicit and keep.any() and model.polygons:
        # the share of the plan's free space the given grid reaches (a grid made for another model)
        full = pose_grid([float(lo[0]), float(hi[0]), 0.25], [float(lo[1]), float(hi[1]), 0.25], z, [0.0])[:, :2]
        full = full[free_space_mask(full, model, inside_only=True, wall_margin_m=wall_margin_m, z=z)[0]]
        g = poses[keep]
        reached = ((full[:, 0] >= g[:, 0].min() - 0.25) & (full[:, 0] <= g[:, 0].max() + 0.25)
                   & (full[:, 1] >= g[:, 1].min() - 0.25) & (full[:, 1] <= g[:, 1].max() + 0.25)).mean() if len(full) else 1.0
        if reached < 0.5:
            notes.append(f"grid covers only {reached:.0%} of the free space of {where}: leave grid.x and grid.y out to "
                         "cover the whole plan")
    if not keep.any():
        gx, gy = poses[:, 0], poses[:, 1]
        raise ValueError(f"the pose grid (x {gx.min():.2f}..{gx.max():.2f} m, y {gy.min():.2f}..{gy.max():.2f} m) keeps "
                         f"no position of {where}{' inside the rooms' if inside_only else ''}: leave grid.x and grid.y out "
                         "to cover the plan, or fix them (or the model's coordinates)")
    return poses[keep], notes
