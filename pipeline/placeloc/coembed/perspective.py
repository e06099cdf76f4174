"""Co-embedding for perspective cameras: the paper's linear model on depth-scaled directions.

The paper's model says the map point is an affine function of the sighting for a given
step: x_i = T_t [y_{t,i}; 1]. A pinhole camera at C_t with rotation R_t gives instead
x_i = C_t + lambda_{t,i} R_t^T d_{t,i}, with d the normalised direction [u~, v~, 1] and
lambda the depth: affine in y = lambda d, but the depths are unknown. We alternate, as
projective factorisation does (Sturm and Triggs, "A Factorization Based Algorithm for
Multi-Image Projective Structure and Motion", ECCV 1996):

1. co-embed with y_{t,i} = lambda_{t,i} d_{t,i} (eq. (11) unchanged, K = 4);
2. per step, fit x ~ M_t y + c_t to the current map by least squares (weights q~), and set
   each depth to the one that puts M_t lambda d + c_t closest to x_i (clipped to stay
   positive); depths are rescaled by their median, which T_t absorbs.

It starts from lambda = 1, where it is the paper's model on normalised coordinates (the
constant third component is one more affine direction, dropped by the per-step whitening).
``alpha_for`` is called with the lifted observations of each round, so the landmark weight
can be re-chosen (by cross-validation) as the depths change.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from placeloc.coembed.observations import Observations
from placeloc.coembed.solver import CoembedResult, coembed_map


def perspective_coembed(obs: Observations, directions: np.ndarray, landmark_cols: np.ndarray, landmark_xyz: np.ndarray, *,
                        alpha_for: Callable[[Observations], float], iterations: int) -> tuple[CoembedResult, np.ndarray, list[float]]:
    """Returns the last round's result, the depths (nnz,) and the alpha of every round."""
    directions = np.asarray(directions, dtype=np.float64)
    rows, cols = obs.rows, obs.indices
    m = obs.n_steps
    w = 1.0 / np.bincount(cols, minlength=obs.n_features)[cols]
    lam = np.ones(obs.nnz)
    alphas: list[float] = []
    for it in range(iterations + 1):
        lifted = Observations(obs.indptr, obs.indices, directions * lam[:, None], obs.step_ids, obs.feature_ids)
        alphas.append(float(alpha_for(lifted)))
        res = coembed_map(lifted, landmark_cols, landmark_xyz, alpha=alphas[-1])
        if it == iterations:
            break
        x = res.X[cols]
        a = np.hstack([lifted.values, np.ones((obs.nnz, 1))])          # (nnz, 4)
        ata = np.zeros((m, 4, 4))
        atx = np.zeros((m, 4, x.shape[1]))
        np.add.at(ata, rows, w[:, None, None] * a[:, :, None] * a[:, None, :])
        np.add.at(atx, rows, w[:, None, None] * a[:, :, None] * x[:, None, :])
        fit = np.einsum("mab,mbd->mad", np.linalg.pinv(ata, hermitian=True), atx)   # (M, 4, d): [M_t^T; c_t^T]
        ray = np.einsum("na,nad->nd", directions, fit[rows, :3])
        off = x - fit[rows, 3]
        lam = np.maximum(np.sum(ray * off, axis=1) / np.maximum(np.sum(ray * ray, axis=1), 1e-300), 1e-3)
        lam /= np.median(lam)
    return res, lam, alphas
