"""Reading UMap's own artifacts back, for localize, evaluate and ``placeloc show``: the floor
plan at a ceiling height from the build-dictionary artifact, its rooms, the model a run's
answers were found with, and the rows each panorama of the extract artifact covered."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from placeloc.core.artifacts import read_strings
from placeloc.geometry.floorplan import floor_plan_model, rooms_at, with_ceiling
from placeloc.umap.panorama import seen_rows


def model_at_ceiling(plan: Any, ceiling: float) -> tuple[np.ndarray, np.ndarray]:
    """(segments, faces) of the build-dictionary artifact ``plan``'s floor plan with every
    room's ceiling at ``ceiling`` metres (where umap.grid.ceilings searched several; the
    artifact keeps the plan)."""
    m = floor_plan_model(with_ceiling(json.loads(str(plan.attrs["plan_json"])), float(ceiling)),
                         str(plan.attrs.get("model", "floor plan")))
    return m.segments, m.faces


def drawn_ceiling(plan: Any) -> float | None:
    """The ceiling height the build-dictionary artifact ``plan``'s floor plan gives every
    room (its ``ceiling_z``, or each room's own where all agree within 1 cm); None where the
    rooms differ, or the artifact keeps no plan (a wireframe)."""
    if "plan_json" not in plan.attrs:
        return None
    fp = json.loads(str(plan.attrs["plan_json"]))
    top = fp.get("ceiling_z")
    rooms = fp.get("rooms") if isinstance(fp.get("rooms"), list) else []
    declared = [r.get("ceiling_z", top) for r in rooms if isinstance(r, dict)] if rooms else [top]
    heights = [float(h) for h in declared if h is not None]
    if not heights or max(heights) - min(heights) > 0.01:
        return None
    return float(np.median(heights))


def answer_model(plan: Any, loc: Any) -> tuple[np.ndarray, np.ndarray]:
    """The (segments, faces) the run's answers were found with: the build-dictionary
    artifact's, at the ceiling height found where umap.grid.ceilings searched several."""
    if "ceiling_m" not in loc or "plan_json" not in plan.attrs:
        return plan["segments"][()], plan["faces"][()]
    return model_at_ceiling(plan, float(loc["ceiling_m"][0]))


def rooms_of_points(src: Any, *points: np.ndarray) -> list[list[str]]:
    """The plan's room name at each point of each (P, 2) array ("" outside every room, or
    where the plan names none: a wireframe, or a build-dictionary of before room names were
    kept), from the build-dictionary artifact ``src``; the plan read once for all."""
    names, polygons = plan_rooms(src)
    if not names:
        return [[""] * len(xy) for xy in points]
    return [rooms_at(xy, polygons, names) for xy in points]


def plan_rooms(src: Any) -> tuple[list[str], list[np.ndarray]]:
    """The plan's room names and their polygons from the build-dictionary artifact ``src``
    (none where the plan names no rooms: a wireframe, an outline, or a build-dictionary of
    before room names were kept)."""
    if "room_names" not in src or "plan" not in src:
        return [], []
    names = read_strings(src["room_names"])
    return names, [src["plan"][f"polygon_{i}"][()] for i in range(len(names))]


def query_seen_rows(ex: Any, height: int, rows: Any = slice(None)) -> np.ndarray | None:
    """(N, height) the line-image rows each panorama (``rows``) of the extract artifact ``ex``
    covered, as its score counts them (:func:`placeloc.umap.panorama.seen_rows`: photo
    spheres stored cropped, the band narrowed by the tilt levelled), or None for an artifact
    from before coverage was recorded."""
    if "coverage" not in ex:
        return None
    return seen_rows(ex["coverage"][rows], height, ex["tilt_deg"][rows] if "tilt_deg" in ex else None)
