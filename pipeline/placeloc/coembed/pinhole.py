"""Co-embedding for a calibrated pinhole camera: the paper's cost with T_t restricted to a camera pose.

The paper's model maps each sighting to the map by a free affine T_t per step. A calibrated
pinhole camera (known intrinsics, undistorted normalised direction d = [u~, v~, 1]) gives
x_i = C_t + mu_{t,i} Q_t d^_{t,i} with d^ = d / |d|, Q_t = R_t^T the camera-to-map rotation,
C_t the camera centre and mu the distance along the ray: T_t = [Q_t | C_t] applied to
[mu d^; 1], the paper's form with the linear part held to a rotation and one depth per
sighting. Put into eq. (7) (weights q~, each feature counts once; the per-feature mean as a
free point x_i, whose minimiser is that mean, so this is (7) exactly) with the landmark term
(8) at alpha -> infinity (landmarks held at x*; leave-one-out picks the top of the grid on
every simulated run anyway):

    Phi = sum_{t,i} w_{t,i} |C_t + mu_{t,i} Q_t d^_{t,i} - x_i|^2,   x_i = x*_i for landmarks.

Minimising over mu leaves the distance of x_i from the ray r = Q_t d^ (the object-space
error of Lu, Hager and Mjolsness, "Fast and Globally Convergent Pose Estimation from Video
Images", PAMI 2000). Image noise is a fixed angle, so that distance has a spread
proportional to the depth; weighting by 1 / mu^2 turns each residual into the tangent of an
angle, and carried to its exact form this is the reprojection error in normalised
coordinates:

    Phi_ang = sum_{t,i} q~_{t,i} |pi(R_t (x_i - C_t)) - u_{t,i}|^2,    pi(p) = p[:2] / p[2],

the calibrated camera's maximum-likelihood fit under Gaussian image noise with the
landmarks as control points (bundle adjustment with control points). The cost is not convex
(rotations; depth times rotation), so the start matters, and resection-intersection
alternation on Phi converged too slowly to use (after 300 rounds from the true map the cost
was still 16x the truth's). What is done (:func:`calibrated_map`), in coordinates centred on
the landmarks and scaled to their spread (OpenCV's PnP has absolute thresholds):

1. every step that sees at least four landmarks gets its pose from them alone (SQPnP,
   Terzakis and Lourakis, ECCV 2020, then Levenberg-Marquardt on the reprojection error):
   their positions are exact, so these poses do not depend on any estimate;
2. grow: intersect every feature the placed steps see (least squares over its rays, with a
   prior ``prior * lambda_max |x - x0|^2`` toward x0, the landmark-constrained linear
   co-embedding map, which matters only where the rays are nearly parallel or absent), place
   every step that sees four or more landmarks or placed features, repeat; steps still
   unplaced use every feature they see (fewer than four: the nearest step's pose);
   intersect again from all steps;
3. a step with features it saw behind it has a wrong pose and takes the nearest good step's
   pose; a feature still behind a camera is brought in front by Levenberg-Marquardt on the
   unit-sphere chord residual (bounded and smooth behind a camera);
4. Levenberg-Marquardt on Phi_ang (:func:`reprojection_refine`; sparse exact Jacobian,
   rotations updated multiplicatively), with no prior: there it held far points near their
   start.

So this is no longer dimensionality reduction: the paper's closed form only supplies the
fallback x0 and the landmark constraint; what places the points is the camera model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from placeloc.coembed.observations import Observations
from placeloc.coembed.solver import CoembedError


@dataclass
class PinholeResult:
    X: np.ndarray          # (N, 3) map
    Q: np.ndarray          # (M, 3, 3) camera-to-map rotations R_t^T
    C: np.ndarray          # (M, 3) camera centres
    depth: np.ndarray      # (nnz,) distance along each ray
    costs: list[float]     # Phi_ang (plus prior) after every Levenberg-Marquardt iteration
    iterations: int


def unit_rays(normalised: np.ndarray) -> np.ndarray:
    """(nnz, 2) undistorted normalised image coordinates -> (nnz, 3) unit directions in the camera frame."""
    d = np.hstack([np.asarray(normalised, dtype=np.float64), np.ones((len(normalised), 1))])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _depths(rows: np.ndarray, cols: np.ndarray, rays: np.ndarray, q: np.ndarray, c: np.ndarray, x: np.ndarray,
            floor: float) -> np.ndarray:
    r = np.einsum("nab,nb->na", q[rows], rays)
    return np.maximum(np.sum(r * (x[cols] - c[rows]), axis=1), floor)


def _pnp(obj: np.ndarray, img: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Camera-to-map rotation Q and centre C from >= 4 known points and their normalised image points, or None."""
    import cv2

    eye = np.eye(3)
    obj = np.ascontiguousarray(obj, dtype=np.float64)
    img = np.ascontiguousarray(img, dtype=np.float64)
    try:
        found, rvec, tvec = cv2.solvePnP(obj, img, eye, None, flags=cv2.SOLVEPNP_SQPNP)
        if found:   # SQPnP's optimum of its algebraic cost, then Levenberg-Marquardt on the reprojection error
            found, rvec, tvec = cv2.solvePnP(obj, img, eye, None, rvec, tvec, useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
    except cv2.error:
        return None
    if not found:
        return None
    rot = cv2.Rodrigues(rvec)[0]
    return rot.T, -rot.T @ tvec.ravel()


def _resect(obs: Observations, normalised: np.ndarray, x: np.ndarray, usable: np.ndarray, steps: np.ndarray,
            q: np.ndarray, c: np.ndarray, ok: np.ndarray) -> None:
    """PnP for each of ``steps`` from the usable features it sees (at least 4); fills q, c, ok in place."""
    for t in steps:
        sl = slice(obs.indptr[t], obs.indptr[t + 1])
        use = usable[obs.indices[sl]]
        if use.sum() < 4:
            continue
        found = _pnp(x[obs.indices[sl]][use], normalised[sl][use])
        if found is not None:
            q[t], c[t] = found
            ok[t] = True


def _intersect(obs: Observations, rays: np.ndarray, q: np.ndarray, c: np.ndarray, use_obs: np.ndarray, x_prior: np.ndarray,
               prior: float) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares intersection of each feature's rays (q~ weights) from the sightings in ``use_obs``, with the
    prior ``prior * lambda_max |x - x_prior|^2``; returns the points and which features had a sighting."""
    n = obs.n_features
    rows, cols = obs.rows[use_obs], obs.indices[use_obs]
    w = 1.0 / np.bincount(obs.indices, minlength=n)[cols]
    r = np.einsum("nab,nb->na", q[rows], rays[use_obs])
    proj = np.eye(3)[None] - r[:, :, None] * r[:, None, :]
    a = np.zeros((n, 3, 3))
    b = np.zeros((n, 3))
    np.add.at(a, cols, w[:, None, None] * proj)
    np.add.at(b, cols, w[:, None] * np.einsum("nab,nb->na", proj, c[rows]))
    gamma = prior * np.linalg.eigvalsh(a)[:, -1]
    seen = np.bincount(cols, minlength=n) > 0
    a += (gamma + ~seen)[:, None, None] * np.eye(3)
    b += (gamma + ~seen)[:, None] * x_prior
    return np.linalg.solve(a, b[:, :, None])[:, :, 0], seen


def _steps_subset(obs: Observations, keep: np.ndarray) -> Observations:
    """The observation matrix restricted to the steps (rows) in ``keep``; all feature columns kept."""
    counts = np.diff(obs.indptr)[keep]
    sel = keep[obs.rows]
    return Observations(np.concatenate([[0], np.cumsum(counts)]).astype(np.int64), obs.indices[sel], obs.values[sel],
                        obs.step_ids[keep], obs.feature_ids)


def calibrated_map(obs: Observations, normalised: np.ndarray, landmark_cols: np.ndarray, landmark_xyz: np.ndarray,
                   x_fallback: np.ndarray, *, prior: float, max_iter: int, tol: float) -> PinholeResult:
    """The calibrated camera's map from the landmarks and the linear map ``x_fallback`` (steps 1-4 of the module docstring)."""
    normalised = np.asarray(normalised, dtype=np.float64)
    if normalised.ndim != 2 or normalised.shape[1] != 2:
        raise CoembedError("camera_model pinhole needs 2-D image points per sighting (normalised by the intrinsics)")
    landmark_cols = np.asarray(landmark_cols, dtype=np.int64)
    xstar = np.asarray(landmark_xyz, dtype=np.float64)
    if xstar.shape[1] != 3:
        raise CoembedError("camera_model pinhole maps image points to a 3-D map (coembed.dim: 3)")
    m, n = obs.n_steps, obs.n_features
    rays = unit_rays(normalised)
    is_lm = np.zeros(n, bool)
    is_lm[landmark_cols] = True
    # Work in coordinates centred on the landmarks and scaled to their RMS spread (OpenCV's PnP has absolute
    # thresholds), and map back at the end: the result does not depend on the map's origin or units.
    origin = xstar.mean(axis=0)
    unit = float(np.sqrt(np.mean(np.sum((xstar - origin) ** 2, axis=1)))) or 1.0
    xstar = (xstar - origin) / unit
    x = (np.array(x_fallback, dtype=np.float64) - origin) / unit
    x[landmark_cols] = xstar
    q = np.tile(np.eye(3), (m, 1, 1))
    c = np.zeros((m, 3))
    ok = np.zeros(m, bool)
    _resect(obs, normalised, x, is_lm, np.arange(m), q, c, ok)
    if not ok.any():
        raise CoembedError("camera_model pinhole: no step sees 4 landmarks, so no camera can be placed from them; "
                           "give more landmarks (or camera_model linear)")
    # Grow from the landmarks: intersect the points the placed frames see, then place the frames that see four or
    # more landmarks or placed points, and repeat. Only then may a frame use the fallback map.
    trusted = is_lm.copy()
    for _ in range(m):
        xi, seen = _intersect(obs, rays, q, c, ok[obs.rows], x, prior)
        fresh = ~is_lm & seen
        x[fresh] = xi[fresh]
        trusted |= fresh
        before = int(ok.sum())
        _resect(obs, normalised, x, trusted, np.flatnonzero(~ok), q, c, ok)
        if ok.sum() == before:
            break
    _resect(obs, normalised, x, np.ones(n, bool), np.flatnonzero(~ok), q, c, ok)
    if not ok.all():
        good = np.flatnonzero(ok)
        near = good[np.argmin(np.abs(np.arange(m)[:, None] - good[None, :]), axis=1)]
        q, c = q[near], c[near]
    xi, _ = _intersect(obs, rays, q, c, np.ones(obs.nnz, bool), x, prior)
    x[~is_lm] = xi[~is_lm]
    behind = _depths(obs.rows, obs.indices, rays, q, c, x, -np.inf) <= 0
    bad = np.bincount(obs.rows[behind], minlength=m) > 0
    if bad.any() and not bad.all():
        # A frame that has points it saw behind it has a wrong pose (a PnP on estimated points gone astray): it takes
        # the nearest good frame's pose, and the points are intersected again.
        good = np.flatnonzero(~bad)
        near = good[np.argmin(np.abs(np.arange(m)[:, None] - good[None, :]), axis=1)]
        q, c = q[near], c[near]
        xi, _ = _intersect(obs, rays, q, c, np.ones(obs.nnz, bool), x, prior)
        x[~is_lm] = xi[~is_lm]
    costs: list[float] = []
    if np.any(_depths(obs.rows, obs.indices, rays, q, c, x, -np.inf) <= 0):
        # A point behind a camera it was seen by: the reprojection error cannot move it (see reprojection_refine),
        # so the chord residual first brings the start in front of the cameras.
        x, q, c, costs = reprojection_refine(obs, normalised, landmark_cols, x, q, c, prior=0.0, max_iter=max_iter, tol=tol,
                                             residual_kind="chord")
    x, q, c, more = reprojection_refine(obs, normalised, landmark_cols, x, q, c, prior=0.0, max_iter=max_iter, tol=tol)
    costs += more
    mu = _depths(obs.rows, obs.indices, rays, q, c, x, 0.0)
    x = x * unit + origin
    x[landmark_cols] = np.asarray(landmark_xyz, dtype=np.float64)     # exactly, not up to rounding
    return PinholeResult(X=x, Q=q, C=c * unit + origin, depth=mu * unit, costs=costs, iterations=len(costs) - 1)


def _skew(v: np.ndarray) -> np.ndarray:
    """(n, 3) -> (n, 3, 3) cross-product matrices [v]_x."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


def _rodrigues(w: np.ndarray) -> np.ndarray:
    """(n, 3) rotation vectors -> (n, 3, 3) rotation matrices."""
    th = np.linalg.norm(w, axis=1)
    k = _skew(w / np.maximum(th, 1e-300)[:, None])
    s, c = np.sin(th)[:, None, None], (1 - np.cos(th))[:, None, None]
    return np.eye(3)[None] + s * k + c * np.einsum("nab,nbc->nac", k, k)


def reprojection_refine(obs: Observations, normalised: np.ndarray, landmark_cols: np.ndarray, x0: np.ndarray, q0: np.ndarray,
                        c0: np.ndarray, *, prior: float, max_iter: int, tol: float,
                        residual_kind: str = "projection") -> tuple[np.ndarray, np.ndarray, np.ndarray, list[float]]:
    """Levenberg-Marquardt on the calibrated camera's residuals plus prior terms, landmarks held fixed.

    ``residual_kind`` projection: sum q~ |pi(R_t (x_i - C_t)) - u_{t,i}|^2, pi(p) = p[:2] / p[2], the
    reprojection error in normalised coordinates (the maximum-likelihood cost); a point behind
    a camera is clamped to a tiny depth (a huge residual with no useful gradient, so a start
    with one stays stuck). chord: sum q~ |v(R_t (x_i - C_t)) - d^_{t,i}|^2 with v(p) = p / |p|, the
    chord between seen and observed direction on the unit sphere (the angle, to 1e-7 relative
    below a milliradian): smooth and bounded behind a camera, so it pulls such a point back,
    but bounded also means a point may settle behind a camera or too near, which is why
    :func:`calibrated_map` uses it only to repair a start. R_t = Q_t^T. Each iteration linearises at the current estimate (rotation updates
    exp([w]) R_t, so the Jacobian is exact at w = 0) and solves the damped normal equations
    (sparse). The prior ``prior * lambda_max(H_i) |x_i - x0_i|^2`` (H_i the diagonal of the
    feature's own block of J^T J at the start) only holds points whose rays are nearly parallel.
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    m, n = obs.n_steps, obs.n_features
    rows, cols = obs.rows, obs.indices
    nnz = obs.nnz
    u = np.asarray(normalised, dtype=np.float64)
    d_obs = unit_rays(u)
    sw = np.sqrt(1.0 / np.bincount(cols, minlength=n)[cols])
    free = np.ones(n, bool)
    free[np.asarray(landmark_cols, dtype=np.int64)] = False
    slot = np.full(n, -1)
    slot[free] = np.arange(free.sum())
    nf = int(free.sum())
    rot = np.transpose(np.asarray(q0, dtype=np.float64), (0, 2, 1)).copy()
    c = np.asarray(c0, dtype=np.float64).copy()
    x = np.asarray(x0, dtype=np.float64).copy()
    xprior = x.copy()
    # A point on a camera centre (chord), or behind one (projection: clamped to this depth): relative to the map's size.
    tiny = 1e-12 * max(float(np.ptp(x, axis=0).max()), 1e-300)
    z_floor = 1e3 * tiny

    def chord_residual(rot: np.ndarray, c: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xc = np.einsum("nab,nb->na", rot[rows], x[cols] - c[rows])
        norm = np.maximum(np.linalg.norm(xc, axis=1), tiny)
        return sw[:, None] * (xc / norm[:, None] - d_obs), xc

    def chord_jacobian(rot: np.ndarray, xc: np.ndarray) -> sp.csr_matrix:
        norm = np.maximum(np.linalg.norm(xc, axis=1), tiny)
        v = xc / norm[:, None]
        dp = (np.eye(3)[None] - v[:, :, None] * v[:, None, :]) * (sw / norm)[:, None, None]   # d v / d xc
        j_w = np.einsum("nab,nbc->nac", dp, -_skew(xc))       # d xc / d w = -[xc]_x
        j_x = np.einsum("nab,nbc->nac", dp, rot[rows])        # d xc / d x = R; d xc / d C = -R
        r_idx = np.repeat(3 * np.arange(nnz)[:, None] + np.arange(3), 3, axis=1).reshape(nnz, 3, 3)
        has = slot[cols] >= 0
        parts_r, parts_v = [r_idx, r_idx, r_idx[has]], [j_w, -j_x, j_x[has]]
        parts_c = [np.broadcast_to((3 * rows)[:, None, None] + np.arange(3), (nnz, 3, 3)),
                   np.broadcast_to((3 * m + 3 * rows)[:, None, None] + np.arange(3), (nnz, 3, 3)),
                   np.broadcast_to((6 * m + 3 * slot[cols[has]])[:, None, None] + np.arange(3), (int(has.sum()), 3, 3))]
        return sp.csr_matrix((np.concatenate([p.ravel() for p in parts_v]),
                              (np.concatenate([p.ravel() for p in parts_r]), np.concatenate([p.ravel() for p in parts_c]))),
                             shape=(3 * nnz, 6 * m + 3 * nf))

    def projection_residual(rot: np.ndarray, c: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xc = np.einsum("nab,nb->na", rot[rows], x[cols] - c[rows])
        z = np.where(xc[:, 2] > z_floor, xc[:, 2], z_floor)     # a point behind the camera: a large residual, not a sign flip
        return sw[:, None] * (xc[:, :2] / z[:, None] - u), xc

    def projection_jacobian(rot: np.ndarray, xc: np.ndarray) -> sp.csr_matrix:
        z = np.where(xc[:, 2] > z_floor, xc[:, 2], z_floor)
        dp = np.zeros((nnz, 2, 3))
        dp[:, 0, 0] = dp[:, 1, 1] = 1.0 / z
        dp[:, 0, 2], dp[:, 1, 2] = -xc[:, 0] / z ** 2, -xc[:, 1] / z ** 2
        dp *= sw[:, None, None]
        j_w = np.einsum("nab,nbc->nac", dp, -_skew(xc))       # d xc / d w = -[xc]_x
        j_x = np.einsum("nab,nbc->nac", dp, rot[rows])        # d xc / d x = R; d xc / d C = -R
        r_idx = np.repeat(2 * np.arange(nnz)[:, None] + np.arange(2), 3, axis=1).reshape(nnz, 2, 3)
        parts_r, parts_c, parts_v = [r_idx, r_idx, r_idx[slot[cols] >= 0]], [], [j_w, -j_x, j_x[slot[cols] >= 0]]
        parts_c.append(np.broadcast_to((3 * rows)[:, None, None] + np.arange(3), (nnz, 2, 3)))
        parts_c.append(np.broadcast_to((3 * m + 3 * rows)[:, None, None] + np.arange(3), (nnz, 2, 3)))
        has = slot[cols] >= 0
        parts_c.append(np.broadcast_to((6 * m + 3 * slot[cols[has]])[:, None, None] + np.arange(3), (int(has.sum()), 2, 3)))
        return sp.csr_matrix((np.concatenate([p.ravel() for p in parts_v]),
                              (np.concatenate([p.ravel() for p in parts_r]), np.concatenate([p.ravel() for p in parts_c]))),
                             shape=(2 * nnz, 6 * m + 3 * nf))

    if residual_kind not in ("projection", "chord"):
        raise CoembedError(f"residual_kind must be projection or chord, got {residual_kind!r}")
    residual, jacobian = ((projection_residual, projection_jacobian) if residual_kind == "projection"
                          else (chord_residual, chord_jacobian))

    res, xc = residual(rot, c, x)
    jac = jacobian(rot, xc)
    hdiag_blocks = (jac.T @ jac).diagonal()[6 * m:].reshape(nf, 3)
    gamma = prior * np.maximum(hdiag_blocks.max(axis=1), 1e-300)     # per free point
    def total(res: np.ndarray, x: np.ndarray) -> float:
        return float(np.sum(res ** 2) + np.sum(gamma[:, None] * (x[free] - xprior[free]) ** 2))
    cost = total(res, x)
    costs = [cost]
    lam = 1e-3
    for _ in range(max_iter):
        g_prior = np.zeros(6 * m + 3 * nf)
        g_prior[6 * m:] = (gamma[:, None] * (x[free] - xprior[free])).ravel()
        h = (jac.T @ jac).tocsr()
        h = h + sp.diags(np.concatenate([np.zeros(6 * m), np.repeat(gamma, 3)]))
        grad = jac.T @ res.ravel() + g_prior
        improved = False
        for _ in range(10):
            step = -spsolve((h + lam * sp.diags(h.diagonal() + 1e-12)).tocsc(), grad)
            rot_new = np.einsum("mab,mbc->mac", _rodrigues(step[:3 * m].reshape(m, 3)), rot)
            c_new = c + step[3 * m:6 * m].reshape(m, 3)
            x_new = x.copy()
            x_new[free] += step[6 * m:].reshape(nf, 3)
            res_new, xc_new = residual(rot_new, c_new, x_new)
            new = total(res_new, x_new)
            if new < cost:
                rot, c, x, res, xc = rot_new, c_new, x_new, res_new, xc_new
                lam = max(lam / 3, 1e-9)
                improved = True
                break
            lam *= 4
        if not improved:
            break
        done = cost - new <= tol * cost
        cost = new
        costs.append(cost)
        if done:
            break
        jac = jacobian(rot, xc)
    return x, np.transpose(rot, (0, 2, 1)), c, costs
