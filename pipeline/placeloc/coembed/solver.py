"""The co-embedding mapper: closed form (11) for the map, (16) for the path.

Notation of the paper (Nakamura and Yairi, "Experimental Study on Mapping by Dimensionality
Reduction"): z_{t,i} = [y_{t,i}; 1] (K = k + 1 entries), the map point
seen at step t is T_t z_{t,i} (d entries), T = [T_1, ..., T_M]^T is (M K) x d.

Choices recorded here (the paper is ambiguous):

* Weights. Eq. (7) defines D_t = sum_i q~_{t,i} z z^T and V with the per-feature
  normalised weights q~_{t,i} = q_{t,i} / sum_t q_{t,i} of eq. (9). With those, (7) is
  exactly sum_i (weighted variance over t of x^_{t,i}), i.e. eq. (6) with q~ in place of
  the binary mask. We implement (7) as written (normalised weights in both terms), so every
  feature counts once however often it is seen.
* Solving (11) without forming the (M K) x (M K) matrix. A = D + V^T C V with
  C = alpha J_x - I. By the push-through identity A^-1 V^T = D^-1 V^T (I + C G)^-1 with
  G = V D^-1 V^T (N x N), so T^ = D^-1 V^T S and X^ = V T^ = G S where
  (I + C G) S = alpha J_x X*. D is block diagonal (M blocks K x K), so G is one sparse
  product, and the only dense solve is N x N. G = P H P^T with H a projection and P P^T = I,
  so I - G is positive semi-definite (a Laplacian-like matrix whose null space is the set of
  perfectly consistent maps) and the landmark term alpha J_x G removes that null space.
  A step with fewer than K independent observations has a singular D_t; we use its
  pseudo-inverse (T_t is then the minimum-norm solution), which keeps G a projection.
* Path (12)-(16). The paper's w^p_{s,t} = 1 when the control input between s and t is
  about zero; a model-free observer does not know its inputs, so we link every pair of
  consecutive steps (a chain Laplacian, i.e. a smoothness prior). vec(T_t) is augmented with
  a constant 1 (``bias``), so the pose is an affine rather than linear function of T_t; the
  origin of T_t's translation column is arbitrary otherwise. Heading uses the same solve
  with targets [cos th, sin th] and atan2 of the result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from placeloc.coembed.observations import Observations


class CoembedError(ValueError):
    """The problem is under-determined (too few landmarks, disconnected observations)."""


@dataclass
class CoembedResult:
    X: np.ndarray        # (N, d) feature map
    T: np.ndarray        # (M, d, K) per-step transforms, x = T_t z
    per_step: np.ndarray  # (nnz, d) x^_{t,i} for every observation


def _blocks(obs: Observations, weights: np.ndarray, z: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """D_t = sum_i w z z^T as (M, K, K), by one bincount per entry (vectorised over steps)."""
    m, kk = obs.n_steps, z.shape[1]
    out = np.empty((m, kk, kk))
    for a in range(kk):
        for b in range(a, kk):
            out[:, a, b] = out[:, b, a] = np.bincount(rows, weights=weights * z[:, a] * z[:, b], minlength=m)
    return out


def check_landmarks(obs: Observations, landmark_cols: np.ndarray, dim: int) -> None:
    """Every group of features observed together needs dim + 1 landmarks to fix its frame."""
    landmark_cols = np.asarray(landmark_cols)
    if len(np.unique(landmark_cols)) < dim + 1:
        raise CoembedError(f"a {dim}-D map needs at least {dim + 1} landmarks (to fix rotation, scale and offset); "
                           f"got {len(np.unique(landmark_cols))}")
    m, n = obs.n_steps, obs.n_features
    rows = obs.rows
    # Bipartite graph steps <-> features: a component is a set of features tied together by co-observation.
    g = sp.coo_matrix((np.ones(obs.nnz), (rows, m + obs.indices)), shape=(m + n, m + n))
    n_comp, labels = connected_components(g, directed=False)
    if n_comp > 1:
        feat_labels = labels[m:]
        per = np.bincount(feat_labels[landmark_cols], minlength=n_comp)
        sizes = np.bincount(feat_labels, minlength=n_comp)
        weak = [(int(sizes[c]), int(per[c])) for c in np.unique(feat_labels) if per[c] < dim + 1]
        if weak:
            raise CoembedError(f"the observations split into {n_comp} groups never seen together; groups of "
                               f"(features, landmarks) {weak[:5]} have fewer than {dim + 1} landmarks; add landmarks or observations linking them")


def coembed_map(obs: Observations, landmark_cols: np.ndarray, landmark_xyz: np.ndarray, *, alpha: float) -> CoembedResult:
    """Eq. (11): the map X^ (N x d) and the transforms T^_t from observations and landmarks."""
    landmark_cols = np.asarray(landmark_cols, dtype=np.int64)
    xstar = np.asarray(landmark_xyz, dtype=np.float64)
    if xstar.ndim != 2 or len(xstar) != len(landmark_cols):
        raise CoembedError("landmark coordinates must be (n_landmarks, d) matching the landmark ids")
    if alpha <= 0:
        raise CoembedError(f"alpha must be > 0 (it weighs the landmark term), got {alpha}")
    d = xstar.shape[1]
    check_landmarks(obs, landmark_cols, d)
    op = coembed_operator(obs)
    s, x = solve_landmarks(op.g, landmark_cols, xstar, alpha=alpha)
    # T^ = D^-1 V^T S, block by block: T_t^T = D_t^-1 sum_i q~ z_{t,i} s_i^T.
    rows, cols, z, qn = obs.rows, obs.indices, op.z, op.weights
    vts = np.zeros((obs.n_steps, z.shape[1], xstar.shape[1]))
    np.add.at(vts, rows, (qn[:, None] * z)[:, :, None] * s[cols][:, None, :])
    tt = np.einsum("mab,mbd->mad", op.dinv, vts)        # (M, K, d) = T_t^T in whitened coordinates
    per_step = np.einsum("nk,nkd->nd", z, tt[rows])
    # Report T_t for the globally standardised observations (z_glob = [(y - mu) / s; 1]): the pose
    # read-out (16) is affine in vec(T_t), and this frame makes it independent of the image origin and units.
    t_mat = np.einsum("mda,mak->mdk", np.transpose(tt, (0, 2, 1)), op.to_global)
    return CoembedResult(X=x, T=t_mat, per_step=per_step)


@dataclass
class CoembedOperator:
    """What eq. (11) needs from the observations alone (independent of the landmarks and alpha)."""

    g: np.ndarray           # (N, N) G = V D^+ V^T
    z: np.ndarray           # (nnz, K) whitened z'_{t,i}
    dinv: np.ndarray        # (M, K, K) D_t^+
    weights: np.ndarray     # (nnz,) q~
    to_global: np.ndarray   # (M, K, K) z'_t = B_t z_glob


def coembed_operator(obs: Observations) -> CoembedOperator:
    """G = V D^+ V^T for the whitened observations (one sparse product)."""
    m, n = obs.n_steps, obs.n_features
    rows, cols = obs.rows, obs.indices
    qn = 1.0 / np.bincount(cols, minlength=n)[cols]  # q~: each feature's weights sum to 1
    z, dinv, to_global = whiten_steps(obs.values, rows, qn, m)
    kk = z.shape[1]
    vcols = (rows[:, None] * kk + np.arange(kk)).ravel()
    vrows = np.repeat(cols, kk)
    vmat = sp.csr_matrix(((qn[:, None] * z).ravel(), (vrows, vcols)), shape=(n, m * kk))
    wvals = qn[:, None] * np.einsum("na,nab->nb", z, dinv[rows])   # rows of V D^-1
    wmat = sp.csr_matrix((wvals.ravel(), (vrows, vcols)), shape=(n, m * kk))
    return CoembedOperator(g=(wmat @ vmat.T).toarray(), z=z, dinv=dinv, weights=qn, to_global=to_global)


def solve_landmarks(g: np.ndarray, landmark_cols: np.ndarray, landmark_xyz: np.ndarray, *, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """(I + C G) S = alpha J_x X*, C = alpha J_x - I; returns S and the map X = G S."""
    n, d = len(g), landmark_xyz.shape[1]
    cdiag = -np.ones(n)
    cdiag[landmark_cols] = alpha - 1.0
    y = np.zeros((n, d))
    y[landmark_cols] = alpha * landmark_xyz
    system = np.eye(n) + cdiag[:, None] * g
    try:
        s = np.linalg.solve(system, y)
    except np.linalg.LinAlgError as exc:
        raise CoembedError("the co-embedding system is singular: the landmarks do not fix the map "
                           "(too few, or all on a line); add landmarks spread over the map") from exc
    return s, g @ s


def whiten_steps(values: np.ndarray, rows: np.ndarray, weights: np.ndarray, m: int,
                 rel_tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-step centred and whitened observations z'_{t,i} = [A_t (y_{t,i} - mu_t); 1], D_t^+ and the map to global coordinates.

    The cost (7) is unchanged when step t's observations are replaced by any invertible affine
    function of them (T_t absorbs it), so this is exact, not an approximation. It makes
    D_t = W_t diag(1, ..., 1) (W_t = the step's total weight) with a zero for every direction the
    step does not span: the rank is decided on the step's own covariance relative to its largest
    eigenvalue (and that relative to the typical step), which does not change when the image
    coordinates are shifted or scaled. Returns z' (nnz x K), D^+ (M x K x K) and, per step, the
    K x K matrix B_t with z'_t = B_t z_glob, z_glob = [(y - mu) / s; 1] with the global weighted
    mean mu and scale s.
    """
    k = values.shape[1]
    wsum = np.bincount(rows, weights=weights, minlength=m)
    mu = np.column_stack([np.bincount(rows, weights=weights * values[:, a], minlength=m) for a in range(k)])
    mu /= np.maximum(wsum, 1e-300)[:, None]
    dev = values - mu[rows]
    cov = np.empty((m, k, k))
    for a in range(k):
        for b in range(a, k):
            cov[:, a, b] = cov[:, b, a] = np.bincount(rows, weights=weights * dev[:, a] * dev[:, b], minlength=m)
    cov /= np.maximum(wsum, 1e-300)[:, None, None]
    lam, vec = np.linalg.eigh(cov)                       # ascending eigenvalues per step
    top = lam[:, -1]
    typical = np.median(top[top > 0]) if np.any(top > 0) else 1.0
    keep = (lam > rel_tol * top[:, None]) & (top[:, None] > rel_tol * typical)
    inv_sd = np.where(keep, 1.0 / np.sqrt(np.where(keep, lam, 1.0)), 0.0)
    a_mat = inv_sd[:, :, None] * np.transpose(vec, (0, 2, 1))   # A_t = Lambda^-1/2 U^T, zero rows dropped
    z = np.hstack([np.einsum("nab,nb->na", a_mat[rows], dev), np.ones((len(rows), 1))])
    dinv = np.zeros((m, k + 1, k + 1))
    safe = np.where(wsum > 0, 1.0 / np.maximum(wsum, 1e-300), 0.0)
    dinv[:, np.arange(k), np.arange(k)] = np.where(keep, safe[:, None], 0.0)
    dinv[:, k, k] = safe
    # Global standardisation: y = s y_glob + g; then y - mu_t = s y_glob - (mu_t - g).
    g = np.average(values, axis=0, weights=weights)
    s = float(np.sqrt(np.average(np.sum((values - g) ** 2, axis=1), weights=weights))) or 1.0
    to_global = np.zeros((m, k + 1, k + 1))
    to_global[:, :k, :k] = s * a_mat
    to_global[:, :k, k] = -np.einsum("mab,mb->ma", a_mat, mu - g)
    to_global[:, k, k] = 1.0
    return z, dinv, to_global


