"""Incremental PIRF-nav2 mapping: node vectors, similarity eqs. (5)-(9), dictionary updates.

Every mapping frame is a location node L_t. Choices where the paper is silent (recorded
here and in docs/pirf.md):

- The query vector m_t is over Q_{t-eps} (eq. 3-4); a node's *stored* vector m_j holds
  every dictionary word that represents P_j: the words its PIRFs matched plus the words
  its own new PIRFs became (or, in the improved update, matched while being inserted).
  Without the latter a revisit could never overlap the node that first saw the place.
- Loop-closure candidates are the nodes j < t - eps: the recent nodes share m_t's words
  trivially (same place, seconds ago), which eps exists to exclude.
- I_j (eq. 6, 8) are the temporal neighbours j-1 and j+1 among the candidates.
- The ratio test needs two candidates; with fewer nothing matches (so the first PIRFs
  always enter the dictionary).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

import numpy as np
import scipy.sparse as sp

from placeloc.core.faiss_loader import import_faiss
from placeloc.pirf.knn import bf_knn2, sq_norms


def gauss(x: float, sigma: float) -> float:
    """Eq. (7): the normal density N(x; 0, sigma)."""
    return math.exp(-x * x / (2 * sigma * sigma)) / math.sqrt(2 * math.pi * sigma * sigma)


def similarity_s(n_mt: int, overlap: np.ndarray, n_pmax: int) -> np.ndarray:
    """Eq. (5): s_j = |m_t|_1 / n_pmax * |m_t AND m_j|_1 / n_pmax."""
    return (n_mt / n_pmax) * (np.asarray(overlap, np.float64) / n_pmax)


def z_norm(s: np.ndarray, sigma: float) -> np.ndarray:
    """Eqs. (6) and (8) with I_j = {j-1, j+1} (those that exist)."""
    s = np.asarray(s, np.float64)
    k = len(s)
    if k == 0:
        return s
    nb_s = np.zeros(k)
    nb_s[1:] += s[:-1]
    nb_s[:-1] += s[1:]
    z = s * gauss(0.0, sigma) + nb_s * gauss(1.0, sigma)  # (6)
    nb_z = np.zeros(k)
    nb_z[1:] += z[:-1]
    nb_z[:-1] += z[1:]
    n_nb = np.full(k, 2.0)
    n_nb[0] -= 1
    n_nb[-1] -= 1
    if k == 1:
        n_nb[:] = 0
    return (z + nb_z) / (1 + n_nb)  # (8)


def ratio_ok(d2: np.ndarray, idx: np.ndarray, ratio: float) -> np.ndarray:
    """Eq. (1) on squared distances; rows without two neighbours never match."""
    return (idx[:, 1] >= 0) & (d2[:, 0] < (ratio * ratio) * d2[:, 1])


def improved_insert(p_new: np.ndarray, d_q: np.ndarray, i_q: np.ndarray, n_dict: int, ratio: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sec. 4.1: insert P_new one by one, in descending d_k (eq. 13), each only if it has no
    ratio-test match in Q^{(i-1)} = Q_{t-1} plus the ones inserted so far (eqs. 11-12, 14-15).

    ``d_q``/``i_q``: squared distances / indices of each p's two nearest entries in Q_{t-1}.
    Returns (order (sorted positions into p_new), added mask over p_new, word per p: the new
    word id if added, else the matched word).
    """
    n = len(p_new)
    order = np.argsort(-d_q[:, 0], kind="stable")  # d_k descending; inf (empty Q) first
    pn = sq_norms(p_new)
    pair = np.maximum(pn[:, None] + pn[None, :] - 2 * (p_new @ p_new.T), 0)
    added = np.zeros(n, bool)
    word = np.full(n, -1, np.int64)
    a_pos: list[int] = []  # positions in p_new of the inserted ones, in insertion order
    next_id = n_dict
    for i in order:
        cand_d = list(d_q[i])
        cand_w = list(i_q[i])
        if a_pos:
            da = pair[i, a_pos]
            two = np.argsort(da, kind="stable")[:2]
            cand_d += list(da[two])
            cand_w += [int(word[a_pos[j]]) for j in two]
        o = np.argsort(np.asarray(cand_d), kind="stable")[:2]
        d1, d2 = cand_d[o[0]], (cand_d[o[1]] if len(o) > 1 else np.inf)
        w1 = cand_w[o[0]]
        valid2 = len(o) > 1 and cand_w[o[1]] >= 0
        if valid2 and w1 >= 0 and d1 < ratio * ratio * d2:
            word[i] = w1  # (12): a match exists in Q^{(i-1)}: rejected, but the node sees that word
        else:
            word[i] = next_id  # (11): inserted
            next_id += 1
            added[i] = True
            a_pos.append(int(i))
    return order, added, word


