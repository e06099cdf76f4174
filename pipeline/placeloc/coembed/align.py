"""Least-squares alignment of an unsupervised embedding to the landmarks.

The paper aligns Isomap and PCAMD "by the least-squares optimal linear transformation on
the labelled features"; we read that as an affine map (a linear map plus a translation),
because an embedding's origin is arbitrary.
"""

from __future__ import annotations

import numpy as np


class AlignmentError(ValueError):
    """Too few or degenerate correspondences to fit the transformation."""


def fit_affine(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """A ((p+1) x d) minimising ||[src 1] A - dst||_F; src (n x p), dst (n x d).

    Needs n >= p + 1 points that are not all on one hyperplane (full column rank).
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.ndim != 2 or dst.ndim != 2 or len(src) != len(dst):
        raise AlignmentError(f"src {src.shape} and dst {dst.shape} must be (n, p) and (n, d) with the same n")
    n, p = src.shape
    if n < p + 1:
        raise AlignmentError(f"an affine map from {p}-D needs at least {p + 1} landmarks, got {n}; give more landmarks")
    a = np.hstack([src, np.ones((n, 1))])
    # Column scaling keeps the rank test meaningful whatever the embedding's units.
    scale = np.linalg.norm(a, axis=0)
    scale[scale == 0] = 1.0
    coef, _, rank, sv = np.linalg.lstsq(a / scale, dst, rcond=None)
    if rank < p + 1:
        raise AlignmentError(f"the {n} landmarks are degenerate in the embedding (rank {rank} < {p + 1}): "
                             "they lie on a line/plane there; give landmarks spread over the map")
    return coef / scale[:, None]


def apply_affine(points: np.ndarray, coef: np.ndarray) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    return points @ coef[:-1] + coef[-1]


def align_to_landmarks(embedding: np.ndarray, landmark_cols: np.ndarray, landmark_xyz: np.ndarray) -> np.ndarray:
    """Map every row of ``embedding`` into the landmark frame by the affine LS fit on the landmark rows."""
    coef = fit_affine(embedding[landmark_cols], landmark_xyz)
    return apply_affine(embedding, coef)
