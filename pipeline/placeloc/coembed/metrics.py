"""Map and path errors of a co-embedding (or baseline) result against known truth; plain arrays in and out."""

from __future__ import annotations

import numpy as np


def _rmse(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(err ** 2)))


def map_errors(feature_ids: np.ndarray, coords: np.ndarray, is_landmark: np.ndarray, truth_ids: np.ndarray,
               truth_xyz: np.ndarray) -> tuple[dict, np.ndarray, np.ndarray]:
    """Errors over the non-landmark features that have a true position.

    Returns (metrics, estimates, truths) with the evaluated rows in map order. Features with a
    true position that were never observed cannot be mapped: they are counted, not hidden.
    """
    d = coords.shape[1]
    have = np.isin(feature_ids, truth_ids) & ~is_landmark
    order = {int(f): j for j, f in enumerate(truth_ids)}
    rows = np.array([order[int(f)] for f in feature_ids[have]], dtype=np.int64)
    est, truth = coords[have], truth_xyz[rows, :d]
    err = np.linalg.norm(est - truth, axis=1)
    out: dict = {"map_rmse": _rmse(err) if len(err) else None, "map_max_error": float(err.max()) if len(err) else None,
                 "map_median_error": float(np.median(err)) if len(err) else None, "n_evaluated": int(len(err)),
                 "n_truth_unobserved": int((~np.isin(truth_ids, feature_ids)).sum())}
    lm_rows = np.array([order[int(f)] for f in feature_ids[is_landmark] if int(f) in order], dtype=np.int64)
    if len(lm_rows) == int(is_landmark.sum()):
        out["landmark_rmse"] = _rmse(np.linalg.norm(coords[is_landmark] - truth_xyz[lm_rows, :d], axis=1))
    return out, est, truth


def path_errors(step_ids: np.ndarray, xy: np.ndarray, heading: np.ndarray | None, label_steps: np.ndarray,
                truth_steps: np.ndarray, truth_xy: np.ndarray, truth_heading: np.ndarray | None) -> tuple[dict, np.ndarray | None]:
    """Errors over the unlabelled steps that have a true pose (``truth_steps`` sorted and unique).

    Returns (metrics, the true path at every estimated step that has one, or None).
    """
    labelled = np.isin(step_ids, label_steps)
    common = np.isin(step_ids, truth_steps) & ~labelled
    if not common.any():
        return {}, None
    idx = np.searchsorted(truth_steps, step_ids[common])
    perr = np.linalg.norm(xy[common] - truth_xy[idx], axis=1)
    out: dict = {"path_rmse": _rmse(perr), "path_max_error": float(perr.max()), "n_path_evaluated": int(common.sum()),
                 "n_pose_labels": int(labelled.sum())}
    if truth_heading is not None and heading is not None:
        dh = (heading[common] - truth_heading[idx] + np.pi) % (2 * np.pi) - np.pi
        out["heading_rmse_deg"] = float(np.degrees(_rmse(dh)))
    return out, truth_xy[np.searchsorted(truth_steps, step_ids[np.isin(step_ids, truth_steps)])]
