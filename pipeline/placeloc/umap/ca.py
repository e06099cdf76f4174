"""Consistency Adjustment (sec. 4 of the paper): how far did the camera move between two
consecutive frames, from AKAZE matches, a majority vote and the laser distance to the wall?"""

from __future__ import annotations

import math

import cv2
import numpy as np

from placeloc.core.images import akaze_detector, read_gray


def akaze(gray: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Keypoint positions (N, 2) float32 and binary descriptors (N, 61) uint8."""
    kps, desc = akaze_detector(threshold).detectAndCompute(gray, None)
    pts = np.array([k.pt for k in kps], dtype=np.float32).reshape(-1, 2)
    if desc is None:
        desc = np.zeros((0, 61), dtype=np.uint8)
    return pts, desc


def match(desc_a: np.ndarray, desc_b: np.ndarray) -> np.ndarray:
    """Brute-force Hamming matching with cross check: (M, 2) index pairs (a, b)."""
    if len(desc_a) == 0 or len(desc_b) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    ms = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(desc_a, desc_b)
    return np.array([[m.queryIdx, m.trainIdx] for m in ms], dtype=np.int64).reshape(-1, 2)


def majority_vote(disp: np.ndarray, bin_px: float) -> np.ndarray:
    """Keep the largest group of matches that move the same way.

    ``disp`` (M, 2) displacement vectors. They are binned on a ``bin_px`` grid; the most
    populated bin's median vector is the consensus, and every match within ``bin_px`` of it
    (on both axes) is kept, so a group split by a bin border is not cut in half.
    Returns a boolean mask over the matches.
    """
    disp = np.asarray(disp, dtype=np.float64).reshape(-1, 2)
    if len(disp) == 0:
        return np.zeros(0, dtype=bool)
    cells = np.floor(disp / bin_px).astype(np.int64)
    uniq, inverse, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
    best = np.argmax(counts)
    centre = np.median(disp[inverse.ravel() == best], axis=0)
    return np.all(np.abs(disp - centre) <= bin_px, axis=1)


def effective_phi(hfov_deg: float) -> float:
    """The phi for eq. (2) under which it is exact pinhole geometry for a camera of horizontal
    field of view ``hfov_deg``: |n| tan(phi) / width = |n| / f  <=>  tan(phi) = 2 tan(hfov / 2).
    (Eq. (2) as printed with phi = the full field of view would overstate the angle.)"""
    return math.degrees(math.atan(2.0 * math.tan(math.radians(hfov_deg) / 2.0)))


def moved_distance_paper(n: float, d: float, theta_deg: float, phi_deg: float, width: int) -> float:
    """Eqs. (2)-(3) as printed:

        omega = 90 - arctan(|n| tan(phi) / width)
        m     = d tan(theta + 90 - omega) - d tan(theta)

    ``n`` the horizontal shift of the matched-feature centroid (pixels), ``d`` the laser
    distance to the wall, ``theta`` the camera angle to the wall normal, ``phi`` the angle
    of view, ``width`` the image width (pixels). Angles in degrees.
    """
    omega = 90.0 - math.degrees(math.atan(abs(n) * math.tan(math.radians(phi_deg)) / width))
    return d * math.tan(math.radians(theta_deg + 90.0 - omega)) - d * math.tan(math.radians(theta_deg))


def moved_distance_exact(u_a: float, u_b: float, d: float, theta_deg: float, focal: float, cx: float, wall_right: bool) -> float:
    """The same wall geometry without assuming the centroid starts at the image centre:
    a wall point seen at horizontal angle beta from the optical axis lies at
    d tan(theta -/+ beta) along the wall, so the camera moved by the difference of the two.
    ``wall_right``: the wall is on the image's right side (beta towards it lowers the angle)."""
    sgn = -1.0 if wall_right else 1.0
    ba = math.atan((u_a - cx) / focal)
    bb = math.atan((u_b - cx) / focal)
    th = math.radians(theta_deg)
    lim = math.radians(89.0)  # a point at the wall normal +-90 deg is at infinity
    a = min(max(th + sgn * ba, -lim), lim)
    b = min(max(th + sgn * bb, -lim), lim)
    return abs(d * math.tan(b) - d * math.tan(a))


def centroid_shift(pts_a: np.ndarray, desc_a: np.ndarray, pts_b: np.ndarray, desc_b: np.ndarray,
                   bin_px: float, min_matches: int) -> tuple[float, float, float, int] | None:
    """Match, vote, and return (n_N, centroid u in a, centroid u in b, kept matches), or None
    when fewer than ``min_matches`` survive the vote."""
    m = match(desc_a, desc_b)
    if len(m) < min_matches:
        return None
    pa, pb = pts_a[m[:, 0]], pts_b[m[:, 1]]
    keep = majority_vote(pb - pa, bin_px)
    if keep.sum() < min_matches:
        return None
    ua = float(pa[keep, 0].mean())
    ub = float(pb[keep, 0].mean())
    return ub - ua, ua, ub, int(keep.sum())


def wall_tangent(heading_deg: float, theta_deg: float, wall_right: bool) -> np.ndarray:
    """Unit plan vector along the wall that :func:`wall_steps` measures displacement on.

    The laser (wall normal) points at heading - theta (wall on the right) or heading + theta
    (left); the tangent is that normal turned +90 deg (counter-clockwise)."""
    n = math.radians(heading_deg - theta_deg if wall_right else heading_deg + theta_deg)
    return np.array([-math.sin(n), math.cos(n)])


def wall_steps(pa: np.ndarray, pb: np.ndarray, d: float, theta_deg: float, focal: float, cx: float,
               wall_right: bool) -> np.ndarray:
    """Signed camera displacement along :func:`wall_tangent` implied by each match (pa -> pb,
    (M, 2) pixels): a wall point at angle alpha from the wall normal lies at d tan(alpha) along
    the wall, so the camera moved by d (tan alpha_a - tan alpha_b). Matches on the wall agree;
    matches on the floor, furniture or far walls scatter, which the vote then discards."""
    lim = math.radians(89.0)  # a point at the wall normal +-90 deg is at infinity
    th = math.radians(theta_deg)
    sgn = -1.0 if wall_right else 1.0
    aa = np.clip(th + sgn * np.arctan((np.asarray(pa)[:, 0] - cx) / focal), -lim, lim)
    ab = np.clip(th + sgn * np.arctan((np.asarray(pb)[:, 0] - cx) / focal), -lim, lim)
    # the left-wall angles run clockwise, so their tangent coordinate flips sign
    return (d * (np.tan(aa) - np.tan(ab))) * (1.0 if wall_right else -1.0)


def metric_vote(steps: np.ndarray, tol_m: float, rel_tol: float) -> np.ndarray:
    """Majority vote in metres rather than pixels: the largest group of per-match steps lying
    within +-(tol_m + rel_tol |step|) of each other. Pixel displacements of an oblique wall
    differ across the image (depth varies), metric steps of wall points do not."""
    s = np.asarray(steps, dtype=np.float64).ravel()
    if len(s) == 0:
        return np.zeros(0, dtype=bool)
    o = np.sort(s)
    width = 2.0 * (tol_m + rel_tol * np.abs(o))
    counts = np.searchsorted(o, o + width, side="right") - np.arange(len(o))
    i = int(np.argmax(counts))
    return (s >= o[i]) & (s <= o[i] + width[i])


def signed_step(pts_a: np.ndarray, desc_a: np.ndarray, pts_b: np.ndarray, desc_b: np.ndarray, d: float, theta_deg: float,
                focal: float, cx: float, wall_right: bool, tol_m: float, rel_tol: float) -> tuple[float, int, int, float]:
    """CA step between two frames: (median signed step along the wall of the winning group,
    its size, the size of the runner-up group among the other matches, the runner-up's median
    step). (nan, 0, 0, nan) when nothing matched. A winner barely larger than the runner-up is a coin toss (often floor
    texture or a far wall against the near wall), which the tracker treats as unreliable."""
    m = match(desc_a, desc_b)
    if len(m) == 0:
        return math.nan, 0, 0, math.nan
    steps = wall_steps(pts_a[m[:, 0]], pts_b[m[:, 1]], d, theta_deg, focal, cx, wall_right)
    keep = metric_vote(steps, tol_m, rel_tol)
    rest = steps[~keep]
    keep2 = metric_vote(rest, tol_m, rel_tol)
    alt = float(np.median(rest[keep2])) if keep2.any() else math.nan
    return float(np.median(steps[keep])), int(keep.sum()), int(keep2.sum()), alt


def is_reliable(kept: int, second: int, *, reliable_matches: int, reliable_ratio: float) -> bool:
    """Enough matches in the vote's winning group, and clearly more than in the runner-up."""
    return kept >= reliable_matches and kept >= reliable_ratio * second


def calibrate(images: list[str], truth_xy: np.ndarray, heading_deg: float, d: np.ndarray, theta_deg: np.ndarray,
              hfov_deg: float, *, akaze_threshold: float, wall_right: bool, vote_tol_m: float, vote_rel_tol: float,
              reliable_matches: int, reliable_ratio: float) -> dict[str, float]:
    """CA error statistics from a calibration sequence with ground truth (never the test one).

    ``images`` the frames in order, ``truth_xy`` (N, 2) their true positions, ``d`` and
    ``theta_deg`` the sensor rows; the keyword arguments are the ``umap.ca`` parameters of the
    same names. Returns error_mean_m and error_std_m of the reliable CA steps (measured - true,
    along the wall; median and 1.4826 x median absolute deviation, so the few confidently wrong
    votes, which re-localization has to catch anyway, do not inflate every gate) and
    fallback_step_m, the median true step length of the frames whose CA vote was unreliable."""
    feats = []
    width = focal = 0.0
    for path in images:
        gray = read_gray(path)  # upright (EXIF orientation), as the stages read frames
        width = gray.shape[1]
        focal = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        feats.append(akaze(gray, akaze_threshold))
    errs, failed = [], []
    for k in range(1, len(images)):
        true = float((truth_xy[k] - truth_xy[k - 1]) @ wall_tangent(heading_deg, theta_deg[k - 1], wall_right))
        st, kept, second, _ = signed_step(*feats[k - 1], *feats[k], d[k - 1], theta_deg[k - 1], focal, (width - 1) / 2.0,
                                          wall_right, vote_tol_m, vote_rel_tol)
        if is_reliable(kept, second, reliable_matches=reliable_matches, reliable_ratio=reliable_ratio):
            errs.append(st - true)
        else:
            failed.append(abs(true))
    e = np.asarray(errs)
    med = float(np.median(e)) if len(e) else 0.0
    mad = 1.4826 * float(np.median(np.abs(e - med))) if len(e) else 0.0
    return {"error_mean_m": med, "error_std_m": mad,
            "fallback_step_m": float(np.median(failed)) if failed else None, "n_reliable": len(errs), "n_failed": len(failed)}
