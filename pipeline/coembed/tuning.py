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
from placeloc.coembed.solver import CoembedError, coembed_operator, solve_landmarks


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
    scores = {}
    for alpha in candidates:
        err = []
        for j in range(len(landmark_cols)):
            keep = np.arange(len(landmark_cols)) != j
            try:
                _, x = solve_landmarks(g, landmark_cols[keep], xstar[keep], alpha=alpha)
                err.append(np.sum((x[landmark_cols[j]] - xstar[j]) ** 2))
            except CoembedError:
                err.append(np.inf)
        scores[float(alpha)] = float(np.sqrt(np.mean(err)))
    return Choice(_pick(scores), scores)


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
