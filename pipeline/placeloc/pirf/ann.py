"""Nearest-neighbour indexes over the finished PIRF dictionary (sec. 4.2).

Backends (all return *squared* L2 distances of the 2 nearest entries, so the ratio test
is d1^2 < 0.49 d2^2 for D = 0.7):

- ``bruteforce``: exact, BLAS (:func:`placeloc.pirf.knn.bf_knn2`).
- ``flann-auto``: OpenCV FLANN autotuned (``algorithm=255``) as in the paper. Python
  cannot pass ``target_precision`` (float/double mismatch), so FLANN's default 0.8
  applies; searched with ``checks=-2`` (the tuned value). Seeded via ``cv2.setRNGSeed``.
- ``flann-kmeans`` (hierarchical k-means, branching 32) and ``flann-kdtree`` (4 trees),
  searched with ``checks`` leaves.
- ``faiss-hnsw`` (HNSW, M = ``hnsw_m``, searched with ``ef_search``) and ``faiss-ivf``
  (IVFFlat, ``ivf_nlist`` lists, ``ivf_nprobe`` probed; k-means seeded).

Storage (no pickle): faiss indexes serialise to bytes (a uint8 dataset). A FLANN index
is saved to a temporary file and stored as bytes; it does not contain the vectors and
loading it over other data of the same shape silently gives wrong answers, so the
dictionary's SHA-256 is stored beside it and checked on load.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import time
from typing import Any

import cv2
import h5py
import numpy as np

from placeloc.core.faiss_loader import import_faiss
from placeloc.pirf.knn import bf_knn2, exact_knn, sq_norms

BACKENDS = ("bruteforce", "flann-auto", "flann-kmeans", "flann-kdtree", "faiss-hnsw", "faiss-ivf")
# The settings each backend reads (their defaults live in placeloc.pirf.params only).
BACKEND_KEYS: dict[str, tuple[str, ...]] = {
    "bruteforce": (), "flann-auto": (), "flann-kmeans": ("checks", "kmeans_branching"), "flann-kdtree": ("checks", "kdtree_trees"),
    "faiss-hnsw": ("hnsw_m", "hnsw_ef_construction", "ef_search"), "faiss-ivf": ("ivf_nlist", "ivf_nprobe")}


class IndexMismatchError(RuntimeError):
    """The stored index does not fit the dictionary (or cannot be loaded); says what to re-run."""


def data_hash(data: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(data, np.float32).tobytes()).hexdigest()


class AnnIndex:
    """A built (or loaded) index over ``data``; :meth:`knn2` answers 2-NN queries."""

    def __init__(self, backend: str, data: np.ndarray, params: dict[str, Any], seed: int = 0) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"unknown index backend {backend!r}; choose one of {', '.join(BACKENDS)}")
        self.backend = backend
        self.data = np.ascontiguousarray(data, np.float32)
        missing = [k for k in BACKEND_KEYS[backend] if k not in params]
        if missing:
            raise ValueError(f"index backend {backend} needs the settings {', '.join(missing)} (see placeloc.pirf.params)")
        self.params = dict(params)
        self.seed = seed
        self.impl: Any = None
        self.norms: np.ndarray | None = None
        self.build_seconds = 0.0
        self.id_map: np.ndarray | None = None  # row of the dictionary for each id in the index (None: identity)
        self.n_held = 0

    # -- building -------------------------------------------------------------------
    def build(self, hold_out: np.ndarray | None = None) -> AnnIndex:
        """Build the index. ``hold_out`` (faiss backends): entries left out for now, so they can
        serve as unseen queries (:mod:`placeloc.pirf.tuning`); :meth:`add_held_out` adds them,
        and ids stay the dictionary's row numbers through ``id_map``."""
        t0 = time.perf_counter()
        p, d, n = self.params, self.data, len(self.data)
        if hold_out is not None and len(hold_out):
            if not self.backend.startswith("faiss"):
                raise ValueError(f"holding entries out needs a faiss backend, not {self.backend}")
            held = np.zeros(n, bool)
            held[hold_out] = True
            self.id_map = np.concatenate([np.flatnonzero(~held), np.flatnonzero(held)]).astype(np.int64)
            self.n_held = int(held.sum())
            d = np.ascontiguousarray(d[self.id_map[: n - self.n_held]])
        if n < 2:
            raise ValueError(f"cannot index a dictionary of {n} entries (need >= 2); map a longer video")
        if self.backend == "bruteforce":
            self.norms = sq_norms(d)
        elif self.backend.startswith("flann"):
            cv2.setRNGSeed(self.seed)  # FLANN's k-means and autotune draw from OpenCV's RNG
            if self.backend == "flann-auto":
                ip = {"algorithm": 255}
            elif self.backend == "flann-kmeans":
                ip = {"algorithm": 2, "branching": int(p["kmeans_branching"]), "iterations": 11}
            else:
                ip = {"algorithm": 1, "trees": int(p["kdtree_trees"])}
            self.impl = cv2.flann_Index(d, ip)
        else:
            faiss = import_faiss()
            dim = d.shape[1]
            if self.backend == "faiss-hnsw":
                idx = faiss.IndexHNSWFlat(dim, int(p["hnsw_m"]))
                idx.hnsw.efConstruction = int(p["hnsw_ef_construction"])
                idx.add(d)
            else:
                nlist = int(max(1, min(p["ivf_nlist"], n // 39)))  # faiss wants >= 39 points per list
                quant = faiss.IndexFlatL2(dim)
                idx = faiss.IndexIVFFlat(quant, dim, nlist)
                idx.cp.seed = self.seed
                idx.train(d)
                idx.add(d)

            self.impl = idx
            self._set_faiss_search()
        self.build_seconds = time.perf_counter() - t0
        return self

    def add_held_out(self) -> None:
        """Add the entries :meth:`build` held out; afterwards the index covers the whole dictionary."""
        if not self.n_held:
            return
        t0 = time.perf_counter()
        self.impl.add(np.ascontiguousarray(self.data[self.id_map[len(self.data) - self.n_held:]]))
        self.n_held = 0
        self.build_seconds += time.perf_counter() - t0

    def _set_faiss_search(self) -> None:
        if self.backend == "faiss-hnsw":
            self.impl.hnsw.efSearch = int(self.params["ef_search"])
        elif self.backend == "faiss-ivf":
            self.impl.nprobe = int(self.params["ivf_nprobe"])

    # -- querying -------------------------------------------------------------------
    def knn2(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(squared distances (n, 2), indices (n, 2)); missing neighbours are inf / -1."""
        return self.knn(q, 2)

    def knn(self, q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(squared distances (n, k), indices (n, k)) of the k nearest entries; missing ones are inf / -1."""
        q = np.ascontiguousarray(q, np.float32)
        if len(q) == 0:
            return np.zeros((0, k), np.float32), np.zeros((0, k), np.int64)
        if q.shape[1] != self.data.shape[1]:
            raise ValueError(f"query descriptors have {q.shape[1]} dimensions, the dictionary {self.data.shape[1]}")
        if self.backend == "bruteforce":
            return bf_knn2(q, self.data, b_norms=self.norms) if k == 2 else exact_knn(q, self.data, k)
        if self.backend.startswith("flann"):
            checks = -2 if self.backend == "flann-auto" else int(self.params["checks"])
            idx, dist = self.impl.knnSearch(q, k, params={"checks": checks})
            idx = np.asarray(idx, np.int64).reshape(-1, k)
            dist = np.asarray(dist, np.float32).reshape(-1, k)
        else:
            dist, idx = self.impl.search(q, k)  # on every core, idle threads sleeping (import_faiss)
            idx = idx.astype(np.int64)
            if self.id_map is not None:
                idx = np.where(idx >= 0, self.id_map[np.maximum(idx, 0)], -1)
        dist = np.where(idx < 0, np.inf, dist).astype(np.float32)
        return dist, idx

    def set_search(self, key: str, value: int) -> None:
        """Change a search-time setting (``ef_search``, ``ivf_nprobe``, ``checks``) without rebuilding."""
        self.params[key] = int(value)
        if self.backend.startswith("faiss"):
            self._set_faiss_search()

    # -- storage --------------------------------------------------------------------
    def to_h5(self, g: h5py.Group) -> None:
        g.attrs["backend"] = self.backend
        g.attrs["seed"] = self.seed
        g.attrs["build_seconds"] = self.build_seconds
        g.attrs["data_sha256"] = data_hash(self.data)
        for k, v in self.params.items():
            g.attrs[f"param_{k}"] = v
        if self.backend == "bruteforce":
            return
        if self.n_held:
            raise RuntimeError("add the held-out entries (add_held_out) before storing the index")
        if self.id_map is not None:
            g.create_dataset("id_map", data=self.id_map, chunks=True, compression="gzip", compression_opts=1)
        if self.backend.startswith("flann"):
            fd, path = tempfile.mkstemp(suffix=".flann")
            os.close(fd)
            try:
                self.impl.save(path)
                with open(path, "rb") as fh:
                    blob = np.frombuffer(fh.read(), np.uint8)
            finally:
                os.unlink(path)
        else:
            blob = import_faiss().serialize_index(self.impl)
        g.create_dataset("blob", data=blob, chunks=True, compression="gzip", compression_opts=1)

    @classmethod
    def from_h5(cls, g: h5py.Group, data: np.ndarray, where: str = "index.h5") -> AnnIndex:
        backend = str(g.attrs["backend"])
        params = {k[6:]: (v.item() if hasattr(v, "item") else v) for k, v in g.attrs.items() if k.startswith("param_")}
        self = cls(backend, data, params, int(g.attrs["seed"]))
        if data_hash(self.data) != str(g.attrs["data_sha256"]):
            raise IndexMismatchError(f"{where}: the stored {backend} index was built over another dictionary; "
                              "re-run `placeloc index` (or `run --force`)")
        if backend == "bruteforce":
            self.norms = sq_norms(self.data)
            return self
        blob = np.asarray(g["blob"][()], np.uint8)
        if backend.startswith("flann"):
            fd, path = tempfile.mkstemp(suffix=".flann")
            os.close(fd)
            try:
                with open(path, "wb") as fh:
                    fh.write(blob.tobytes())
                self.impl = cv2.flann_Index()
                if not self.impl.load(self.data, path):
                    raise IndexMismatchError(f"{where}: the stored FLANN index could not be loaded; re-run `placeloc index`")
            finally:
                os.unlink(path)
        else:
            self.impl = import_faiss().deserialize_index(blob)
            if "id_map" in g:
                self.id_map = np.asarray(g["id_map"][()], np.int64)
            self._set_faiss_search()
        return self