def coembed_map_dense(obs: Observations, landmark_cols: np.ndarray, landmark_xyz: np.ndarray, *, alpha: float) -> np.ndarray:
    """Eq. (11) literally, forming and solving the (M K) x (M K) system; for checks and the benchmark only."""
    landmark_cols = np.asarray(landmark_cols, dtype=np.int64)
    xstar = np.asarray(landmark_xyz, dtype=np.float64)
    m, n = obs.n_steps, obs.n_features
    rows, cols = obs.rows, obs.indices
    z = np.hstack([obs.values, np.ones((obs.nnz, 1))])
    kk = z.shape[1]
    qn = 1.0 / np.bincount(cols, minlength=n)[cols]
    vcols = (rows[:, None] * kk + np.arange(kk)).ravel()
    vmat = sp.csr_matrix(((qn[:, None] * z).ravel(), (np.repeat(cols, kk), vcols)), shape=(n, m * kk)).toarray()
    dmat = np.zeros((m * kk, m * kk))
    blocks = _blocks(obs, qn, z, rows)
    for a in range(kk):
        for b in range(kk):
            dmat[np.arange(m) * kk + a, np.arange(m) * kk + b] = blocks[:, a, b]
    jx = np.zeros(n)
    jx[landmark_cols] = 1.0
    xs = np.zeros((n, xstar.shape[1]))
    xs[landmark_cols] = xstar
    a_mat = dmat + vmat.T @ ((alpha * jx - 1.0)[:, None] * vmat)
    rhs = alpha * vmat.T @ (jx[:, None] * xs)
    try:
        t_hat = np.linalg.solve(a_mat, rhs)
    except np.linalg.LinAlgError:
        t_hat = np.linalg.lstsq(a_mat, rhs, rcond=None)[0]   # a step with too few sightings: min-norm T_t
    return vmat @ t_hat


