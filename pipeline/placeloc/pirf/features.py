"""Local features per frame (SIFT default; AKAZE, ORB; SURF where OpenCV has it).

Every descriptor is returned as float32 so one L2 code path (BLAS, FLANN, faiss) serves
all types: ORB's and AKAZE's binary descriptors are unpacked to 0/1 bits, whose squared
L2 distance equals the Hamming distance.
"""

from __future__ import annotations

import cv2
import numpy as np

from placeloc.core.images import ImageError, akaze_detector, read_gray

FEATURE_TYPES = ("sift", "akaze", "orb", "surf")


def make_detector(kind: str, n_features: int) -> cv2.Feature2D:
    """OpenCV detector for ``kind``; AKAZE lives in cv2.xfeatures2d from OpenCV 5 on."""
    if kind == "sift":
        return cv2.SIFT_create(nfeatures=n_features)
    if kind == "orb":
        return cv2.ORB_create(nfeatures=n_features or 1000)
    if kind == "akaze":
        return akaze_detector(None)
    if kind == "surf":
        xf = getattr(cv2, "xfeatures2d", None)
        try:
            return xf.SURF_create(400)  # type: ignore[union-attr]
        except Exception as exc:  # non-free: absent from the pip wheels
            raise ImageError(f"SURF is not available in this OpenCV build ({type(exc).__name__}); "
                             "it is non-free: use pirf.features: sift (the default)") from exc
    raise ValueError(f"unknown feature type {kind!r}; choose one of {', '.join(FEATURE_TYPES)}")


def descriptor_dim(kind: str) -> int:
    return {"sift": 128, "surf": 64, "orb": 256, "akaze": 488}[kind]


def to_float(desc: np.ndarray | None, kind: str) -> np.ndarray:
    if desc is None or len(desc) == 0:
        return np.zeros((0, descriptor_dim(kind)), np.float32)
    if desc.dtype == np.uint8 and kind in ("orb", "akaze"):
        return np.unpackbits(desc, axis=1).astype(np.float32)
    return np.ascontiguousarray(desc, np.float32)


def extract_frame(item: tuple[str, str, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]:
    """Work item for ``ctx.executor.map``: (path, kind, n_features) -> (xy, response, desc, shape)."""
    path, kind, n_features = item
    img = read_gray(path)
    return detect(img, kind, n_features)


def frame_arrays(image: np.ndarray, *, kind: str, n_features: int) -> dict[str, np.ndarray]:
    """The engine's per-image function (:mod:`placeloc.core.imagework`): one greyscale
    frame -> its keypoints ``xy`` (n, 2), ``response`` (n) and float32 ``descriptors``
    (n, d), all ragged."""
    xy, resp, d, _shape = detect(image, kind, n_features)
    return {"xy": xy, "response": resp, "descriptors": d}


def detect(img: np.ndarray, kind: str, n_features: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]:
    """Keypoints (xy), responses, float32 descriptors and the image shape of one greyscale frame."""
    kps, desc = make_detector(kind, n_features).detectAndCompute(img, None)
    xy = np.array([k.pt for k in kps], np.float32).reshape(-1, 2)
    resp = np.array([k.response for k in kps], np.float32)
    d = to_float(desc, kind)
    if n_features and len(d) > n_features:  # ORB/AKAZE ignore the cap: keep the strongest
        keep = np.argsort(-resp)[:n_features]
        xy, resp, d = xy[keep], resp[keep], d[keep]
    return xy, resp, d, (int(img.shape[0]), int(img.shape[1]))
