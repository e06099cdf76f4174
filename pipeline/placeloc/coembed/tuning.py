"""Choosing the free settings from the landmarks alone: leave-one-landmark-out cross-validation.

For each candidate setting, every landmark in turn is hidden, the map is solved from the
others, and the hidden landmark's placement error is recorded; the setting with the
smallest RMS error wins (ties: the first candidate). Only the known landmark positions
are used, never the truth of the unknown points, so the choice is one a user could make.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from placeloc.coembed.align import AlignmentError, align_to_landmarks
from placeloc.coembed.isomap import IsomapError, isomap_features
from placeloc.coembed.observations import Observations
from placeloc.coembed.solver import CoembedError, coembed_operator


@dataclass
class Choice:
    value: float
    scores: dict[float, float]   # candidate -> leave-one-out RMS error (inf where the solve failed)


def _pick(scores: dict[float, float]) -> float:
    best = min(scores.values())
    if not np.isfinite(best):
        raise CoembedError("leave-one-landmark-out cross-validation failed for every candidate: too few landmarks "
                           "(it needs at least dim + 2)")
    return next(k for k, v in scores.items() if v == best)


def loo_alpha(obs: Observations, landmark_cols: np.ndarray, landmark_xyz: np.ndarray, *, candidates: tuple[float, ...]) -> Choice:
    """The landmark weight alpha of eq. (11) with the smallest leave-one-landmark-out error."""
    landmark_cols = np.asarray(landmark_cols, dtype=np.int64)
    xstar = np.asarray(landmark_xyz, dtype=np.float64)
    g = coembed_operator(obs).g                    # independent of alpha and of the landmarks: built once
    scores = {float(alpha): _loo_error(g, landmark_cols, xstar, float(alpha)) for alpha in candidates}
    return Choice(_pick(scores), scores)


def _loo_error(g: np.ndarray, landmark_cols: np.ndarray, xstar: np.ndarray, alpha: float) -> float:
    """RMS error of each hidden landmark, all of them from one inverse of the full system.

    Hiding landmark j changes row j of (I + C G) by -alpha g_j (a rank-one update) and zeroes row j
    of the right-hand side, so Sherman-Morrison gives every hold-out solve from A^-1 in O(N^2).
    """
    n = len(g)
    cdiag = -np.ones(n)
    cdiag[landmark_cols] = alpha - 1.0
    y = np.zeros((n, xstar.shape[1]))
    y[landmark_cols] = alpha * xstar
    try:
        ainv = np.linalg.inv(np.eye(n) + cdiag[:, None] * g)
    except np.linalg.LinAlgError:
        return float("inf")
    ay = ainv @ y
    err = []
    for j, col in enumerate(landmark_cols):
        a_e = ainv[:, col]
        b = ay - np.outer(a_e, y[col])          # A^-1 (y with row j zeroed)
        u = -alpha * a_e                        # A^-1 (-alpha e_j)
        denom = 1.0 + g[col] @ u
        if abs(denom) < 1e-12:
            err.append(np.inf)                  # the map is not fixed without this landmark
            continue
        s_j = b - np.outer(u, g[col] @ b) / denom
        err.append(float(np.sum((g[col] @ s_j - xstar[j]) ** 2)))
    return float(np.sqrt(np.mean(err)))


def loo_affine_error(embedding: np.ndarray, landmark_cols: np.ndarray, landmark_xyz: np.ndarray) -> float:
    """RMS error of each landmark when the affine alignment is fitted on the others."""
    err = []
    for j in range(len(landmark_cols)):
        keep = np.arange(len(landmark_cols)) != j
        try:
            x = align_to_landmarks(embedding, landmark_cols[keep], landmark_xyz[keep])
            err.append(np.sum((x[landmark_cols[j]] - landmark_xyz[j]) ** 2))
        except AlignmentError:
            err.append(np.inf)
    return float(np.sqrt(np.mean(err)))


def loo_isomap_neighbors(obs: Observations, landmark_cols: np.ndarray, landmark_xyz: np.ndarray, *, dim: int, min_common: int,
                         candidates: tuple[int, ...]) -> Choice:
    """Isomap's neighbour count with the smallest leave-one-landmark-out alignment error."""
    landmark_cols = np.asarray(landmark_cols, dtype=np.int64)
    xstar = np.asarray(landmark_xyz, dtype=np.float64)
    scores = {}
    for k in candidates:
        if k >= obs.n_features:
            continue
        try:
            emb = isomap_features(obs, n_neighbors=int(k), dim=dim, min_common=min_common)
            scores[int(k)] = loo_affine_error(emb, landmark_cols, xstar)
        except IsomapError:
            scores[int(k)] = float("inf")
    return Choice(_pick(scores), scores)
