"""The one pose reader: a CSV of per-frame positions (and optionally height and heading).

Columns are found by name (case-insensitive, surrounding spaces ignored):

- the frame key, one of ``frame``, ``t``, ``step``, ``index``, ``image``, ``name``,
  ``file``, ``filename``: an integer frame number (a position in the folder's natural
  order, or a time step) or an image file name;
- the position: ``x``/``y``, or ``easting``/``northing``, or ``utm_e``/``utm_n`` (metres),
  or ``lat``/``lon`` (also ``latitude``/``longitude``, ``lng``; WGS84 degrees, projected to
  UTM metres in the zone of the file's first row, see :func:`latlon_to_utm`);
- optional ``z``;
- optional ``traverse`` (or ``role``): ``reference`` or ``query`` (also ``db``/``database``/
  ``map`` and ``queries``), so that one file can hold both traverses of a pair; a key may
  then appear once per traverse;
- optional heading: ``heading`` or ``yaw`` in radians, ``heading_deg`` or ``yaw_deg`` in
  degrees (returned in radians).

Every problem is a :class:`PoseError` naming the file, the line and the fix.
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from placeloc.core.safe_io import UnsafeInputError, read_input_text, separator_hint

KEY_COLUMNS = ("frame", "t", "step", "index", "image", "name", "file", "filename")
XY_COLUMNS = (("x", "y"), ("easting", "northing"), ("utm_e", "utm_n"))
LATLON_COLUMNS = (("lat", "lon"), ("latitude", "longitude"), ("lat", "lng"))
TRAVERSE_COLUMNS = ("traverse", "role")
TRAVERSE_NAMES = {"reference": "reference", "ref": "reference", "db": "reference", "database": "reference",
                  "map": "reference", "query": "query", "queries": "query", "q": "query"}

# WGS84 ellipsoid and the UTM grid.
WGS84_A = 6378137.0
WGS84_F = 1 / 298.257223563
UTM_K0 = 0.9996
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
    traverse: tuple[str, ...] | None = None
    utm_zone: str | None = None  # e.g. "38N" when the file gave lat/lon

    def __len__(self) -> int:
        return len(self.keys)

    def _rows(self, traverse: str | None) -> list[int]:
        if traverse is None or self.traverse is None:
            return list(range(len(self.keys)))
        rows = [i for i, t in enumerate(self.traverse) if t == traverse]
        if not rows:
            raise PoseError(f"{self.path}: no row has traverse {traverse!r}; "
                            "give each row a traverse column value of reference or query")
        return rows

    def rows_for_frames(self, n: int, *, what: str = "frames", traverse: str | None = None) -> np.ndarray:
        """Row of each frame 0..n-1 (integer keys); a missing frame is an error. With a
        ``traverse`` column, only the rows of ``traverse`` (``reference``/``query``) count."""
        if self.frames is None:
            raise PoseError(f"{self.path}: the frame column holds names, not frame numbers; "
                            f"give one row per frame numbered 0..{n - 1} (or name the images)")
        row = {int(self.frames[i]): i for i in self._rows(traverse)}
        missing = [t for t in range(n) if t not in row]
        if missing:
            raise PoseError(f"{self.path}: no pose for {len(missing)} of {n} {what} (first: frame {missing[0]}); "
                            f"the file must list frames 0..{n - 1}")
        return np.array([row[t] for t in range(n)], np.int64)

    def rows_for_names(self, names: Sequence[str], *, what: str = "images", traverse: str | None = None) -> np.ndarray:
        """Row of each image name (matched by file name, with or without the folder). With a
        ``traverse`` column, only the rows of ``traverse`` (``reference``/``query``) count."""
        row: dict[str, int] = {}
        for i in self._rows(traverse):
            name = Path(self.keys[i]).name
            if name in row and traverse is None:
                raise PoseError(f"{self.path}: image name {name!r} appears twice (lines {row[name] + 2} and {i + 2}); "
                                "add a traverse column (reference/query) to say which folder each row is for")
            row[name] = i
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
        if not path.exists():
            raise PoseError(f"{what}: {path} does not exist; fix the path (relative paths start at the config's folder)")
        # utf-8-sig: a byte-order mark (Excel writes one) is not part of the first column's name
        reader = csv.DictReader(io.StringIO(read_input_text(path, what, encoding="utf-8-sig"), newline=""))
        fields = list(reader.fieldnames or [])
        rows = list(reader)
    except UnsafeInputError as exc:
        raise PoseError(str(exc)) from None
    except (OSError, csv.Error) as exc:
        raise PoseError(f"{what}: {path} cannot be read as a CSV file ({exc})") from exc
    key_col = _column(fields, KEY_COLUMNS)
    xy_cols = next(((cx, cy) for a, b in XY_COLUMNS if (cx := _column(fields, (a,))) and (cy := _column(fields, (b,)))), None)
    latlon_cols = None
    if xy_cols is None:
        latlon_cols = next(((ca, co) for a, b in LATLON_COLUMNS
                            if (ca := _column(fields, (a,))) and (co := _column(fields, (b,)))), None)
    if key_col is None or (xy_cols is None and latlon_cols is None):
        raise PoseError(f"{what}: {path} needs a header with a frame column ({', '.join(KEY_COLUMNS[:4])} or image) "
                        f"and positions (x,y / easting,northing / utm_e,utm_n / lat,lon); it has {fields}"
                        f"{separator_hint(fields)}")
    trav_col = _column(fields, TRAVERSE_COLUMNS)
    if not rows:
        raise PoseError(f"{what}: {path} has a header but no rows")
    z_col = _column(fields, ("z",))
    head_col = _column(fields, tuple(HEADING_COLUMNS))
    head_scale = HEADING_COLUMNS[head_col.strip().lower()] if head_col else 1.0
    keys, xy, z, heading = [], np.empty((len(rows), 2)), np.empty(len(rows)), np.empty(len(rows))
    traverse: list[str] = []
    pos_cols = xy_cols or latlon_cols
    assert pos_cols is not None
    for i, r in enumerate(rows):
        line = i + 2
        if trav_col:
            t = str(r[trav_col] or "").strip().lower()
            if t not in TRAVERSE_NAMES:
                raise PoseError(f"{what}: {path}:{line}: {trav_col} is {r[trav_col]!r}; write reference or query")
            traverse.append(TRAVERSE_NAMES[t])
        if any(r[c] is None for c in (key_col, *pos_cols, z_col, head_col) if c):
            # csv.DictReader fills a short row's missing values with None: say so, not
            # "float() argument must be ... not 'NoneType'"
            raise PoseError(f"{what}: {path}:{line}: {len([v for k, v in r.items() if k is not None and v is not None])} "
                            f"values where the header has {len(fields)} ({','.join(fields)}); complete the row (a "
                            "line break inside a value, a lone carriage return, splits a row in two)")
        try:
            keys.append(str(r[key_col]).strip())
            xy[i] = float(r[pos_cols[0]]), float(r[pos_cols[1]])
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
    if head_col and head_scale == 1.0 and np.nanmax(np.abs(heading)) > 2 * math.pi + 0.01:
        # `heading`/`yaw` are radians; values past a turn are almost always degrees (a wound-up
        # odometry angle is the rare exception), and read as radians every yaw error is noise
        big = float(np.nanmax(np.abs(heading)))
        import logging

        logging.getLogger("placeloc").warning(
            "%s: %s: the %s column is read in radians, but its values reach %g, more than a turn: if they are "
            "degrees, name the column %s_deg", what, path, head_col, big, head_col.strip().lower())
    zone = None
    if latlon_cols is not None:
        bad_lat = np.flatnonzero((np.abs(xy[:, 0]) > 84) | (xy[:, 0] < -80) | (np.abs(xy[:, 1]) > 180))
        if bad_lat.size:
            raise PoseError(f"{what}: {path}:{int(bad_lat[0]) + 2}: lat {xy[bad_lat[0], 0]}, lon {xy[bad_lat[0], 1]} is "
                            "outside the UTM grid (-80..84 degrees latitude, -180..180 longitude); "
                            "check that the columns are latitude, longitude in degrees")
        number = utm_zone_number(xy[0, 0], xy[0, 1])
        north = bool(xy[0, 0] >= 0)
        e, n = latlon_to_utm(xy[:, 0], xy[:, 1], zone=number, north=north)
        xy = np.column_stack([e, n])
        zone = f"{number}{'N' if north else 'S'}"
    tagged = list(zip(traverse, keys)) if trav_col else keys
    if len(set(tagged)) != len(tagged):
        seen: set = set()
        dup = next(k for k in tagged if k in seen or seen.add(k))  # type: ignore[func-returns-value]
        raise PoseError(f"{what}: {path} lists frame {dup!r} twice; give one row per frame")
    frames = None
    if all(k.lstrip("-").isdigit() for k in keys):
        frames = np.array([int(k) for k in keys], np.int64)
    return Poses(path=path, keys=tuple(keys), xy=xy, z=z if z_col else None, heading=heading if head_col else None,
                 frames=frames, traverse=tuple(traverse) if trav_col else None, utm_zone=zone)


def utm_zone_number(lat: float, lon: float) -> int:
    """The UTM zone of a point, with the Norway and Svalbard exceptions."""
    zone = int((lon + 180) // 6) % 60 + 1
    if 56 <= lat < 64 and 3 <= lon < 12:
        zone = 32
    if 72 <= lat < 84 and lon >= 0:
        zone = 31 if lon < 9 else 33 if lon < 21 else 35 if lon < 33 else 37 if lon < 42 else zone
    return zone


def latlon_to_utm(lat: np.ndarray | float, lon: np.ndarray | float, *, zone: int, north: bool) -> tuple[np.ndarray, np.ndarray]:
    """WGS84 latitude/longitude (degrees) to UTM easting/northing (metres) in ``zone``.

    Transverse Mercator by Krüger's series to fourth order in the third flattening n
    (C. F. F. Karney, "Transverse Mercator with an accuracy of a few nanometers", J. Geodesy
    2011): sub-millimetre within a zone, and still metre-accurate a few degrees outside it,
    so one zone serves a whole data set that straddles a zone border.
    """
    lat = np.radians(np.asarray(lat, np.float64))
    lon = np.asarray(lon, np.float64)
    lon0 = np.radians(zone * 6 - 183)
    dlon = np.radians(lon) - lon0
    n = WGS84_F / (2 - WGS84_F)
    big_a = WGS84_A / (1 + n) * (1 + n**2 / 4 + n**4 / 64)
    alpha = (n / 2 - 2 / 3 * n**2 + 5 / 16 * n**3 + 41 / 180 * n**4,
             13 / 48 * n**2 - 3 / 5 * n**3 + 557 / 1440 * n**4,
             61 / 240 * n**3 - 103 / 140 * n**4,
             49561 / 161280 * n**4)
    c = 2 * math.sqrt(n) / (1 + n)
    t = np.sinh(np.arctanh(np.sin(lat)) - c * np.arctanh(c * np.sin(lat)))
    xi = np.arctan2(t, np.cos(dlon))
    eta = np.arctanh(np.sin(dlon) / np.sqrt(1 + t**2))
    e_sum, n_sum = eta.copy(), xi.copy()
    for j, a_j in enumerate(alpha, start=1):
        e_sum += a_j * np.cos(2 * j * xi) * np.sinh(2 * j * eta)
        n_sum += a_j * np.sin(2 * j * xi) * np.cosh(2 * j * eta)
    easting = 500000.0 + UTM_K0 * big_a * e_sum
    northing = UTM_K0 * big_a * n_sum + (0.0 if north else 10000000.0)
    return easting, northing


_AT_NAME = re.compile(r"^@(-?[0-9.]+(?:e-?[0-9]+)?)@(-?[0-9.]+(?:e-?[0-9]+)?)@")


def positions_from_names(names: Sequence[str], *, what: str = "images") -> np.ndarray:
    """UTM easting, northing (metres) from file names written as the place-recognition
    benchmarks of Berton et al. (pitts30k, MSLS, SF-XL in VPR-methods-evaluation's format)
    write them: ``@UTM_east@UTM_north@...@.jpg``."""
    out = np.empty((len(names), 2))
    for i, name in enumerate(names):
        m = _AT_NAME.match(Path(name).name)
        if m is None:
            raise PoseError(f"{what}: file name {name!r} does not start with @UTM_east@UTM_north@ "
                            "(as in @0543256.96@4178906.42@...@.jpg); give a positions CSV instead")
        out[i] = float(m.group(1)), float(m.group(2))
    return out
