"""Localization error summaries."""

from __future__ import annotations

from typing import Any

import numpy as np


def error_metrics(err: np.ndarray) -> dict[str, Any]:
    """Max, mean, median plan error (metres) and the share of frames within 0.5 m and 1 m."""
    err = np.asarray(err, float)
    return {"max_error_m": float(err.max()), "mean_error_m": float(err.mean()), "median_error_m": float(np.median(err)),
            "within_0_5m": float(np.mean(err <= 0.5)), "within_1m": float(np.mean(err <= 1.0)), "n_frames": int(len(err))}


def yaw_errors(est_deg: np.ndarray, truth_deg: np.ndarray) -> np.ndarray:
    """Absolute heading differences in degrees, wrapped into [0, 180]."""
    return np.abs((np.asarray(est_deg, float) - np.asarray(truth_deg, float) + 180.0) % 360.0 - 180.0)


def recall_metrics(err_m: np.ndarray, yaw_err_deg: np.ndarray | None) -> dict[str, Any]:
    """Share of frames within 2 m, and when headings are known the median yaw error, the
    share within 10 and 30 degrees, and within 0.5 m / 1 m / 2 m *and* 30 degrees."""
    err_m = np.asarray(err_m, float)
    out: dict[str, Any] = {"within_2m": float(np.mean(err_m <= 2.0))}
    if yaw_err_deg is not None:
        y = np.asarray(yaw_err_deg, float)
        out.update({"median_yaw_error_deg": float(np.median(y)), "yaw_within_10deg": float(np.mean(y <= 10.0)),
                    "yaw_within_30deg": float(np.mean(y <= 30.0)),
                    "within_0_5m_30deg": float(np.mean((err_m <= 0.5) & (y <= 30.0))),
                    "within_1m_30deg": float(np.mean((err_m <= 1.0) & (y <= 30.0))),
                    "within_2m_30deg": float(np.mean((err_m <= 2.0) & (y <= 30.0)))})
    return out
