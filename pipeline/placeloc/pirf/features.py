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


# A true loop closure's score (eq. 9) grows with the square of the PIRFs a frame keeps: on
# the generated omnidirectional video (synth omni, layout small, 120 frames, seeds 0-2) the
# median score of the correct closures over (median PIRFs a frame)^2 was 1.2e-6 at 120 x 60
# (27 PIRFs), 1.6e-6 at 240 x 120 (51) and 1.7e-6 at 480 x 240 (84); 1.6e-6 over all nine
# runs (docs/pirf.md, "Your own video"). Table 1's tau 0.015 is thus the score of a typical
# true closure from ~95 PIRFs a frame.
SCORE_PER_PIRF_SQUARED = 1.6e-6


def blank_frames_note(role: str, names: list[str], n_features: np.ndarray, kind: str, shown: int = 5) -> str | None:
    """One line counting and naming the frames where the detector found nothing (None: there
    are none). Such frames are kept as frames without PIRFs; they cannot close a loop, and
    the PIRF tracks through them break."""
    blank = np.flatnonzero(np.asarray(n_features) == 0)
    if not len(blank):
        return None
    listed = ", ".join(names[k] for k in blank[:shown]) + (f" and {len(blank) - shown} more" if len(blank) > shown else "")
    return (f"{role}: {len(blank)} of {len(n_features)} frames have no {kind} features (blank or featureless: {listed}); "
            "kept as frames without PIRFs, which match nothing (pirf.blank_frames: stop refuses them instead)")


def few_features_note(role: str, n_features: np.ndarray, n_pirfs: np.ndarray, windows: np.ndarray, *, shape: tuple[int, int],
                      kind: str, n_pmin: int, tau: float) -> str | None:
    """One line saying why PIRF-nav2 will accept few loop closures on frames this small or
    plain, with the measured counts and what to change (None unless a true closure at the
    median PIRF count is expected to score below half of ``tau``: then most fall below it).

    Eq. (2)'s window shrinks while a frame has fewer than n_pmin PIRFs; at 1 every feature
    matched in the previous frame is a PIRF. And a true closure scores about
    SCORE_PER_PIRF_SQUARED x PIRFs^2. Frame 0 (no history) and the frames without any
    feature (:func:`blank_frames_note` names those) are left out of the medians."""
    seen = np.asarray(n_features)[1:] > 0
    n_features, n_pirfs, windows = (np.asarray(a)[1:][seen] for a in (n_features, n_pirfs, windows))
    if not len(n_pirfs):
        return None
    pirfs = float(np.median(n_pirfs))
    expected = SCORE_PER_PIRF_SQUARED * pirfs ** 2
    if expected >= tau / 2:  # at expected == tau about half the true closures reach tau
        return None
    height, width = shape
    collapsed = int((windows <= 1).sum())
    window = (f"; the adaptive window fell to 1 in {collapsed} of {len(windows)} frames (fewer PIRFs than pirf.n_pmin "
              f"{n_pmin})") if pirfs < n_pmin else ""
    return (f"{role}: frames of {width} x {height} give few features: median {np.median(n_features):.0f} {kind} features "
            f"and {pirfs:.0f} PIRFs a frame{window}. A true loop closure scores about {SCORE_PER_PIRF_SQUARED:.1e} x "
            f"PIRFs^2, here {expected:.2g}, far below pirf.tau {tau:g}: most true closures will not be accepted. Give "
            "frames with more detail (a typical true closure reaches table 1's tau 0.015 from ~95 PIRFs a frame; generated "
            "omnidirectional frames of 480 x 240 give ~85, from ~490 SIFT features), or set pirf.tau to about "
            f"{expected / 2:.2g} and check it against ground truth (docs/pirf.md, \"Your own video\")")

