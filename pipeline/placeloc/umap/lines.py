"""Query line images: LSD segments drawn into binary images of the database camera's size."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from placeloc.core.images import ImageError
from placeloc.geometry import Camera
from placeloc.geometry.panorama import detect_segments


def line_image(gray: np.ndarray, cam: Camera, *, min_length: float, thickness: int) -> np.ndarray:
    """LSD segments of ``gray`` drawn into a binary image of the database camera's size.

    ``gray`` must have the camera's aspect ratio; segments are scaled by cam.width / width
    and those shorter than ``min_length`` (database pixels) are dropped."""
    segs = detect_segments(gray) * (cam.width / gray.shape[1])
    keep = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]) >= min_length
    img = np.zeros((cam.height, cam.width), np.uint8)
    for x0, y0, x1, y1 in segs[keep]:
        cv2.line(img, (int(round(x0)), int(round(y0))), (int(round(x1)), int(round(y1))), 1, int(thickness))
    return img


ASPECT_TOLERANCE = 0.01   # a query image's aspect ratio may differ from the one wanted by this share


def check_query_size(path: Path, shape: tuple[int, ...], first: tuple[int, ...] | None, cam: Camera, kind: str) -> None:
    """Every query image of a run has one size, with the database camera's aspect ratio
    (pinhole) or 2:1 (equirectangular); the error names the file and the fix."""
    h, w = shape[:2]
    if first is not None and (h, w) != first:
        raise ImageError(f"{path}: query image is {w}x{h} but the first query image is {first[1]}x{first[0]}; "
                         "all query images of one run must have the same size")
    want = 2.0 if kind == "equirect" else cam.width / cam.height
    if abs(w / h - want) > ASPECT_TOLERANCE * want:
        what = ("an equirectangular panorama needs width = 2 x height (a 360 degree photo as the camera app exports "
                "it, not cropped), or a photo sphere stored cropped with its Photo Sphere metadata (GPano) kept; "
                "for ordinary photos set umap.query_kind: pinhole") if kind == "equirect" else (
            f"the database camera is {cam.width}x{cam.height}: set umap.camera.width/height to the images' aspect ratio or resize them")
        raise ImageError(f"{path}: query image is {w}x{h} (aspect {w / h:.3f}); {what}")
