"""Isomap (Tenenbaum, de Silva and Langford 2000) on features with missing observations.

Each feature is a point in observation space (its column of the observation matrix). Two
features are compared on the steps where both were observed: the distance is the RMS
difference of their observations there, scaled by sqrt(M) so it has the units of a full
Euclidean distance. Pairs with fewer than ``min_common`` shared steps have no distance.
A k-nearest-neighbour graph on the known distances, joined with their minimum spanning tree
so that the graph is connected whenever the known distances connect it, gives geodesics
(Dijkstra); classical MDS of the geodesics gives the embedding.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree, shortest_path

from placeloc.coembed.observations import Observations


class IsomapError(ValueError):
    """The neighbourhood graph is disconnected or the input too small."""


def feature_distances(obs: Observations, *, min_common: int) -> np.ndarray:
    """N x N RMS observation distance over shared steps (inf where fewer than ``min_common`` are shared)."""
    q = obs.mask().astype(np.float64)
    common = (q.T @ q).toarray()
    d2 = np.zeros_like(common)
    for a in range(obs.value_dim):
        y = obs.component(a)
        ysq = y.multiply(y).tocsr()
        s = (ysq.T @ q).toarray()          # sum over steps shared with j of y_i^2
        d2 += s + s.T - 2.0 * (y.T @ y).toarray()
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.sqrt(np.maximum(d2, 0.0) / common * obs.n_steps)
    dist[common < max(min_common, 1)] = np.inf
    np.fill_diagonal(dist, 0.0)
    return dist


def classical_mds(dist: np.ndarray, dim: int) -> np.ndarray:
    """Torgerson MDS: top ``dim`` eigenvectors of the double-centred squared distances."""
    n = len(dist)
    d2 = dist ** 2
    j = np.eye(n) - 1.0 / n
    b = -0.5 * j @ d2 @ j
    w, v = np.linalg.eigh((b + b.T) / 2)
    order = np.argsort(w)[::-1][:dim]
    return v[:, order] * np.sqrt(np.maximum(w[order], 0.0))


def isomap_from_distances(dist: np.ndarray, n_neighbors: int, dim: int) -> np.ndarray:
    """Isomap embedding (n x dim) from a distance matrix with inf for unknown distances."""
    dist = np.asarray(dist, dtype=np.float64)
    n = len(dist)
    if n < dim + 2:
        raise IsomapError(f"Isomap into {dim}-D needs at least {dim + 2} points, got {n}")
    if n_neighbors < 1:
        raise IsomapError("isomap_neighbors must be >= 1")
    known = np.isfinite(dist)
    np.fill_diagonal(known, False)
    d = np.where(known, dist, np.inf)
    k = min(n_neighbors, n - 1)
    nn = np.argpartition(d, k - 1, axis=1)[:, :k]
    rows = np.repeat(np.arange(n), k)
    cols = nn.ravel()
    vals = d[rows, cols]
    ok = np.isfinite(vals)
    # Zero distances would vanish in a sparse graph; a tiny positive weight keeps the edge.
    tiny = 1e-12 * (np.max(d[known]) if known.any() else 1.0)
    knn = sp.coo_matrix((np.maximum(vals[ok], tiny), (rows[ok], cols[ok])), shape=(n, n)).tocsr()
    full = sp.csr_matrix(np.where(known, np.maximum(dist, tiny), 0.0))
    mst = minimum_spanning_tree(full)
    graph = knn.maximum(knn.T).maximum(mst.maximum(mst.T))
    n_comp, labels = connected_components(graph, directed=False)
    if n_comp > 1:
        sizes = np.bincount(labels)
        raise IsomapError(f"the features fall into {n_comp} groups that are never observed together "
                          f"(sizes {sorted(sizes.tolist(), reverse=True)[:5]}); Isomap cannot place one group relative to another")
    geo = shortest_path(graph, method="D", directed=False)
    return classical_mds(geo, dim)


def isomap_points(points: np.ndarray, n_neighbors: int, dim: int) -> np.ndarray:
    """Isomap of complete data (n x p points, Euclidean distances)."""
    points = np.asarray(points, dtype=np.float64)
    sq = np.sum(points ** 2, axis=1)
    dist = np.sqrt(np.maximum(sq[:, None] + sq[None, :] - 2 * points @ points.T, 0.0))
    return isomap_from_distances(dist, n_neighbors, dim)


def isomap_features(obs: Observations, *, n_neighbors: int, dim: int, min_common: int) -> np.ndarray:
    """Unsupervised Isomap embedding of every feature (N x dim)."""
    return isomap_from_distances(feature_distances(obs, min_common=min_common), n_neighbors, dim)
