"""Pinhole camera geometry for image-point observations: intrinsics, undistortion, normalised coordinates.

A perspective camera sees a point X (in the camera's frame) at pixel (u, v) with
[u, v, 1] ~ K [X / Z], after radial (k1, k2, k3) and tangential (p1, p2) distortion of the
normalised point. Undistorting and applying K^-1 gives the normalised direction
d = [(u - cx) / f, (v - cy) / f, 1], so X = Z d: the point is linear in d once its depth Z
is known. That is what :mod:`placeloc.coembed.perspective` builds on.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from placeloc.coembed.observations import ObservationError


@dataclass(frozen=True)
class Intrinsics:
    f: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float]   # OpenCV order k1, k2, p1, p2, k3


def read_intrinsics(path: str | Path) -> Intrinsics:
    """CSV with columns f, cx, cy and optionally k1, k2, k3, p1, p2 (one row: one camera)."""
    path = Path(path)
    if not path.is_file():
        raise ObservationError(f"coembed.intrinsics: {path} does not exist")
    with path.open(newline="", encoding="utf-8-sig") as fh:  # a BOM is not part of the first column's name
        reader = csv.DictReader(fh)
        rows = list(reader)
        header = list(reader.fieldnames or [])
    if len(rows) != 1:
        raise ObservationError(f"coembed.intrinsics: {path} must hold exactly one camera row (it has {len(rows)})")
    row = {k.strip().lower(): v for k, v in rows[0].items() if k}
    try:
        f, cx, cy = float(row["f"]), float(row["cx"]), float(row["cy"])
        dist = tuple(float(row.get(k) or 0.0) for k in ("k1", "k2", "p1", "p2", "k3"))
    except KeyError as exc:
        from placeloc.core.safe_io import separator_hint

        raise ObservationError(f"coembed.intrinsics: {path} needs columns f, cx, cy (optionally k1, k2, k3, p1, p2); "
                               f"missing {exc}{separator_hint(header)}") from None
    except ValueError as exc:
        raise ObservationError(f"coembed.intrinsics: {path}:2: values must be numbers ({exc})") from None
    if f <= 0:
        raise ObservationError(f"coembed.intrinsics: {path}: focal length f must be > 0, got {f}")
    return Intrinsics(f, cx, cy, dist)  # type: ignore[arg-type]


def normalised_coordinates(pixels: np.ndarray, cam: Intrinsics) -> np.ndarray:
    """(n, 2) pixels -> (n, 2) undistorted normalised image coordinates ((u - cx) / f after undistortion)."""
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim != 2 or pixels.shape[1] != 2:
        raise ObservationError("normalised coordinates need both image coordinates per sighting (coembed.image_values: xy)")
    if not any(cam.dist):
        return (pixels - [cam.cx, cam.cy]) / cam.f
    import cv2

    k = np.array([[cam.f, 0, cam.cx], [0, cam.f, cam.cy], [0, 0, 1]], dtype=np.float64)
    und = cv2.undistortPoints(pixels.reshape(-1, 1, 2), k, np.array(cam.dist, dtype=np.float64))
    return und.reshape(-1, 2)
