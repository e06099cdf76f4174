"""Observation matrices with missing entries: read, validate, store.

An observation matrix has one row per time step and one column per feature; entry (t, i)
is a k-vector (k = 1 for a bearing, a range or a horizontal image coordinate; k = 2 for
an image point). In memory and on disk it is CSR: ``indptr`` (M+1), ``indices`` (nnz
feature columns) and ``values`` (nnz x k). The sparsity pattern *is* the mask q_{t,i}:
an explicit 0.0 is a real observation (a bearing straight ahead), so the mask is never
inferred from the values.
"""

from __future__ import annotations

import csv
from array import array
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import scipy.sparse as sp


class ObservationError(ValueError):
    """Input that cannot form an observation matrix; the message names the fix."""


@dataclass
class Observations:
    """Sparse observation matrix: row r is time step ``step_ids[r]``, column c feature ``feature_ids[c]``."""

    indptr: np.ndarray      # (M+1,) int64
    indices: np.ndarray     # (nnz,) int64 column of each observation
    values: np.ndarray      # (nnz, k) float64
    step_ids: np.ndarray    # (M,) int64
    feature_ids: np.ndarray  # (N,) int64

    @property
    def n_steps(self) -> int:
        return len(self.step_ids)

    @property
    def n_features(self) -> int:
        return len(self.feature_ids)

    @property
    def value_dim(self) -> int:
        return self.values.shape[1]

    @property
    def nnz(self) -> int:
        return len(self.indices)

    @property
    def rows(self) -> np.ndarray:
        """Row (time step index) of every observation."""
        return np.repeat(np.arange(self.n_steps), np.diff(self.indptr))

    def mask(self) -> sp.csr_matrix:
        """q_{t,i} as a boolean CSR matrix (M x N)."""
        return sp.csr_matrix((np.ones(self.nnz, bool), self.indices, self.indptr), shape=(self.n_steps, self.n_features))

    def component(self, a: int) -> sp.csr_matrix:
        """Value component ``a`` as CSR (M x N); zeros inside the mask are kept as explicit entries."""
        return sp.csr_matrix((self.values[:, a].copy(), self.indices, self.indptr), shape=(self.n_steps, self.n_features))

    def columns_of(self, ids: np.ndarray | list[int], what: str = "feature") -> np.ndarray:
        """Column index of each feature id; an id never observed is an error naming it."""
        ids = np.asarray(ids, dtype=np.int64)
        pos = np.searchsorted(self.feature_ids, ids)
        pos = np.clip(pos, 0, max(self.n_features - 1, 0))
        bad = ids[(self.n_features == 0) | (self.feature_ids[pos] != ids)]
        if bad.size:
            raise ObservationError(f"{what} id(s) {bad[:10].tolist()} never appear in the observations "
                                   "(unknown id, or a feature that is never observed); check the ids or the observation file")
        return pos


def from_triplets(steps: np.ndarray, features: np.ndarray, values: np.ndarray) -> Observations:
    """Build the CSR matrix from long-form triplets; a (step, feature) pair given twice is an error."""
    steps = np.asarray(steps, dtype=np.int64)
    features = np.asarray(features, dtype=np.int64)
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 1:
        values = values[:, None]
    if not (len(steps) == len(features) == len(values)):
        raise ObservationError("steps, features and values must have the same length")
    if len(steps) == 0:
        raise ObservationError("the observation matrix is empty: no (step, feature, value) rows")
    if not np.all(np.isfinite(values)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(values), axis=1))[0])
        raise ObservationError(f"observation of feature {features[bad]} at step {steps[bad]} is not a finite number; "
                               "leave missing observations out instead of writing NaN")
    step_ids, rows = np.unique(steps, return_inverse=True)
    feature_ids, cols = np.unique(features, return_inverse=True)
    order = np.lexsort((cols, rows))
    rows, cols, values = rows[order], cols[order], values[order]
    dup = (np.diff(rows) == 0) & (np.diff(cols) == 0)
    if dup.any():
        j = int(np.flatnonzero(dup)[0])
        raise ObservationError(f"feature {feature_ids[cols[j]]} is observed twice at step {step_ids[rows[j]]}; "
                               "each (step, feature) pair may appear once")
    indptr = np.zeros(len(step_ids) + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=len(step_ids)), out=indptr[1:])
    return Observations(indptr, cols.astype(np.int64), values, step_ids.astype(np.int64), feature_ids.astype(np.int64))


