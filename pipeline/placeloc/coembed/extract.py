"""Observation matrices from images: ArUco markers (paper's experiment 1) and SIFT tracks (experiment 2).

Experiment 1 records, per frame, each marker's id and the horizontal image coordinate of its
centre; we do the same with OpenCV's aruco module (``image_values: x``), or keep both
coordinates (``xy``). Experiment 2 tracks SIFT features through the video by matching each
frame to the next (Lowe's ratio test, plus a mutual check so a track never forks); a track
is a feature id. Per-image work (detection) is a module-level function the engine
(:mod:`placeloc.core.imagework`) maps over the frames; the chaining of matches into tracks
is sequential by nature.
"""

from __future__ import annotations

from typing import Callable, Iterable

import cv2
import numpy as np

from placeloc.core.imagework import ImageWork


class ExtractError(ValueError):
    """Images gave no usable observations; the message says what to check."""


def aruco_dictionary(name: str):  # noqa: ANN201 - an OpenCV object
    if not hasattr(cv2, "aruco"):
        raise ExtractError("this OpenCV build has no aruco module: install opencv-contrib-python-headless")
    const = getattr(cv2.aruco, name, None)
    if not isinstance(const, int):
        raise ExtractError(f"coembed.aruco_dictionary: {name!r} is not an OpenCV aruco dictionary (e.g. DICT_4X4_50)")
    return cv2.aruco.getPredefinedDictionary(const)


def marker_arrays(gray: np.ndarray, *, dictionary: str) -> dict[str, np.ndarray]:
    """The engine's per-image function for ArUco markers: marker ``ids`` (n,) int64 and
    their ``centres`` (n, 2) in pixels (both ragged)."""
    detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), cv2.aruco.DetectorParameters())
    corners, ids, _ = detector.detectMarkers(gray)
    if ids is None or len(ids) == 0:
        return {"ids": np.zeros(0, np.int64), "centres": np.zeros((0, 2))}
    centres = np.array([np.asarray(c).reshape(-1, 2).mean(axis=0) for c in corners], dtype=np.float64)
    ids = np.asarray(ids).ravel().astype(np.int64)
    # A marker id seen twice in one frame is ambiguous (two printed copies): drop it rather than guess.
    uniq, counts = np.unique(ids, return_counts=True)
    keep = np.isin(ids, uniq[counts == 1])
    return {"ids": ids[keep], "centres": centres[keep]}


def sift_arrays(gray: np.ndarray, *, n_features: int) -> dict[str, np.ndarray]:
    """The engine's per-image function for SIFT: keypoint positions ``xy`` (n, 2) and
    ``descriptors`` (n, 128) float32 (both ragged)."""
    sift = cv2.SIFT_create(nfeatures=n_features)
    kps, desc = sift.detectAndCompute(gray, None)
    if desc is None or not kps:
        return {"xy": np.zeros((0, 2), np.float32), "descriptors": np.zeros((0, 128), np.float32)}
    return {"xy": np.array([k.pt for k in kps], np.float32), "descriptors": desc.astype(np.float32)}


def _mutual_ratio_matches(d0: np.ndarray, d1: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    if len(d0) < 2 or len(d1) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    bf = cv2.BFMatcher(cv2.NORM_L2)
    fwd = bf.knnMatch(d0, d1, k=2)
    i0, i1 = [], []
    for pair in fwd:
        if len(pair) == 2 and pair[0].distance < ratio * pair[1].distance:
            i0.append(pair[0].queryIdx)
            i1.append(pair[0].trainIdx)
    if not i0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    back = np.array([m.trainIdx for m in bf.match(d1, d0)])
    i0, i1 = np.array(i0), np.array(i1)
    ok = back[i1] == i0
    return i0[ok], i1[ok]


def sift_tracks(per_frame: list[tuple[np.ndarray, np.ndarray]], *, ratio: float, min_track: int,
                id_offset: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Chain frame-to-frame matches into tracks; returns (frame, track id, x y) of tracks seen >= min_track times."""
    frames, tracks, pts = [], [], []
    next_id = 0
    prev_ids: np.ndarray | None = None
    for t, (xy, desc) in enumerate(per_frame):
        ids = np.full(len(xy), -1, np.int64)
        if prev_ids is not None and t > 0:
            a, b = _mutual_ratio_matches(per_frame[t - 1][1], desc, ratio)
            ids[b] = prev_ids[a]
        new = ids < 0
        ids[new] = np.arange(next_id, next_id + int(new.sum()))
        next_id += int(new.sum())
        frames.append(np.full(len(xy), t))
        tracks.append(ids)
        pts.append(xy)
        prev_ids = ids
    if not frames:
        raise ExtractError("no frames to track SIFT features in")
    f, k, p = np.concatenate(frames), np.concatenate(tracks), np.vstack(pts).astype(np.float64)
    counts = np.bincount(k, minlength=next_id) if next_id else np.zeros(0, int)
    keep = counts[k] >= min_track
    if not keep.any():
        raise ExtractError(f"no SIFT track lasts {min_track} frames: frames too far apart, or too little texture")
    return f[keep], k[keep] + id_offset, p[keep]


def observations_from_images(n_frames: int, *, source: str, image_values: str, aruco_dictionary: str,
                             sift_features: int, sift_ratio: float, sift_min_track: int, sift_id_offset: int,
                             describe: Callable[[ImageWork], Iterable[dict[str, np.ndarray]]],
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(step, feature, values) triplets from a sequence of ``n_frames`` frames, by
    ``source`` (aruco, sift or aruco+sift). ``describe(work)`` gives each frame's arrays for
    a per-image work, in frame order (the engine's :class:`placeloc.core.imagework.ImageStream`)."""
    use = [0] if image_values == "x" else [0, 1]
    steps, feats, vals = [], [], []
    if source in ("aruco", "aruco+sift"):
        markers = ImageWork(fn=marker_arrays, settings={"dictionary": aruco_dictionary}, ragged=("ids", "centres"))
        for t, frame in enumerate(describe(markers)):
            steps.append(np.full(len(frame["ids"]), t))
            feats.append(frame["ids"])
            vals.append(frame["centres"][:, use])
    if source in ("sift", "aruco+sift"):
        sift = ImageWork(fn=sift_arrays, settings={"n_features": sift_features}, ragged=("xy", "descriptors"))
        per_frame = [(frame["xy"], frame["descriptors"]) for frame in describe(sift)]
        offset = sift_id_offset if source == "aruco+sift" else 0
        f, k, p = sift_tracks(per_frame, ratio=sift_ratio, min_track=sift_min_track, id_offset=offset)
        steps.append(f)
        feats.append(k)
        vals.append(p[:, use])
    s = np.concatenate(steps) if steps else np.zeros(0, np.int64)
    if len(s) == 0:
        raise ExtractError(f"no {source} observations in {n_frames} images: check coembed.images and the marker dictionary")
    return s, np.concatenate(feats), np.vstack(vals)
