"""Map and path errors of a co-embedding (or baseline) result against known truth; plain arrays in and out."""

from __future__ import annotations

import numpy as np

from placeloc.evaluation.maps import map_errors  # noqa: F401  (re-exported)


def _rmse(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(err ** 2)))


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
