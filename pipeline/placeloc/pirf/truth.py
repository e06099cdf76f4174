"""PIRF-nav2 ground truth: the positions of the frames a run actually used.

Poses come only from the config: the reference traverse's from ``ground_truth.path``
(``ground_truth.kind: poses``), the query's from ``pirf.query_poses``. They are read with
the one pose reader (:func:`placeloc.evaluation.poses.read_poses`) and aligned to frames
through the pose file's frame column: integer keys are positions in the image folder's
natural order (before any unreadable image was skipped), other keys are image file names.
A frame without a pose is an error naming the file; it is never filled in or guessed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from placeloc.evaluation.poses import PoseError, Poses, read_poses


def frame_xy(poses: Poses, names: Sequence[str], index: Sequence[int], n_listed: int) -> np.ndarray:
    """(n, 2) position of each kept frame: ``names[k]`` is its file, ``index[k]`` its position
    among the ``n_listed`` images of the folder."""
    if poses.frames is not None:
        if len(poses) < n_listed:
            raise PoseError(f"{poses.path}: {len(poses)} poses for {n_listed} frames; give one row per image "
                            f"(frame 0..{n_listed - 1}, or the image's file name) - poses are never guessed")
        rows = poses.rows_for_frames(n_listed)[np.asarray(index, np.int64)]
    else:
        rows = poses.rows_for_names(list(names))
    return poses.xy[rows]


def read_frame_xy(path: str | Path, names: Sequence[str], index: Sequence[int], n_listed: int, what: str) -> np.ndarray:
    """:func:`frame_xy` of the pose file at ``path`` (``what`` names it in errors)."""
    return frame_xy(read_poses(path, what=what), names, index, n_listed)