def chain_laplacian(m: int) -> sp.csr_matrix:
    """L_p = D_p - W_p with w = 1 between consecutive steps."""
    if m < 2:
        return sp.csr_matrix((m, m))
    w = sp.diags([np.ones(m - 1), np.ones(m - 1)], [-1, 1], shape=(m, m))
    return (sp.diags(np.asarray(w.sum(axis=1)).ravel()) - w).tocsr()


def estimate_path(t_mat: np.ndarray, label_rows: np.ndarray, label_targets: np.ndarray, *, beta: float,
                  bias: bool = True) -> np.ndarray:
    """Eq. (16): H^T = (T+^T (J_r + beta L_p) T+)^-1 T+^T J_r P*, then P^ = T+ H^T for every step.

    ``label_targets`` are the known values (positions, or [cos th, sin th]) at ``label_rows``.
    """
    m = t_mat.shape[0]
    feats = t_mat.reshape(m, -1)
    if bias:
        feats = np.hstack([feats, np.ones((m, 1))])
    label_rows = np.asarray(label_rows, dtype=np.int64)
    targets = np.asarray(label_targets, dtype=np.float64)
    if len(label_rows) == 0:
        raise CoembedError("the path needs known poses (labels); give coembed.poses and coembed.pose_label_every")
    if beta < 0:
        raise CoembedError(f"beta must be >= 0, got {beta}")
    jr = np.zeros(m)
    jr[label_rows] = 1.0
    pstar = np.zeros((m, targets.shape[1]))
    pstar[label_rows] = targets
    lhs = feats.T @ (jr[:, None] * feats) + beta * (feats.T @ (chain_laplacian(m) @ feats))
    rhs = feats.T @ (jr[:, None] * pstar)
    # lstsq rather than solve: with few labels the normal matrix can be singular; min-norm H then.
    h_t = np.linalg.lstsq(lhs, rhs, rcond=1e-12)[0]
    return feats @ h_t


def estimate_poses(t_mat: np.ndarray, label_rows: np.ndarray, label_xy: np.ndarray, label_heading: np.ndarray | None, *,
                   beta: float) -> tuple[np.ndarray, np.ndarray | None]:
    """Positions (M x 2) and, when headings are labelled, headings (M,) in radians."""
    xy = estimate_path(t_mat, label_rows, label_xy, beta=beta)
    heading = None
    if label_heading is not None:
        cs = estimate_path(t_mat, label_rows, np.column_stack([np.cos(label_heading), np.sin(label_heading)]), beta=beta)
        heading = np.arctan2(cs[:, 1], cs[:, 0])
    return xy, heading