@dataclass
class PirfMapper:
    """Grows the dictionary frame by frame and finds each frame's best earlier node (brute
    force, exact). The loop-closure decision (score >= tau, eq. 9) does not feed back into
    mapping in the paper, so it is applied afterwards by :func:`loop_closures`."""

    dim: int
    ratio: float
    n_pmax: int
    eps: int
    sigma: float
    update: str
    # Nearest neighbours while mapping: exact ("bruteforce") or an HNSW graph grown with the
    # dictionary ("faiss-hnsw", searched with ``ef_search``; M and efConstruction as given).
    search: str
    hnsw_m: int
    hnsw_ef_construction: int
    ef_search: int
    words: np.ndarray = field(init=False)
    norms: np.ndarray = field(init=False)
    n: int = 0
    dict_size_after: list[int] = field(default_factory=list)
    node_words: list[np.ndarray] = field(default_factory=list)
    pairs_after: list[int] = field(default_factory=list)
    best: list[tuple[int, float]] = field(default_factory=list)
    # after each step: (P_new, squared distances and ids of their 2 nearest words in Q_{t-1}, |Q_{t-1}|)
    last_new: tuple[np.ndarray, np.ndarray, np.ndarray, int] | None = None

    def __post_init__(self) -> None:
        if self.update not in ("plain", "improved"):
            raise ValueError(f"update must be plain or improved, got {self.update!r}")
        self.words = np.zeros((4096, self.dim), np.float32)
        self.norms = np.zeros(4096, np.float32)
        if self.search not in ("bruteforce", "faiss-hnsw"):
            raise ValueError(f"search must be bruteforce or faiss-hnsw, got {self.search!r}")
        self._hnsw = None
        if self.search == "faiss-hnsw":
            faiss = import_faiss()
            self._hnsw = faiss.IndexHNSWFlat(self.dim, int(self.hnsw_m))
            self._hnsw.hnsw.efConstruction = int(self.hnsw_ef_construction)
        self._pair_nodes = np.zeros(1 << 16, np.int32)
        self._pair_words = np.zeros(1 << 16, np.int64)
        self._npairs = 0

    def _grow(self, extra: int) -> None:
        need = self.n + extra
        if need > len(self.words):
            cap = max(need, 2 * len(self.words))
            w = np.zeros((cap, self.dim), np.float32)
            w[: self.n] = self.words[: self.n]
            nr = np.zeros(cap, np.float32)
            nr[: self.n] = self.norms[: self.n]
            self.words, self.norms = w, nr

    def _add_pairs(self, node: int, words: np.ndarray) -> None:
        need = self._npairs + len(words)
        if need > len(self._pair_nodes):
            cap = max(need, 2 * len(self._pair_nodes))
            self._pair_nodes = np.resize(self._pair_nodes, cap)
            self._pair_words = np.resize(self._pair_words, cap)
        self._pair_nodes[self._npairs:need] = node
        self._pair_words[self._npairs:need] = words
        self._npairs = need

    def _hnsw_knn2(self, q: np.ndarray, limit: int) -> tuple[np.ndarray, np.ndarray]:
        """2-NN among the first ``limit`` words (Q_{t-1} or Q_{t-eps}) from the HNSW graph."""
        faiss = import_faiss()

        if limit == 0 or len(q) == 0:
            return np.full((len(q), 2), np.inf, np.float32), np.full((len(q), 2), -1, np.int64)
        params = faiss.SearchParametersHNSW()
        params.efSearch = int(self.ef_search)
        sel = faiss.IDSelectorRange(0, int(limit))  # kept referenced while the search runs
        if limit < self.n:
            params.sel = sel
        threads = faiss.omp_get_max_threads()
        faiss.omp_set_num_threads(1)  # measured serial (19.5 frames/s at 481k words); threads with sleeping idle workers untried here
        try:
            d, i = self._hnsw.search(q, 2, params=params)
        finally:
            faiss.omp_set_num_threads(threads)
        i = i.astype(np.int64)
        return np.where(i < 0, np.inf, d).astype(np.float32), i

    def _hnsw_add(self, x: np.ndarray) -> None:
        faiss = import_faiss()

        threads = faiss.omp_get_max_threads()
        faiss.omp_set_num_threads(1)
        try:
            self._hnsw.add(np.ascontiguousarray(x, np.float32))
        finally:
            faiss.omp_set_num_threads(threads)

    @property
    def dictionary(self) -> np.ndarray:
        return self.words[: self.n]

    def step(self, pirfs: np.ndarray) -> tuple[int, float, int]:
        """Process frame t's PIRFs: returns (best candidate node or -1, its z_norm, |m_t|)."""
        t = len(self.node_words)
        p = np.ascontiguousarray(pirfs, np.float32).reshape(-1, self.dim)
        n_eps = self.dict_size_after[t - self.eps] if t - self.eps >= 0 else 0
        if self._hnsw is None:
            d_f, i_f, d_e, i_e = bf_knn2(p, self.words[: self.n], b_norms=self.norms[: self.n], splits=(n_eps,))
        else:
            d_f, i_f = self._hnsw_knn2(p, self.n)
            d_e, i_e = self._hnsw_knn2(p, n_eps) if n_eps < self.n else (d_f, i_f)
        # m_t over Q_{t-eps} (eqs. 3-4)
        m_t = np.unique(i_e[ratio_ok(d_e, i_e, self.ratio), 0]) if n_eps else np.zeros(0, np.int64)
        k = max(0, t - self.eps)  # candidates j < t - eps
        c, score = -1, 0.0
        if k > 0 and len(m_t):
            ind = np.zeros(self.n, bool)
            ind[m_t] = True
            npairs = self.pairs_after[k - 1]
            hit = ind[self._pair_words[:npairs]]
            overlap = np.bincount(self._pair_nodes[:npairs][hit], minlength=k)
            z = z_norm(similarity_s(len(m_t), overlap, self.n_pmax), self.sigma)
            c = int(np.argmax(z))
            score = float(z[c])
        self.best.append((c, score))
        # dictionary update (sec. 3.4 / 4.1) against the whole Q_{t-1}
        ok = ratio_ok(d_f, i_f, self.ratio)
        matched = i_f[ok, 0]
        new = np.flatnonzero(~ok)
        # P_new with its two nearest words in Q_{t-1}, kept for diagnostics (what the other
        # update would have done with this frame): references, no copies
        self.last_new = (p[new], d_f[new], i_f[new], self.n)
        if self.update == "plain":
            ids = np.arange(self.n, self.n + len(new))
            add_rows = new
            node = np.concatenate([matched, ids])
        else:
            order, added, word = improved_insert(p[new], d_f[new], i_f[new], self.n, self.ratio)
            # rows are appended in insertion order so word ids are consecutive
            ins = order[added[order]]
            add_rows = new[ins]
            node = np.concatenate([matched, word])
        self._grow(len(add_rows))
        self.words[self.n:self.n + len(add_rows)] = p[add_rows]
        self.norms[self.n:self.n + len(add_rows)] = sq_norms(p[add_rows]) if len(add_rows) else 0
        if self._hnsw is not None and len(add_rows):
            self._hnsw_add(p[add_rows])
        self.n += len(add_rows)
        node = np.unique(node)
        self.node_words.append(node)
        self._add_pairs(t, node)
        self.pairs_after.append(self._npairs)
        self.dict_size_after.append(self.n)
        return c, score, len(m_t)


