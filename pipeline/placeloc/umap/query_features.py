"""What one UMap query image gives, for the engine (:mod:`placeloc.core.imagework`).

A pinhole or equirectangular query becomes its packed line image(s) (LSD, one view per
grid heading for an equirectangular image) and the AKAZE keypoints and descriptors of its
first view (UMap+CA); a whole panorama becomes one packed equirectangular line image.
Every query image of a run has one size (the engine checks that against the first one);
its aspect ratio is checked here, per image.
"""

from __future__ import annotations

import numpy as np

from placeloc.core.images import panorama_crop
from placeloc.geometry import Camera, equirect_to_pinhole
from placeloc.geometry.panorama import (
    WHOLE,
    draw_line_image,
    panorama_lines,
    segment_normals,
    upright_rotation,
    whole_panorama,
)
from placeloc.umap import ca as ca_mod
from placeloc.umap.bits import pack
from placeloc.umap.lines import ASPECT_TOLERANCE, check_query_size, line_image
from placeloc.umap.panorama import orientation_channels


def query_camera(shape: tuple[int, int], camera: tuple[int, int, float], kind: str) -> Camera:
    """The camera the query's line images are cut with: twice the database resolution for
    views of an equirectangular image (so LSD sees enough detail), else the image's own size."""
    width, height, hfov = camera
    if kind == "equirect":
        return Camera(int(width) * 2, int(height) * 2, float(hfov))
    return Camera(int(shape[1]), int(shape[0]), float(hfov))


def query_arrays(gray: np.ndarray, *, camera: tuple[int, int, float], kind: str, headings: tuple[float, ...],
                 min_length: float, thickness: int, akaze_threshold: float, path: str = "") -> dict[str, np.ndarray]:
    """One grey query image -> ``lines`` (n_views, n_words) uint64, ``kp_pts`` (k, 2)
    float32 and ``kp_desc`` (k, 61) uint8 (the last two ragged)."""
    cam = Camera(*camera)
    check_query_size(path, gray.shape, None, cam, kind)
    qcam = query_camera(gray.shape[:2], camera, kind)
    views = [equirect_to_pinhole(gray, hd, qcam) for hd in headings] if kind == "equirect" else [gray]
    lines = pack(np.stack([line_image(v, cam, min_length=min_length, thickness=thickness) for v in views]))
    pts, desc = ca_mod.akaze(views[0], akaze_threshold)
    return {"lines": lines, "kp_pts": pts, "kp_desc": desc}


def panorama_arrays(gray: np.ndarray, *, width: int, height: int, face_px: int, min_length: float,
                    orientation_bins: int = 1, level_max_deg: float = 0.0, equalize_clip: float = 0.0,
                    path: str = "") -> dict[str, np.ndarray]:
    """One grey equirectangular panorama -> ``lines`` (B, n_words) uint64: its line image, or
    with ``orientation_bins`` B > 1 its B oriented channels
    (:func:`placeloc.umap.panorama.orientation_channels`), and ``tilt_deg`` (a float32
    scalar): how far its zenith lay from the image's where ``level_max_deg`` > 0 levelled it
    (:func:`placeloc.geometry.panorama.upright_rotation`), else 0. A photo that is not 2:1
    but carries Photo Sphere metadata (GPano: a phone's photo sphere stored cropped to what it
    covered) is placed in its whole panorama first, and only its lines are drawn
    (:func:`placeloc.geometry.panorama.whole_panorama`); ``coverage`` (4,) float32 says what
    part of the sphere it covers (left, top, width, height as fractions; 0 0 1 1: all).
    ``equalize_clip`` > 0: each cube face's contrast is equalised locally before LSD
    (:func:`placeloc.geometry.panorama.equalized`)."""
    coverage = WHOLE
    h, w = gray.shape[:2]
    if abs(w / h - 2.0) > ASPECT_TOLERANCE * 2.0 and path:
        # not 2:1: a photo sphere stored cropped to what it covered, where its GPano metadata says so
        crop = panorama_crop(path)
        if crop is not None:
            gray, coverage = whole_panorama(gray, crop, path)
    check_query_size(path, gray.shape, None, Camera(2, 2, 90.0), "equirect")
    faces = panorama_lines(gray, face_px=face_px, min_length=min_length, equalize_clip=equalize_clip)
    rotation, tilt = upright_rotation(*segment_normals(faces, face_px, coverage), max_tilt_deg=level_max_deg)
    drawn = draw_line_image(faces, face_px=face_px, width=width, height=height,
                            orientation_bins=orientation_bins if orientation_bins > 1 else 0,
                            rotation=None if tilt == 0.0 else rotation, coverage=coverage)
    lines = pack(orientation_channels(drawn, orientation_bins)) if orientation_bins > 1 else pack(drawn[None])
    return {"lines": lines, "tilt_deg": np.float32(tilt),
            "coverage": np.array([coverage.left, coverage.top, coverage.width, coverage.height], np.float32)}
