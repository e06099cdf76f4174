"""Each photo's room where the person who took it knows it (``umap.room_hints``): the whole
panorama search kept to that room.

Whoever stands in a home with a 360 degree camera knows which room they are in; what they
want is where in it, and which way they face. Lines alone cannot tell a bedroom from its
look-alike next door, nor place a photo of a white room whose few detected lines are
clutter (docs/umap.md): a room named for the photo takes those rivals out of the search.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from placeloc.core.errors import ConfigError
from placeloc.geometry.floorplan import segment_distances
from placeloc.geometry.polygons import point_in_polygon


def room_label(name: str) -> str:
    """The label of a room name of the form ``id (label)`` (as the ZInD importer names rooms,
    ``complete_room_3 (kitchen)``), else the name itself."""
    name = str(name).strip()
    if name.endswith(")") and " (" in name:
        return name[name.rindex(" (") + 2:-1].strip()
    return name


def matching_rooms(hint: str, names: Sequence[str]) -> list[int]:
    """The rooms (indices into ``names``) a hint names: those whose name, or whose label in
    parentheses (:func:`room_label`), equals it, ignoring case. Every match counts, so that
    ``bedroom`` names every room labelled so (the photo was taken in one of them)."""
    want = hint.strip().casefold()
    return [i for i, n in enumerate(names) if want in (str(n).strip().casefold(), room_label(n).casefold())]


class RoomRegion:
    """The plan points a photo taken in some rooms may stand at: inside one of their
    polygons, or within ``margin_m`` of one's outline (a camera in a doorway counts for
    either room it joins)."""

    def __init__(self, polygons: Sequence[np.ndarray], margin_m: float) -> None:
        self.polygons = [np.asarray(p, float).reshape(-1, 2) for p in polygons]
        self.margin_m = float(margin_m)
        self.edges = np.concatenate([np.column_stack([p, np.roll(p, -1, axis=0)]) for p in self.polygons]) \
            if self.polygons else np.zeros((0, 4))

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, float).reshape(-1, 2)
        inside = np.zeros(len(xy), bool)
        for poly in self.polygons:
            inside |= point_in_polygon(xy, poly)
        rest = np.flatnonzero(~inside)
        if len(rest) and len(self.edges) and self.margin_m > 0:
            for s in range(0, len(rest), 4096):   # chunks keep the (points x edges) temporaries small
                part = rest[s:s + 4096]
                inside[part] = segment_distances(xy[part], self.edges).min(axis=1) <= self.margin_m + 1e-9
        return inside


def read_room_hints(path: str | Path, frames: Sequence[str], room_names: Sequence[str]) -> tuple[list[str | None], list[str]]:
    """Each query frame's room hint from a CSV with the columns ``frame`` and ``room`` (None
    where the frame has no row, or an empty room), and the CSV's frames that are not query
    frames (for the caller to warn about). A room must name at least one of the plan's rooms
    (:func:`matching_rooms`). A frame given with a folder (``photos/IMG_1.jpg``) names the query
    frame of its file name. Errors name the file, the line and the fix."""
    path = Path(path)
    if not room_names:
        raise ConfigError(f"umap.room_hints {path}: the model names no rooms (only a floor plan of rooms does, or a "
                          "ZInD zind_data.json); leave room_hints out")
    try:
        f = open(path, newline="", encoding="utf-8-sig")   # a BOM is not part of the header
    except OSError as exc:
        raise ConfigError(f"umap.room_hints: cannot read {path} ({exc.strerror or exc}); give a CSV with the columns "
                          "frame, room") from exc
    hints: dict[str, str] = {}
    with f:
        reader = csv.DictReader(f)
        if reader.fieldnames is None or not {"frame", "room"} <= {c.strip() for c in reader.fieldnames}:
            raise ConfigError(f"{path}: umap.room_hints needs a CSV with the columns frame, room (it has "
                              f"{reader.fieldnames})")
        for line, row in enumerate(reader, 2):
            row = {(k or "").strip(): (v or "").strip() for k, v in row.items() if k is not None}
            frame, room = row.get("frame", ""), row.get("room", "")
            if not frame:
                raise ConfigError(f"{path}:{line}: a row with no frame; give the photo's file name, e.g. pano_000.png")
            if frame in hints and hints[frame] != room:
                raise ConfigError(f"{path}:{line}: {frame} is given twice, in {hints[frame]!r} and {room!r}; keep one")
            if room and not matching_rooms(room, room_names):
                known = ", ".join(dict.fromkeys(str(n) for n in room_names))
                raise ConfigError(f"{path}:{line}: {room!r} names none of the plan's rooms ({known}); give one of "
                                  "them, or a label in parentheses (kitchen for 'complete_room_3 (kitchen)')")
            hints[frame] = room
    # a frame given with its folder (photos/IMG_1.jpg) names the query image of that file name:
    # query frames are named by file name alone
    wanted = set(frames)
    for k in [k for k in hints if k not in wanted and Path(k).name in wanted and Path(k).name not in hints]:
        hints[Path(k).name] = hints.pop(k)
    stray = [k for k in hints if k not in wanted]
    return [hints.get(k) or None for k in frames], stray