def map_video(pirfs: np.ndarray, offsets: np.ndarray, *, ratio: float, n_pmax: int, eps: int, sigma: float, update: str,
              search: str, hnsw_m: int, hnsw_ef_construction: int, ef_search: int,
              progress: Callable[[Iterable[int]], Iterable[int]] = iter) -> dict[str, Any]:
    """Map a whole video: frame t's PIRFs are ``pirfs[offsets[t]:offsets[t + 1]]``.

    Returns the dictionary, node vectors (CSR ``node_ptr``/``node_words``), every frame's best
    candidate and score, the dictionary size after each frame and seconds per frame, wall
    (``map_seconds``) and CPU of this process, all threads (``map_cpu_seconds``: on a shared
    machine the wall time also counts other jobs).
    """
    mapper = PirfMapper(pirfs.shape[1], ratio=ratio, n_pmax=n_pmax, eps=eps, sigma=sigma, update=update, search=search,
                        hnsw_m=hnsw_m, hnsw_ef_construction=hnsw_ef_construction, ef_search=ef_search)
    n = len(offsets) - 1
    secs = np.zeros(n)
    cpu = np.zeros(n)
    for t in progress(range(n)):
        t0, c0 = time.perf_counter(), time.process_time()
        mapper.step(pirfs[offsets[t]:offsets[t + 1]])
        secs[t] = time.perf_counter() - t0
        cpu[t] = time.process_time() - c0
    ptr = np.concatenate([[0], np.cumsum([len(v) for v in mapper.node_words])]).astype(np.int64)
    return {"dictionary": mapper.dictionary, "node_ptr": ptr,
            "node_words": np.concatenate(mapper.node_words).astype(np.int64) if n else np.zeros(0, np.int64),
            "best_node": np.array([b[0] for b in mapper.best], np.int64),
            "best_score": np.array([b[1] for b in mapper.best], np.float64),
            "dict_size_after": np.array(mapper.dict_size_after, np.int64), "map_seconds": secs, "map_cpu_seconds": cpu}