def _read_numeric_csv(path: str | Path, min_cols: int, what: str) -> tuple[list[str], np.ndarray]:
    """A header row, then rows of numbers, as many as the header names. A bad row is named
    by its line in the file (counting the header and blank lines), as an editor shows it."""
    path = Path(path)
    if not path.is_file():
        raise ObservationError(f"{what}: {path} does not exist")
    with path.open(newline="", encoding="utf-8-sig") as fh:  # a BOM is not part of the header
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None or len(header) < min_cols:
            from placeloc.core.safe_io import separator_hint

            raise ObservationError(f"{what}: {path} needs a header row with at least {min_cols} columns"
                                   f"{separator_hint(header or [])}")
        values = array("d")  # 8 bytes a number: a list of float rows would take ~6x the memory
        for row in reader:
            if not any(field.strip() for field in row) or row[0].lstrip().startswith("#"):
                continue  # blank lines and comments, as numpy.loadtxt skipped them
            if len(row) != len(header):
                raise ObservationError(f"{what}: {path} line {reader.line_num} has {len(row)} fields but the header "
                                       f"names {len(header)} ({', '.join(h.strip() for h in header)}); fix that line")
            try:
                values.extend(float(field) for field in row)
            except ValueError:
                bad = next(field for field in row if not _is_number(field))
                raise ObservationError(f"{what}: {path} line {reader.line_num}: {bad.strip()!r} is not a number; every "
                                       "field after the header must be one") from None
    data = np.frombuffer(values, np.float64).reshape(-1, len(header)) if values else np.zeros((0, len(header)))
    return [h.strip() for h in header], data


def _is_number(field: str) -> bool:
    try:
        float(field)
    except ValueError:
        return False
    return True


def _ids(col: np.ndarray, path: str | Path, what: str) -> np.ndarray:
    if not np.all(col == np.round(col)):
        raise ObservationError(f"{what}: {path}: the id column must hold integers")
    return col.astype(np.int64)


def read_observations_csv(path: str | Path) -> Observations:
    """Long form ``t,feature,value[,value2...]`` (any header names; order of columns matters)."""
    _, data = _read_numeric_csv(path, 3, "observations")
    return from_triplets(_ids(data[:, 0], path, "observations"), _ids(data[:, 1], path, "observations"), data[:, 2:])


def read_points_csv(path: str | Path, what: str = "landmarks") -> tuple[np.ndarray, np.ndarray]:
    """``feature,x,y[,z]``: ids (n,) and coordinates (n, d)."""
    _, data = _read_numeric_csv(path, 3, what)
    ids = _ids(data[:, 0], path, what)
    if len(np.unique(ids)) != len(ids):
        raise ObservationError(f"{what}: {path} lists a feature id twice")
    return ids, data[:, 1:]


def poses_by_step(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Poses keyed by integer step (via the one pose reader, :func:`placeloc.evaluation.poses.read_poses`).

    Returns step ids (sorted), positions (n, 2) and headings in radians (or None).
    """
    from placeloc.evaluation.poses import PoseError, read_poses

    poses = read_poses(path)
    if poses.frames is None:
        raise PoseError(f"poses: {path}: the step column must hold integer time steps (the observation file's t)")
    order = np.argsort(poses.frames, kind="stable")
    heading = None if poses.heading is None else poses.heading[order]
    return poses.frames[order], poses.xy[order], heading


def write_observations(group: h5py.Group, obs: Observations) -> None:
    """CSR arrays; the pattern (indptr, indices) is the mask."""
    group.create_dataset("indptr", data=obs.indptr)
    group.create_dataset("indices", data=obs.indices, chunks=True if obs.nnz > 65536 else None,
                         compression="gzip" if obs.nnz > 65536 else None)
    group.create_dataset("values", data=obs.values, chunks=True if obs.nnz > 65536 else None,
                         compression="gzip" if obs.nnz > 65536 else None)
    group.create_dataset("step_ids", data=obs.step_ids)
    group.create_dataset("feature_ids", data=obs.feature_ids)
    group.attrs["shape"] = (obs.n_steps, obs.n_features)
    group.attrs["value_dim"] = obs.value_dim
    group.attrs["fill"] = obs.nnz / max(obs.n_steps * obs.n_features, 1)
    group.attrs["mask"] = "the CSR pattern (indptr, indices) is the mask q; explicit zeros are observations"


def read_observations(group: h5py.Group) -> Observations:
    return Observations(group["indptr"][()], group["indices"][()], group["values"][()],
                        group["step_ids"][()], group["feature_ids"][()])
