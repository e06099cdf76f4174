"""Ground truth for place recognition between a reference and a query traverse.

Convention (as the difference matrix): ``block(r0, r1, q0, q1)`` is a boolean array with
rows = reference, columns = query, True where reference r is a correct match for query q.
Indices are the positions in the *original* (unfiltered) image lists, so images skipped
with ``on_error: skip`` do not shift the answer.

Kinds:
- ``synchronous``: r is correct for q when ``|r - q| <= tolerance``.
- ``csv``: either ``query,ref_first,ref_last`` (inclusive ranges) or ``query,reference``
  (one true reference; correct within ``tolerance`` of it). A query absent from the file
  has no correct reference.
- ``hdf5``: a boolean matrix (rows = reference, columns = query) in the first dataset of
  the file, or in the dataset named ``gt``.
"""

from __future__ import annotations

import csv
from pathlib import Path

import h5py
import numpy as np


class GroundTruthError(ValueError):
    pass


class GroundTruth:
    """Ground truth as a lazily evaluated boolean matrix (rows = reference, cols = query)."""

    def __init__(self, n_ref: int, n_query: int, *, tolerance: int = 0, lo: np.ndarray | None = None,
                 hi: np.ndarray | None = None, matrix: np.ndarray | None = None, synchronous: bool = False) -> None:
        self.n_ref, self.n_query = n_ref, n_query
        self.tolerance = int(tolerance)
        self.synchronous = synchronous
        self.lo, self.hi, self.matrix = lo, hi, matrix

    @classmethod
    def from_config(cls, section: dict, n_ref: int, n_query: int) -> GroundTruth:
        kind = section.get("kind", "none")
        tol = int(section.get("tolerance", 0) or 0)
        if kind == "synchronous":
            return cls(n_ref, n_query, tolerance=tol, synchronous=True)
        if kind == "csv":
            return cls.from_csv(section["path"], n_ref, n_query, tol)
        if kind == "hdf5":
            return cls.from_hdf5(section["path"], n_ref, n_query)
        raise GroundTruthError(f"ground_truth.kind {kind!r} cannot score place matches; use synchronous, csv or hdf5")

    @classmethod
    def from_csv(cls, path: str | Path, n_ref: int, n_query: int, tolerance: int = 0) -> GroundTruth:
        path = Path(path)
        with path.open(newline="") as fh:
            rows = list(csv.reader(fh))
        if not rows:
            raise GroundTruthError(f"{path}: empty ground-truth file")
        header = [h.strip().lower() for h in rows[0]]
        body = rows[1:] if not header[0].lstrip("-").isdigit() else rows
        if not header[0].lstrip("-").isdigit():
            ranges = header[:3] == ["query", "ref_first", "ref_last"]
            pairs = header[:2] == ["query", "reference"]
            if not (ranges or pairs):
                raise GroundTruthError(f"{path}: header must be 'query,ref_first,ref_last' or 'query,reference', got {rows[0]}")
        else:
            ranges = len(rows[0]) >= 3
        lo = np.full(n_query, 1, np.int64)
        hi = np.full(n_query, 0, np.int64)  # empty range: no correct reference
        for line_no, row in enumerate(body, start=2):
            try:
                q = int(row[0])
                if ranges:
                    a, b = int(row[1]), int(row[2])
                else:
                    a = b = int(row[1])
                    a, b = a - tolerance, b + tolerance
            except (ValueError, IndexError) as exc:
                raise GroundTruthError(f"{path}:{line_no}: cannot read {row!r} as integers ({exc})") from exc
            if 0 <= q < n_query:
                lo[q], hi[q] = a, b
        return cls(n_ref, n_query, lo=lo, hi=hi)

    @classmethod
    def from_hdf5(cls, path: str | Path, n_ref: int, n_query: int) -> GroundTruth:
        with h5py.File(path, "r") as f:
            names = [k for k in f if isinstance(f[k], h5py.Dataset)]
            if not names:
                raise GroundTruthError(f"{path}: no dataset found; store the boolean matrix as dataset 'gt'")
            m = np.asarray(f["gt" if "gt" in f else names[0]][()], dtype=bool)
        if m.shape != (n_ref, n_query):
            raise GroundTruthError(f"{path}: matrix is {m.shape}, expected (reference={n_ref}, query={n_query})")
        return cls(n_ref, n_query, matrix=m)

    def block(self, r0: int, r1: int, q0: int, q1: int) -> np.ndarray:
        return self.block_idx(np.arange(r0, r1), np.arange(q0, q1))

    def block_idx(self, r_idx: np.ndarray, q_idx: np.ndarray) -> np.ndarray:
        """Boolean (len(r_idx), len(q_idx)) block for arbitrary original indices."""
        r = np.asarray(r_idx)[:, None]
        q = np.asarray(q_idx)[None, :]
        if self.matrix is not None:
            return self.matrix[r, q]
        if self.synchronous:
            return np.abs(r - q) <= self.tolerance
        return (r >= self.lo[q]) & (r <= self.hi[q])

    def correct(self, query: np.ndarray, reference: np.ndarray) -> np.ndarray:
        """Elementwise: is ``reference[i]`` correct for ``query[i]`` (-1 = no match -> False)."""
        query = np.asarray(query)
        reference = np.asarray(reference)
        valid = reference >= 0
        out = np.zeros(np.broadcast(query, reference).shape, bool)
        q = np.broadcast_to(query, out.shape)
        r = np.broadcast_to(reference, out.shape)
        if self.matrix is not None:
            rr = np.where(valid, r, 0)
            out = self.matrix[rr, q] & valid
        elif self.synchronous:
            out = (np.abs(r - q) <= self.tolerance) & valid
        else:
            out = (r >= self.lo[q]) & (r <= self.hi[q]) & valid
        return out

    def has_match(self) -> np.ndarray:
        """Per query: does any reference count as correct?"""
        if self.matrix is not None:
            return self.matrix.any(axis=0)
        if self.synchronous:
            q = np.arange(self.n_query)
            return (q - self.tolerance <= self.n_ref - 1) & (q + self.tolerance >= 0)
        return (self.hi >= self.lo) & (self.hi >= 0) & (self.lo <= self.n_ref - 1)