def loop_closures(best_node: np.ndarray, best_score: np.ndarray, tau: float) -> np.ndarray:
    """Frames whose best earlier node scores at least ``tau`` (eq. 9): a loop closure."""
    return np.flatnonzero((best_node >= 0) & (best_score >= tau))


def correct_for_travel_direction(frames: np.ndarray, nodes: np.ndarray, window: np.ndarray, span: int) -> np.ndarray:
    """Loop-closure nodes corrected for the lag of PIRF tracks on opposite-direction revisits.

    A PIRF is a feature tracked through the last w frames and belongs to the last one, so
    node j's words describe frames j-w..j. Revisiting a place walking the other way, the
    query's last w_t frames lie *ahead* (in old-frame order) of where it stands, and the
    best-overlapping node c is about (w_t + w_c) / 2 frames past the true one; walking the
    same way the two lags cancel. The direction is read from the loop closures themselves:
    over the closures of the last ``span`` frames, matched nodes that decrease while t
    increases mean the other way. The first closure of a revisit is left as matched.
    """
    out = nodes.copy()
    for k, (t, c) in enumerate(zip(frames, nodes)):
        recent = nodes[(frames >= t - span) & (frames <= t)]
        if len(recent) < 2 or np.median(np.diff(recent)) >= 0:
            continue
        out[k] = max(0, c - int(round((window[t] + window[c]) / 2)))
    return out


def node_vector(d2: np.ndarray, idx: np.ndarray, ratio: float) -> np.ndarray:
    """m_t as sorted word ids: the dictionary entries some PIRF ratio-test-matches."""
    return np.unique(idx[ratio_ok(d2, idx, ratio), 0])


def localize_frame(m_t: np.ndarray, nodes: sp.csr_matrix, n_pmax: int, sigma: float) -> tuple[int, float]:
    """Best node (eq. 9) over all nodes for a query vector; (-1, 0) when m_t is empty."""
    if len(m_t) == 0 or nodes.shape[0] == 0:
        return -1, 0.0
    ind = np.zeros(nodes.shape[1], np.float32)
    ind[m_t] = 1
    overlap = nodes @ ind
    z = z_norm(similarity_s(len(m_t), overlap, n_pmax), sigma)
    c = int(np.argmax(z))
    return c, float(z[c])


def localize_video(pirfs: np.ndarray, offsets: np.ndarray, knn2: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
                   nodes: sp.csr_matrix, *, ratio: float, n_pmax: int, sigma: float) -> dict[str, Any]:
    """Best node per query frame, with ``knn2`` (an index's 2-NN search) computing m_t;
    m_t as CSR (``m_ptr``/``m_words``) and seconds per frame spent on m_t."""
    n = len(offsets) - 1
    best = np.full(n, -1, np.int64)
    score = np.zeros(n)
    secs = np.zeros(n)
    vecs = []
    for t in range(n):
        t0 = time.perf_counter()
        d2, ix = knn2(pirfs[offsets[t]:offsets[t + 1]])
        m = node_vector(d2, ix, ratio)
        secs[t] = time.perf_counter() - t0
        vecs.append(m)
        best[t], score[t] = localize_frame(m, nodes, n_pmax, sigma)
    ptr = np.concatenate([[0], np.cumsum([len(v) for v in vecs])]).astype(np.int64)
    return {"best_node": best, "score": score, "mt_seconds": secs, "m_ptr": ptr,
            "m_words": np.concatenate(vecs).astype(np.int64) if vecs else np.zeros(0, np.int64)}


def csr_rows(ptr: np.ndarray, words: np.ndarray, n_cols: int) -> sp.csr_matrix:
    """Node vectors stored as CSR arrays -> a sparse (nodes x words) 0/1 matrix."""
    return sp.csr_matrix((np.ones(len(words), np.float32), words.astype(np.int64), ptr.astype(np.int64)),
                         shape=(len(ptr) - 1, n_cols))
