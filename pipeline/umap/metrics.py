"""Localization error summaries."""

from __future__ import annotations

from typing import Any

import numpy as np


def error_metrics(err: np.ndarray) -> dict[str, Any]:
    """Max, mean, median plan error (metres) and the share of frames within 0.5 m and 1 m."""
    err = np.asarray(err, float)
    return {"max_error_m": float(err.max()), "mean_error_m": float(err.mean()), "median_error_m": float(np.median(err)),
            "within_0_5m": float(np.mean(err <= 0.5)), "within_1m": float(np.mean(err <= 1.0)), "n_frames": int(len(err))}
