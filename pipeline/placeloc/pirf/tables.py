"""The CSV files a PIRF-nav2 run writes beside its artifacts, readable without h5py.

- ``loop_closures.csv``: one row per loop closure found while mapping: the frame that
  closed the loop, the earlier node it matched, the score (eq. 9) and, with ground truth,
  the distance between the two (positions) and whether it is right (within the radius, or
  by the loop-closure matrix or CSV);
- ``localization.csv``: one row per query frame and index backend: the best node, its
  reference image, the score and, with ground truth, the estimated and true position.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Sequence

import numpy as np

from placeloc.core.artifacts import atomic_open


def _num(v: float) -> str:
    return "" if v is None or not np.isfinite(v) else f"{v:.6g}"


def write_loop_closures(path: Path, frames: np.ndarray, nodes: np.ndarray, scores: np.ndarray, names: Sequence[str],
                        r_xy: np.ndarray | None, radius: float, correct: np.ndarray | None = None) -> None:
    """``correct``: per closure, as judged (within ``radius`` with positions, or by a
    loop-closure matrix or CSV, which give no distance: that column stays empty)."""
    with atomic_open(path, newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["frame", "image", "node", "node_image", "score", "distance_m", "correct"])
        for k, (f, c, s) in enumerate(zip(frames, nodes, scores)):
            dist = float(np.linalg.norm(r_xy[f] - r_xy[c])) if r_xy is not None else float("nan")
            ok = "" if correct is None else int(correct[k])
            w.writerow([int(f), names[f], int(c), names[c], f"{s:.6g}", _num(dist), ok])


def write_localization(path: Path, results: dict[str, tuple[np.ndarray, np.ndarray]], q_names: Sequence[str],
                       r_names: Sequence[str], q_xy: np.ndarray | None, r_xy: np.ndarray | None, radius: float) -> None:
    """``results``: backend -> (best node per query frame (-1: none), score)."""
    with atomic_open(path, newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["backend", "frame", "image", "node", "reference_image", "score", "x_est", "y_est", "x_true", "y_true",
                    "error_m", "correct"])
        for backend, (best, score) in results.items():
            for t, (c, s) in enumerate(zip(best, score)):
                est = r_xy[c] if (r_xy is not None and c >= 0) else (np.nan, np.nan)
                true = q_xy[t] if q_xy is not None else (np.nan, np.nan)
                err = float(np.hypot(est[0] - true[0], est[1] - true[1]))
                ok = "" if q_xy is None or r_xy is None else int(c >= 0 and err <= radius)
                w.writerow([backend, t, q_names[t], int(c), r_names[c] if c >= 0 else "", f"{s:.6g}", _num(est[0]), _num(est[1]),
                            _num(true[0]), _num(true[1]), _num(err), ok])
