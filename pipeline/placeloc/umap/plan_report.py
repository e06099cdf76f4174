"""Check a floor plan before localizing against it (``placeloc plan``).

Whoever traces a listing's floor plan into ``floor_plan.yaml`` by hand needs to see what
the localizer will read from it before spending a run on it: the rooms and their areas
(a plan drawn at the wrong scale shows in a room's area first), the doors and windows, the
camera height, the grid of places localize searches, a picture of the plan with all of it,
and the map's lines as a 360 degree camera would see them from a chosen point, to hold
against a photo taken there.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from placeloc.core.artifacts import atomic_open
from placeloc.geometry.floorplan import (
    Model,
    floor_plan_model,
    label_points,
    load_model,
    load_plan,
    plan_grid,
    rooms_at,
)
from placeloc.geometry.panorama import render_panoramas
from placeloc.umap.bits import unpack

# the view's size: wide enough that a door's jambs are columns apart (0.4 degrees a column)
VIEW_WIDTH = 900

# grid points over the plan's bounds the check lays at most: 0.02 m over a 13 x 9 m home is
# about 290,000 and takes 2 s; a step of millimetres would take minutes and gigabytes
MAX_GRID_POINTS = 2_000_000


@dataclass(frozen=True)
class PlanSummary:
    """What a plan file holds, as localize reads it. ``rooms``: (name, floor area in square
    metres without its internal wall blocks, ceiling height above the floor in metres or
    None); ``counts``: doors, openings, windows and internal blocks as the file lists them;
    ``bounds``: x min, y min, x max, y max of the plan in metres; ``grid``: the (N, 4) poses
    localize would search with the given step, wall margin and camera height."""

    source: str
    kind: str                                  # "rooms", "outline" or "wireframe"
    rooms: list[tuple[str, float, float | None]]
    counts: dict[str, int]
    camera_z: float | None
    bounds: tuple[float, float, float, float]
    grid: np.ndarray
    step_m: float
    wall_margin_m: float
    z: float | None
    notes: list[str] = field(default_factory=list)
    gaps: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))   # doors and openings: x0 y0 x1 y1
    windows: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))  # x0 y0 x1 y1

    def lines(self) -> list[str]:
        """The summary as the ``plan`` command prints it."""
        x0, y0, x1, y1 = self.bounds
        kind = {"rooms": "a plan of rooms", "outline": "an outline plan", "wireframe": "a wireframe"}[self.kind]
        out = [f"{self.source}: {kind}, {x1 - x0:.2f} m x {y1 - y0:.2f} m "
               f"(x {x0:.2f} to {x1:.2f}, y {y0:.2f} to {y1:.2f})"]
        if self.rooms:
            total = sum(a for _, a, _ in self.rooms)
            out.append(f"{len(self.rooms)} room{'s' if len(self.rooms) != 1 else ''}, {total:.1f} m2 in all:")
            width = max(len(name) for name, _, _ in self.rooms)
            for name, area, ceiling in self.rooms:
                out.append(f"  {name:<{width}}  {area:6.1f} m2" + (f", ceiling {ceiling:.2f} m" if ceiling is not None else ""))
        if self.counts:
            out.append(", ".join(f"{n} {k if n != 1 else k[:-1]}" for k, n in self.counts.items()))
        out.append(f"camera height: {self.camera_z:.2f} m (camera_z)" if self.camera_z is not None else
                   "camera height: not in the plan; give umap.grid.z (or camera_z in the plan, or --z here)")
        if self.z is not None:
            out.append(f"grid: {len(self.grid):,} places at {self.step_m:g} m, at least {self.wall_margin_m:g} m from "
                       f"the walls, camera at {self.z:.2f} m (about {len(self.grid) * self.step_m ** 2:.1f} m2 of free space)")
        out.extend(self.notes)
        return out


def summarise(path: str | Path, *, floor: str | None = None, step_m: float | None = None,
              wall_margin_m: float | None = None, z: float | None = None) -> tuple[PlanSummary, Model]:
    """The :class:`PlanSummary` of the model in ``path`` (a floor plan, a ZInD
    ``zind_data.json`` with ``floor``, or a wireframe) and the model localize builds from it.
    ``step_m`` and ``wall_margin_m`` None: ``umap.grid``'s defaults; ``z`` None: the plan's
    own camera height (no grid where it has none)."""
    from placeloc.umap.params import GridParams

    defaults = GridParams()
    step_m = defaults.step_m if step_m is None else float(step_m)
    wall_margin_m = defaults.wall_margin_m if wall_margin_m is None else float(wall_margin_m)
    if step_m <= 0 or wall_margin_m < 0:
        raise ValueError(f"the grid's step ({step_m:g} m) must be above 0 and its wall margin ({wall_margin_m:g} m) "
                         "not below 0")
    path = Path(path)
    plan = load_plan(path, floor)   # the file read once: a plan's model is built from it as load_model does
    model = floor_plan_model(plan, str(path)) if plan is not None else load_model(path, floor)
    walls = np.asarray(model.segments, float).reshape(-1, 6)
    points = np.vstack([*model.polygons, walls[:, [0, 1]], walls[:, [3, 4]]]) if len(walls) or model.polygons else \
        np.zeros((1, 2))
    bounds = (float(points[:, 0].min()), float(points[:, 1].min()), float(points[:, 0].max()), float(points[:, 1].max()))
    rooms: list[tuple[str, float, float | None]] = []
    counts: dict[str, int] = {}
    gaps = np.asarray(model.gaps, float).reshape(-1, 4)   # doors and openings, as the model keeps them
    windows = np.zeros((0, 4))   # a wireframe has none
    kind = "wireframe"
    if plan is not None:
        kind = "rooms" if "rooms" in plan else "outline"
        floor_z = float(plan.get("floor_z", 0.0))
        if kind == "rooms":
            for i, (room, poly) in enumerate(zip(plan["rooms"], model.polygons)):
                blocks = [np.asarray(b, float) for b in room.get("internal", []) or []]
                area = polygon_area(poly) - sum(polygon_area(b) for b in blocks)
                ceiling = room.get("ceiling_z", plan.get("ceiling_z"))
                name = model.room_names[i] if i < len(model.room_names) else f"room {i}"
                rooms.append((str(name), area, None if ceiling is None else float(ceiling) - floor_z))
        else:
            ceiling = plan.get("ceiling_z")
            area = polygon_area(model.polygons[0]) - sum(polygon_area(p) for p in model.polygons[1:])
            rooms.append(("inside the outline", area, None if ceiling is None else float(ceiling) - floor_z))
        for key in ("doors", "openings", "windows"):
            counts[key] = len(plan.get(key, []) or [])
        windows = np.array([[*w["from"], *w["to"]] for w in plan.get("windows", []) or [] if isinstance(w, dict)],
                           float).reshape(-1, 4)
        if kind == "rooms":
            counts["internal blocks"] = sum(len(r.get("internal", []) or []) for r in plan["rooms"])
    z = model.camera_z if z is None else float(z)
    grid = np.zeros((0, 4))
    notes: list[str] = []
    if z is not None:
        laid = np.ceil((bounds[2] - bounds[0]) / step_m + 1) * np.ceil((bounds[3] - bounds[1]) / step_m + 1)
        if laid > MAX_GRID_POINTS:
            raise ValueError(f"a grid step of {step_m:g} m lays {laid:,.0f} points over the plan's "
                             f"{bounds[2] - bounds[0]:.1f} x {bounds[3] - bounds[1]:.1f} m, more than "
                             f"{MAX_GRID_POINTS:,}; give a larger --step (umap.grid.step_m is {defaults.step_m:g} m)")
        grid, notes = plan_grid(model, step_m=step_m, z=z, wall_margin_m=wall_margin_m)
    return PlanSummary(str(path), kind, rooms, counts, model.camera_z, bounds, grid, float(step_m),
                       float(wall_margin_m), z, list(notes), gaps, windows), model


# the look-alike check's places: every LOOK_ALIKE_STEP_M over the rooms (the localize grid's
# 0.25 m would cost four times the renders and tell the same of a room)
LOOK_ALIKE_STEP_M = 0.5
# at most this many places: a larger plan (an office floor) is sampled more coarsely, so that the
# check's table (places x places x headings) stays seconds, not minutes. On the 2-core machine
# generated home 21 took 2.5 s at 363 places, 5.8 s at 723 and 19.5 s at 1,494
LOOK_ALIKE_MAX_PLACES = 1500
# a place whose view another room repeats this well: on generated development homes 0-12 (five
# grid origins, the defaults) 23 % of the answers at such places were wrong, against 0.5 %
# below 0.6 (docs/umap.md, "Rooms that look alike")
LOOK_ALIKE = 0.7


@dataclass(frozen=True)
class LookAlike:
    """How well another room repeats one room's views: over the room's places (every
    :data:`LOOK_ALIKE_STEP_M`), the median of each place's best score at a place of another
    room more than ``apart_m`` away (``score``; 1: the same view), the room that gave most of
    those bests (``like``), and the number of places."""

    room: str
    score: float
    like: str
    places: int

    @property
    def marked(self) -> bool:
        """Whether the room looks alike (:data:`LOOK_ALIKE` or more): photos taken there need
        their room named."""
        return self.score >= LOOK_ALIKE


class LookAlikePlaces(NamedTuple):
    """:func:`look_alike_places`: the places (P, 2) in the named rooms, each one's ``room``,
    its best score at a place of another room (``score``) and that room (``like``)."""

    xy: np.ndarray
    room: np.ndarray
    score: np.ndarray
    like: np.ndarray


def look_alike_places(model: Model, *, z: float, wall_margin_m: float, step_m: float = LOOK_ALIKE_STEP_M,
                      apart_m: float | None = None) -> LookAlikePlaces:
    """The map's own lines seen from every place of the plan's named rooms (every ``step_m``,
    coarser where that lays more than :data:`LOOK_ALIKE_MAX_PLACES`, as localize's grid lays
    them with ``wall_margin_m``, the camera at ``z``), each scored as a
    photo against every place and heading (the chamfer table of localize with
    ``umap.panorama``'s defaults), and its best taken over the places of the other rooms more
    than ``apart_m`` away (None: ``margin_distance_m``, as the rival of a localize answer);
    -inf where there is none. A clutter-free view is its own best (1)."""
    from placeloc.umap.panorama import _query_side, _search_table, chamfer_spectra, map_images, map_side
    from placeloc.umap.params import PanoramaParams

    pp = PanoramaParams()
    apart_m = pp.margin_distance_m if apart_m is None else float(apart_m)
    names = list(model.room_names[:len(model.polygons)]) if model.rooms else []
    none = LookAlikePlaces(np.zeros((0, 2)), np.zeros(0, str), np.zeros(0), np.zeros(0, str))
    if len(set(names)) < 2:
        return none
    try:
        grid, _ = plan_grid(model, step_m=step_m, z=z, wall_margin_m=wall_margin_m)
    except ValueError:   # no place at this step (rooms narrower than it): nothing to compare
        return none
    if len(grid) > LOOK_ALIKE_MAX_PLACES:   # coarser, to about LOOK_ALIKE_MAX_PLACES places
        grid, _ = plan_grid(model, step_m=step_m * math.sqrt(len(grid) / LOOK_ALIKE_MAX_PLACES), z=z,
                            wall_margin_m=wall_margin_m)
    room = np.array(rooms_at(grid[:, :2], model.polygons[:len(names)], names))
    grid, room = grid[room != ""], room[room != ""]
    if len(set(room)) < 2:
        return none
    lines = map_images(model.segments, model.faces, grid, width=pp.width, height=pp.height,
                       bins=int(pp.orientation_bins), hidden=True)
    queries, weights, prows, spread = _query_side(lines, pp)
    spectra = chamfer_spectra(lines, **map_side(pp, pp.height))
    xy = grid[:, :2]
    best, like = np.full(len(grid), -np.inf), np.full(len(grid), "", dtype=room.dtype)
    for s in range(0, len(grid), 32):
        table = _search_table(spectra, queries[s:s + 32], weights, prows, spread, pp).max(axis=2)   # (q, P)
        for k, row in enumerate(table):
            i = s + k
            other = (room != room[i]) & (np.hypot(*(xy - xy[i]).T) > apart_m)
            if other.any():
                j = np.flatnonzero(other)[int(np.argmax(row[other]))]
                best[i], like[i] = row[j], room[j]
    return LookAlikePlaces(xy, room, best, like)


def look_alike_rooms(model: Model, *, z: float, wall_margin_m: float, step_m: float = LOOK_ALIKE_STEP_M,
                     apart_m: float | None = None) -> list[LookAlike]:
    """Each named room's :class:`LookAlike` over :func:`look_alike_places`, the most alike
    first: twin bedrooms repeat each other's views at 0.7-0.9, a hall or a living room
    another room's at about 0.5. Empty for a plan without two named rooms.

    Why: a photo taken where another room shows nearly the same lines is found in the other
    room as easily as in its own once clutter moves the score by a few hundredths; whoever
    takes photos there should name their room (``umap.room_hints``)."""
    got = look_alike_places(model, z=z, wall_margin_m=wall_margin_m, step_m=step_m, apart_m=apart_m)
    out = []
    for name in dict.fromkeys(got.room):
        mine = (got.room == name) & np.isfinite(got.score)
        if mine.any():
            rooms_, counts = np.unique(got.like[mine], return_counts=True)
            out.append(LookAlike(str(name), float(np.median(got.score[mine])), str(rooms_[np.argmax(counts)]),
                                 int(mine.sum())))
    return sorted(out, key=lambda a: -a.score)


def look_alike_lines(found: list[LookAlike]) -> list[str]:
    """What ``placeloc plan`` prints of :func:`look_alike_rooms`."""
    if not found:
        return []
    width = max(len(a.room) for a in found)
    out = [f"rooms that look alike from inside (the map's lines from each place against every place of another room; "
           f"1: the same view; a median of {LOOK_ALIKE:g} or more asks for the room of each photo taken there):"]
    for a in found:
        note = "  look alike: name the room of photos taken here (umap.room_hints)" if a.marked else ""
        out.append(f"  {a.room:<{width}}  {a.score:.2f} like {a.like}{note}")
    return out


def point_note(model: Model, at: tuple[float, float]) -> str | None:
    """What to say of a view's point that no camera of a localize run could stand at: one
    outside every room (or the outline), where the view looks at the plan from outside.
    None where it is inside (or the model has no rooms to tell)."""
    if not model.polygons or bool(model.inside(np.array([at], float))[0]):
        return None
    return (f"note: ({at[0]:g}, {at[1]:g}) lies outside the plan's rooms; view.png shows the plan from outside "
            "(plan.png shows where the rooms are)")


@dataclass(frozen=True)
class PhotoAt:
    """A photo held against the map at one point: the heading at which its lines best match
    the map's there (degrees, 0 along +x, counter-clockwise), that match's chamfer score (the
    plain halves' mean, 0-1, :func:`placeloc.umap.panorama.chamfer_yaw_scores`), and the two
    (H, W) line images at the localizer's size, the map's turned to that heading."""

    heading_deg: float
    score: float
    photo_lines: np.ndarray
    map_lines: np.ndarray


def photo_at(model: Model, x: float, y: float, z: float, photo: str | Path) -> PhotoAt:
    """The 360 degree ``photo`` (an equirectangular image, or a photo sphere stored cropped)
    as localize reads it (``umap.panorama``'s defaults, one direction bin: its lines at the
    localizer's size, levelled), scored against the map at (x, y, z) at every heading."""
    from placeloc.core.images import ImageError, read_gray
    from placeloc.umap.panorama import chamfer_yaw_scores, closeness
    from placeloc.umap.params import PanoramaParams
    from placeloc.umap.query_features import panorama_arrays

    pp = PanoramaParams()
    w, h = pp.width, pp.height
    if not Path(photo).is_file():
        raise ValueError(f"{photo}: no such file; give the 360 degree photo taken at the point")
    try:
        gray = read_gray(photo)
    except ImageError as exc:   # its words, without the advice for a run's image folders
        raise ValueError(str(exc).split("; remove or replace it")[0] + "; give a JPEG or PNG of the photo") from None
    got = panorama_arrays(gray, width=w, height=h, face_px=pp.face_px, min_length=pp.lsd_min_length_px,
                          level_max_deg=pp.level_max_deg, equalize_clip=pp.equalize_clip, path=str(photo))
    lines = unpack(got["lines"], h, w)[0]
    packed = render_panoramas(model.segments, model.faces, np.array([[x, y, z, 0.0]]), width=w, height=h, hidden=True)
    drawn = unpack(packed, h, w)
    scores = chamfer_yaw_scores(packed, closeness(drawn, pp.chamfer_tau_px), lines, tau_px=pp.chamfer_tau_px,
                                chance="none")[0]
    k = int(np.argmax(scores))
    # a panorama at heading psi is the one at heading 0 rolled by psi W / 360 columns
    return PhotoAt(k * 360.0 / w, float(scores[k]), lines > 0, np.roll(drawn[0], k, axis=1) > 0)


def polygon_area(poly: Any) -> float:
    """The area of a simple polygon (its vertices in order, either way round), in the
    square of its units (the shoelace formula)."""
    p = np.asarray(poly, float).reshape(-1, 2)
    return 0.5 * abs(float(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(p[:, 1], np.roll(p[:, 0], -1))))


def view_lines(model: Model, x: float, y: float, z: float, heading_deg: float = 0.0,
               width: int = VIEW_WIDTH) -> np.ndarray:
    """(width / 2, width) bool: the map's lines, hidden lines removed, as an equirectangular
    360 degree camera at (x, y, z) with its centre column at ``heading_deg`` (0 along +x,
    counter-clockwise) would see them (:func:`placeloc.geometry.panorama.render_panoramas`,
    the localizer's own renderer)."""
    h = width // 2
    packed = render_panoramas(model.segments, model.faces, np.array([[x, y, z, heading_deg]], float), width=width,
                              height=h, hidden=True)
    return unpack(packed, h, width)[0] > 0


def draw(summary: PlanSummary, model: Model, out_dir: Path, at: tuple[float, float] | None = None,
         heading_deg: float = 0.0, photo: PhotoAt | None = None, look_alike: list[LookAlike] | None = None) -> list[Path]:
    """``plan.png`` (the rooms, doors as gaps, windows in green, room names, the grid's
    places as grey dots and the ``at`` point; a room :func:`look_alike_rooms` marks is named
    with the room it looks like, "bedroom1: like bedroom3 (0.82)") and, with ``at``,
    ``view.png``: :func:`view_lines` from there.
    With ``photo`` (:func:`photo_at` at ``at``), ``photo.png``: its lines against the map's
    there at the heading where they match best."""
    from placeloc.evaluation.pose_estimates import plot_estimates_on_plan
    from placeloc.umap.plots import plot_map_view

    out_dir.mkdir(parents=True, exist_ok=True)
    est = np.array([at], float) if at is not None else np.zeros((0, 2))
    labels = list(model.room_names[:len(model.polygons)]) if model.rooms else None
    marked = {a.room: a for a in look_alike or [] if a.marked}
    if labels and marked:
        labels = [f"{n}: like {marked[n].like} ({marked[n].score:.2f})" if n in marked else n for n in labels]
    x0, y0, x1, y1 = summary.bounds
    title = (f"{Path(summary.source).name}: {x1 - x0:.1f} m x {y1 - y0:.1f} m" +
             (f", {len(summary.grid):,} grid places at {summary.step_m:g} m" if len(summary.grid) else
              ", no grid (no camera height)") +
             (f"; look-alike rooms: {', '.join(marked)} (name the room of photos taken there)" if marked else ""))
    paths = [plot_estimates_on_plan(out_dir / "plan.png", None, est, model.polygons if model.polygons else [],
                                    model.segments, "the view's point", None,
                                    np.array([heading_deg]) if at is not None else None,
                                    names=["view.png"] if at is not None else None, openings=summary.gaps,
                                    labels=labels, label_xy=label_points(model.polygons[:len(labels)]) if labels else None,
                                    grid=summary.grid[:, :2], title=title,
                                    est_label="the point view.png is seen from", windows=summary.windows)]
    if at is not None:
        if summary.z is None:
            raise ValueError("the view needs a camera height: the plan gives none (camera_z); give --z")
        lines = view_lines(model, at[0], at[1], summary.z, heading_deg)
        if photo is not None:
            from placeloc.umap.plots import plot_panorama_overlay

            plot_panorama_overlay(out_dir / "photo.png", photo.photo_lines, photo.map_lines, None,
                                  f"the photo against the map at ({at[0]:g}, {at[1]:g}), heading {photo.heading_deg:g} deg "
                                  f"(its best), score {photo.score:.3f}")
            paths.append(out_dir / "photo.png")
        paths.append(plot_map_view(out_dir / "view.png", lines,
                                   f"{Path(summary.source).name}: the map's lines from ({at[0]:g}, {at[1]:g}) at "
                                   f"{summary.z:.2f} m, centre column heading {heading_deg:g} deg (0 along +x)"))
    return paths


def rooms_template(summary: PlanSummary, photos: Path, out_dir: Path) -> tuple[Path, int]:
    """Write ``out_dir/rooms.csv``: a ``umap.room_hints`` file with a row for each image of the
    folder ``photos`` (named as localize names them) and its room left empty, for the person
    who took them to fill in. Returns its path and the number of photos. A plan without named
    rooms is refused (a hint would have nothing to name)."""
    from placeloc.core.images import list_images

    if summary.kind != "rooms":
        what = {"outline": "an outline plan", "wireframe": "a wireframe"}.get(summary.kind, summary.kind)
        raise ValueError(f"{summary.source}: {what} names no rooms; umap.room_hints needs a plan of rooms")
    frames = list_images(photos).names
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "rooms.csv"
    with atomic_open(path, newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "room"])
        w.writerows([name, ""] for name in frames)
    return path, len(frames)

