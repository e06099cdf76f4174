"""The one pose reader: a CSV of per-frame positions (and optionally height and heading).

Columns are found by name (case-insensitive, surrounding spaces ignored):

- the frame key, one of ``frame``, ``t``, ``step``, ``index``, ``image``, ``name``,
  ``file``, ``filename``: an integer frame number (a position in the folder's natural
  order, or a time step) or an image file name;
- the position: ``x``/``y``, or ``easting``/``northing``, or ``utm_e``/``utm_n``;
- optional ``z``;
- optional heading: ``heading`` or ``yaw`` in radians, ``heading_deg`` or ``yaw_deg`` in
  degrees (returned in radians).

Every problem is a :class:`PoseError` naming the file, the line and the fix.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

KEY_COLUMNS = ("frame", "t", "step", "index", "image", "name", "file", "filename")
XY_COLUMNS = (("x", "y"), ("easting", "northing"), ("utm_e", "utm_n"))
HEADING_COLUMNS = {"heading": 1.0, "yaw": 1.0, "heading_deg": math.pi / 180, "yaw_deg": math.pi / 180}


class PoseError(ValueError):
    """A pose file cannot be read or does not cover the frames it must cover."""


@dataclass(frozen=True)
class Poses:
    """Poses in file order. ``keys`` are the frame keys as written; ``frames`` holds them
    as integers when every key is an integer (else None)."""

    path: Path
    keys: tuple[str, ...]
    xy: np.ndarray
    z: np.ndarray | None = None
    heading: np.ndarray | None = None
    frames: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.keys)

    def rows_for_frames(self, n: int, *, what: str = "frames") -> np.ndarray:
        """Row of each frame 0..n-1 (integer keys); a missing frame is an error."""
        if self.frames is None:
            raise PoseError(f"{self.path}: the frame column holds names, not frame numbers; "
                            f"give one row per frame numbered 0..{n - 1} (or name the images)")
        row = {int(f): i for i, f in enumerate(self.frames)}
        missing = [t for t in range(n) if t not in row]
        if missing:
            raise PoseError(f"{self.path}: no pose for {len(missing)} of {n} {what} (first: frame {missing[0]}); "
                            f"the file must list frames 0..{n - 1}")
        return np.array([row[t] for t in range(n)], np.int64)

    def rows_for_names(self, names: Sequence[str], *, what: str = "images") -> np.ndarray:
        """Row of each image name (matched by file name, with or without the folder)."""
        row = {Path(k).name: i for i, k in enumerate(self.keys)}
        missing = [n for n in names if Path(n).name not in row]
        if missing:
            raise PoseError(f"{self.path}: no pose for {len(missing)} of {len(names)} {what} (first: {missing[0]}); "
                            "add a row for each image, keyed by its file name")
        return np.array([row[Path(n).name] for n in names], np.int64)


def _column(fields: list[str], options: Sequence[str]) -> str | None:
    lower = {f.strip().lower(): f for f in fields}
    for name in options:
        if name in lower:
            return lower[name]
    return None


def read_poses(path: str | Path, *, what: str = "poses") -> Poses:
    """Read a pose CSV (see the module docstring for the columns it understands)."""
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            fields = list(reader.fieldnames or [])
            rows = list(reader)
    except FileNotFoundError:
        raise PoseError(f"{what}: {path} does not exist; fix the path (relative paths start at the config's folder)") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise PoseError(f"{what}: {path} cannot be read as a CSV file ({exc})") from exc
    key_col = _column(fields, KEY_COLUMNS)
    xy_cols = next(((cx, cy) for a, b in XY_COLUMNS if (cx := _column(fields, (a,))) and (cy := _column(fields, (b,)))), None)
    if key_col is None or xy_cols is None:
        raise PoseError(f"{what}: {path} needs a header with a frame column ({', '.join(KEY_COLUMNS[:4])} or image) "
                        f"and positions (x,y / easting,northing / utm_e,utm_n); it has {fields}")
    if not rows:
        raise PoseError(f"{what}: {path} has a header but no rows")
    z_col = _column(fields, ("z",))
    head_col = _column(fields, tuple(HEADING_COLUMNS))
    head_scale = HEADING_COLUMNS[head_col.strip().lower()] if head_col else 1.0
    keys, xy, z, heading = [], np.empty((len(rows), 2)), np.empty(len(rows)), np.empty(len(rows))
    for i, r in enumerate(rows):
        line = i + 2
        try:
            keys.append(str(r[key_col]).strip())
            xy[i] = float(r[xy_cols[0]]), float(r[xy_cols[1]])
            if z_col:
                z[i] = float(r[z_col])
            if head_col:
                heading[i] = float(r[head_col]) * head_scale
        except (TypeError, ValueError) as exc:
            raise PoseError(f"{what}: {path}:{line}: positions{', z' if z_col else ''}{' and heading' if head_col else ''} "
                            f"must be numbers ({exc})") from None
        if not keys[-1]:
            raise PoseError(f"{what}: {path}:{line}: the {key_col} column is empty")
    if not np.isfinite(xy).all():
        bad = int(np.flatnonzero(~np.isfinite(xy).all(axis=1))[0])
        raise PoseError(f"{what}: {path}:{bad + 2}: position is not finite")
    if len(set(keys)) != len(keys):
        seen: set[str] = set()
        dup = next(k for k in keys if k in seen or seen.add(k))  # type: ignore[func-returns-value]
        raise PoseError(f"{what}: {path} lists frame {dup!r} twice; give one row per frame")
    frames = None
    if all(k.lstrip("-").isdigit() for k in keys):
        frames = np.array([int(k) for k in keys], np.int64)
    return Poses(path=path, keys=tuple(keys), xy=xy, z=z if z_col else None, heading=heading if head_col else None,
                 frames=frames)
