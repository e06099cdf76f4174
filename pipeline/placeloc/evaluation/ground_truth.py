"""Ground truth for place recognition between a reference and a query traverse.

Convention (as the difference matrix): ``block(r0, r1, q0, q1)`` is a boolean array with
rows = reference, columns = query, True where reference r is a correct match (a
*positive*) for query q. Indices are the positions in the *original* (unfiltered) image
lists, in the folder's natural order from 0, so images skipped with ``on_error: skip`` do
not shift the answer.

Kinds (``ground_truth.kind``):

- ``synchronous``: r is correct for q when ``|r - q| <= tolerance``.
- ``csv``: a CSV with a header, one row per positive:

  * ``query,reference``: reference is a positive for query, and so is every reference
    within ``tolerance`` of it. Several rows per query give several positives (all count).
  * ``query,ref_first,ref_last``: the inclusive range is positive (``tolerance`` is not
    added); several rows per query add ranges.

  Each query/reference cell is an index (0-based, natural order) or an image **file
  name** from the folder. An optional ``soft`` column (1/true/yes) marks a row as *soft*:
  those references are neither required nor counted wrong (the GThard/GTsoft convention
  of Schubert, Neubert, Garg, Milford and Fischer, "Visual place recognition: a tutorial",
  IEEE RAM 2023). A query absent from the file has no positive.
- ``hdf5``: a boolean (or 0/1 integer) matrix, rows = reference, columns = query, in the
  dataset ``gt`` (or ``GThard``, or the only dataset); an optional soft matrix in
  ``gt_soft`` or ``GTsoft``. A ``.npz`` file with ``GThard``/``GTsoft`` (the tutorial's
  format) is read the same way.
- ``poses``: positions in metres; r is a positive for q when they are at most
  ``radius`` metres apart (25 m is the convention of VPR-Bench and of Berton et al.'s
  VPR-methods-evaluation). ``path`` is a positions CSV read by
  :func:`placeloc.evaluation.poses.read_poses` (x/y, UTM easting/northing or WGS84 lat/lon,
  keyed by frame number or image name, with a ``traverse`` column when one file holds
  both traverses), or a **folder**: then each image's position is read from its file
  name, ``@UTM_east@UTM_north@...@.jpg``, as pitts30k and MSLS name them in that format.

Soft ground truth: ``soft_only(q, r)`` is True where r is in the soft set but not a hard
positive. Metrics drop such candidates from a ranking before scoring it.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from placeloc.core.common_params import GroundTruthParams
from placeloc.core.errors import ConfigError
from placeloc.core.safe_io import UnsafeInputError, load_arrays, read_input_text

# The shared defaults (one home: placeloc.core.common_params), for callers that pass no config section.
DEFAULT_RADIUS_M: float = GroundTruthParams().radius
DEFAULT_TOLERANCE: int = GroundTruthParams().tolerance
TRUE_WORDS = {"1", "true", "yes", "y", "soft"}
FALSE_WORDS = {"", "0", "false", "no", "n", "hard"}


class GroundTruthError(ConfigError):
    """A ground-truth file or setting is wrong; the message names the file, row and fix."""


def _is_int(text: str) -> bool:
    t = text.strip()
    return bool(t) and t.lstrip("-").isdigit()


class GroundTruth:
    """Ground truth as a lazily evaluated boolean matrix (rows = reference, cols = query).

    Exactly one form is held: ``synchronous`` (``|r - q| <= tolerance``), merged
    inclusive reference ``intervals`` per query, a dense ``matrix``, or ``positions``
    (reference and query coordinates in metres with a ``radius``). ``soft`` (optional) is
    a second GroundTruth over the same pair holding the soft set (a superset of this one).
    """

    def __init__(self, n_ref: int, n_query: int, *, tolerance: int = DEFAULT_TOLERANCE, lo: np.ndarray | None = None,
                 hi: np.ndarray | None = None, matrix: np.ndarray | None = None, synchronous: bool = False,
                 intervals: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                 ref_xy: np.ndarray | None = None, query_xy: np.ndarray | None = None, radius: float | None = None,
                 soft: GroundTruth | None = None) -> None:
        self.n_ref, self.n_query = int(n_ref), int(n_query)
        self.tolerance = int(tolerance)
        self.synchronous = synchronous
        self.matrix = matrix
        self.ref_xy, self.query_xy, self.radius = ref_xy, query_xy, radius
        self.soft = soft
        self.iv: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        if lo is not None and hi is not None:
            intervals = (np.arange(len(lo)), np.asarray(lo), np.asarray(hi))
        if intervals is not None:
            self.iv = _merge_intervals(*intervals, n_ref=self.n_ref)

    @property
    def form(self) -> str:
        if self.matrix is not None:
            return "matrix"
        if self.synchronous:
            return "synchronous"
        if self.ref_xy is not None:
            return "positions"
        return "intervals"

    # ------------------------------------------------------------------ readers
    @classmethod
    def from_config(cls, section: dict, n_ref: int, n_query: int, *, ref_names: Sequence[str] | None = None,
                    query_names: Sequence[str] | None = None) -> GroundTruth:
        """Build from the ``ground_truth`` config section. ``ref_names``/``query_names``
        are the file names of the listed images (needed for names and positions)."""
        kind = section.get("kind", "none")
        tol = section.get("tolerance", DEFAULT_TOLERANCE)
        tol = 0 if tol is None else tol
        if int(tol) < 0:
            raise GroundTruthError(f"ground_truth.tolerance is {tol}; it must be >= 0 (frames either side of a "
                                   "listed reference that also count), e.g. ground_truth.tolerance: 2")
        tol = int(tol)
        if kind == "synchronous":
            return cls(n_ref, n_query, tolerance=tol, synchronous=True)
        if kind == "csv":
            # loop closure (no query folder): the queries are the reference images
            q_names = query_names if query_names is not None or n_query != n_ref else ref_names
            return cls.from_csv(section["path"], n_ref, n_query, tol, ref_names=ref_names, query_names=q_names)
        if kind == "hdf5":
            return cls.from_hdf5(section["path"], n_ref, n_query)
        if kind == "poses":
            radius = section.get("radius")
            return cls.from_positions(section["path"], n_ref, n_query, radius=DEFAULT_RADIUS_M if radius is None else radius,
                                      ref_names=ref_names, query_names=query_names)
        raise GroundTruthError(f"ground_truth.kind {kind!r} cannot score place matches; use synchronous, csv, hdf5 or poses")

    @classmethod
    def from_csv(cls, path: str | Path, n_ref: int, n_query: int, tolerance: int = DEFAULT_TOLERANCE, *,
                 ref_names: Sequence[str] | None = None, query_names: Sequence[str] | None = None) -> GroundTruth:
        """Pairs or ranges, by index or file name, several rows per query (module docstring)."""
        path = Path(path)
        try:
            text = read_input_text(path, "ground_truth.path")
            rows = [r for r in csv.reader(io.StringIO(text, newline="")) if any(c.strip() for c in r)]
        except UnsafeInputError as exc:
            raise GroundTruthError(str(exc)) from None
        except (OSError, csv.Error) as exc:
            raise GroundTruthError(f"ground_truth.path: {path} cannot be read as a CSV file ({exc})") from None
        if not rows:
            raise GroundTruthError(f"{path}: empty ground-truth file; write a header 'query,reference' and one row per pair")
        head = [h.strip().lower() for h in rows[0]]
        if _is_int(head[0]):  # no header: 2 columns = pairs, 3 = ranges (indices only)
            cols = {"query": 0, "reference": 1} if len(rows[0]) == 2 else {"query": 0, "ref_first": 1, "ref_last": 2}
            body, first_line = rows, 1
        else:
            cols = {h: i for i, h in enumerate(head)}
            body, first_line = rows[1:], 2
        ranges = "ref_first" in cols and "ref_last" in cols
        if "query" not in cols or not (ranges or "reference" in cols):
            from placeloc.core.safe_io import separator_hint

            raise GroundTruthError(f"{path}:1: header must be 'query,reference' (pairs) or 'query,ref_first,ref_last' "
                                   f"(ranges), optionally with a 'soft' column; got {rows[0]}{separator_hint(rows[0])}")
        q_lookup = _Lookup(query_names, n_query, "query", path)
        r_lookup = _Lookup(ref_names, n_ref, "reference", path)
        soft_col = cols.get("soft")
        hard: list[tuple[int, int, int]] = []
        soft: list[tuple[int, int, int]] = []
        for line_no, row in enumerate(body, start=first_line):
            need = max(cols["query"], *(cols[c] for c in (("ref_first", "ref_last") if ranges else ("reference",))))
            if len(row) <= need:
                raise GroundTruthError(f"{path}:{line_no}: expected {need + 1} columns, got {row!r}")
            q = q_lookup(row[cols["query"]], line_no)
            if ranges:
                a, b = r_lookup.bound(row[cols["ref_first"]], line_no), r_lookup.bound(row[cols["ref_last"]], line_no)
                if a > b:
                    raise GroundTruthError(f"{path}:{line_no}: ref_first {a} > ref_last {b}; swap them")
                if b < 0 or a > n_ref - 1:
                    raise GroundTruthError(f"{path}:{line_no}: range {a}..{b} lies outside the reference traverse "
                                           f"(0..{n_ref - 1}); indices count the folder's images in natural order from 0")
            else:
                r = r_lookup(row[cols["reference"]], line_no)
                a, b = r - tolerance, r + tolerance
            is_soft = False
            if soft_col is not None and soft_col < len(row):
                word = row[soft_col].strip().lower()
                if word not in TRUE_WORDS | FALSE_WORDS:
                    raise GroundTruthError(f"{path}:{line_no}: soft is {row[soft_col]!r}; write 1 (soft) or 0 (hard)")
                is_soft = word in TRUE_WORDS
            (soft if is_soft else hard).append((q, a, b))
        if not hard:
            raise GroundTruthError(f"{path}: no (hard) positive listed; add rows 'query,reference'")
        hq, ha, hb = (np.array(c, np.int64) for c in zip(*hard))
        soft_gt = None
        if soft:
            sq, sa, sb = (np.array(c, np.int64) for c in zip(*soft))
            soft_gt = cls(n_ref, n_query, intervals=(np.r_[hq, sq], np.r_[ha, sa], np.r_[hb, sb]))
        return cls(n_ref, n_query, intervals=(hq, ha, hb), soft=soft_gt)

    @classmethod
    def from_hdf5(cls, path: str | Path, n_ref: int, n_query: int) -> GroundTruth:
        """A boolean or 0/1 matrix (rows = reference); ``.npz`` as the tutorial's GThard/GTsoft."""
        path = Path(path)
        hard_names, soft_names = ("gt", "GThard", "gt_hard"), ("gt_soft", "GTsoft")
        # The matrix is n_ref x n_query: no array of the file may need more than that at 8 bytes
        # an element, checked from its header before it is read.
        budget = max(n_ref * n_query * 8, 1 << 16)
        try:
            arrays = load_arrays(path, "ground_truth.path", budget, kind=".npz" if path.suffix.lower() == ".npz" else ".h5")
        except UnsafeInputError as exc:
            raise GroundTruthError(str(exc)) from None
        if not arrays:
            raise GroundTruthError(f"{path}: no dataset found; store the boolean matrix as dataset 'gt'")
        hard_key = next((k for k in hard_names if k in arrays), None)
        others = [k for k in arrays if k not in soft_names]
        if hard_key is None:
            if len(others) != 1:
                raise GroundTruthError(f"{path}: datasets {sorted(arrays)}; name the matrix 'gt' (and a soft one 'gt_soft')")
            hard_key = others[0]
        hard = _bool_matrix(arrays[hard_key], path, hard_key, n_ref, n_query)
        soft_key = next((k for k in soft_names if k in arrays), None)
        soft = None
        if soft_key is not None:
            soft = cls(n_ref, n_query, matrix=_bool_matrix(arrays[soft_key], path, soft_key, n_ref, n_query) | hard)
        return cls(n_ref, n_query, matrix=hard, soft=soft)

    @classmethod
    def from_positions(cls, path: str | Path, n_ref: int, n_query: int, *, radius: float,
                       ref_names: Sequence[str] | None = None, query_names: Sequence[str] | None = None,
                       loop_closure: bool | None = None) -> GroundTruth:
        """Positions within ``radius`` metres (module docstring). ``query_names`` None and
        ``n_query == n_ref`` with ``loop_closure`` means the query traverse is the reference."""
        from placeloc.evaluation.poses import PoseError, positions_from_names, read_poses

        path = Path(path)
        if not radius or radius <= 0:
            raise GroundTruthError(f"ground_truth.radius is {radius}; give the match radius in metres (> 0), "
                                   f"e.g. ground_truth.radius: {DEFAULT_RADIUS_M:g}")
        if loop_closure is None:
            loop_closure = query_names is None and n_query == n_ref
        try:
            if path.is_dir():
                if ref_names is None:
                    raise GroundTruthError(f"ground_truth.path {path} is a folder: positions come from image file names, "
                                           "but no image names were given")
                ref_xy = positions_from_names(ref_names, what="reference images")
                q_xy = ref_xy if loop_closure else positions_from_names(query_names or [], what="query images")
            else:
                poses = read_poses(path, what="ground_truth.path")
                ref_xy, q_xy = _traverse_positions(poses, n_ref, n_query, ref_names, query_names, loop_closure)
        except PoseError as exc:
            raise GroundTruthError(str(exc)) from None
        if len(ref_xy) != n_ref or len(q_xy) != n_query:
            raise GroundTruthError(f"{path}: got {len(ref_xy)} reference and {len(q_xy)} query positions for "
                                   f"{n_ref} and {n_query} images; give one position per image")
        return cls(n_ref, n_query, ref_xy=np.asarray(ref_xy, np.float64), query_xy=np.asarray(q_xy, np.float64),
                   radius=float(radius))

    # ------------------------------------------------------------------ queries
    def block(self, r0: int, r1: int, q0: int, q1: int) -> np.ndarray:
        return self.block_idx(np.arange(r0, r1), np.arange(q0, q1))

    def block_idx(self, r_idx: np.ndarray, q_idx: np.ndarray) -> np.ndarray:
        """Boolean (len(r_idx), len(q_idx)) block for arbitrary original indices."""
        return self.correct(np.asarray(q_idx)[None, :], np.asarray(r_idx)[:, None])

    def correct(self, query: np.ndarray, reference: np.ndarray) -> np.ndarray:
        """Elementwise (broadcast): is ``reference`` a positive for ``query`` (-1 = no match -> False)."""
        q, r = np.broadcast_arrays(np.asarray(query, np.int64), np.asarray(reference, np.int64))
        valid = (r >= 0) & (r < self.n_ref) & (q >= 0) & (q < self.n_query)
        rr, qq = np.where(valid, r, 0), np.where(valid, q, 0)
        if self.matrix is not None:
            out = self.matrix[rr, qq]
        elif self.synchronous:
            out = np.abs(rr - qq) <= self.tolerance
        elif self.ref_xy is not None:
            d = self.ref_xy[rr] - self.query_xy[qq]
            out = np.hypot(d[..., 0], d[..., 1]) <= self.radius
        else:
            iq, ilo, ihi = self.iv
            width = self.n_ref + 1
            i = np.searchsorted(iq * width + ilo, qq * width + rr, side="right") - 1
            ic = np.clip(i, 0, max(len(iq) - 1, 0))
            out = (i >= 0) & (iq[ic] == qq) & (ihi[ic] >= rr) if len(iq) else np.zeros(q.shape, bool)
        return out & valid

    def soft_only(self, query: np.ndarray, reference: np.ndarray) -> np.ndarray:
        """Elementwise: in the soft set but not a hard positive (neither right nor wrong)."""
        if self.soft is None:
            return np.zeros(np.broadcast(np.asarray(query), np.asarray(reference)).shape, bool)
        return self.soft.correct(query, reference) & ~self.correct(query, reference)

    def has_match(self) -> np.ndarray:
        """Per query: does any reference count as correct?"""
        return self.example_positive() >= 0

    def example_positive(self) -> np.ndarray:
        """Per query, one positive reference (-1 if none): the middle of the first range,
        the nearest reference by position, the first of the matrix, or the query's own
        index (synchronous)."""
        q = np.arange(self.n_query)
        if self.matrix is not None:
            return np.where(self.matrix.any(axis=0), np.argmax(self.matrix, axis=0), -1)
        if self.synchronous:
            r = np.clip(q, 0, self.n_ref - 1)
            return np.where(np.abs(r - q) <= self.tolerance, r, -1)
        if self.ref_xy is not None:
            best, dist = _nearest(self.ref_xy, self.query_xy)
            return np.where(dist <= self.radius, best, -1)
        iq, ilo, ihi = self.iv
        out = np.full(self.n_query, -1, np.int64)
        first = np.r_[True, iq[1:] != iq[:-1]] if len(iq) else np.zeros(0, bool)
        out[iq[first]] = (ilo[first] + ihi[first]) // 2
        return out

    def positives(self, r_idx: np.ndarray, q_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The positive pairs among the references ``r_idx`` and queries ``q_idx`` (original
        indices) as (row, column) positions in them, sorted by column, then row: the
        nonzeros of ``block_idx(r_idx, q_idx)``, found without building that n_ref x n_query
        block where the truth is a band, ranges or positions (a few positives per query).
        Every pair is confirmed by :meth:`correct`, so both always agree."""
        r_idx, q_idx = np.asarray(r_idx, np.int64), np.asarray(q_idx, np.int64)
        if self.matrix is not None:
            cols, rows = np.nonzero(self.block_idx(r_idx, q_idx).T)
            return rows.astype(np.int64), cols.astype(np.int64)
        col_of_query = np.full(self.n_query, -1, np.int64)
        q_ok = (q_idx >= 0) & (q_idx < self.n_query)
        col_of_query[q_idx[q_ok]] = np.flatnonzero(q_ok)
        # candidates: (column position, original reference), a superset of the positives
        if self.synchronous:
            offsets = np.arange(-self.tolerance, self.tolerance + 1, dtype=np.int64)
            cols = np.repeat(np.arange(len(q_idx), dtype=np.int64), len(offsets))
            refs = (q_idx[:, None] + offsets[None, :]).ravel()
        elif self.ref_xy is not None:
            from scipy.spatial import cKDTree

            cols_ok = np.flatnonzero(q_ok)
            # a hair wider than the radius: the tree's distance may round differently from
            # correct()'s hypot; correct() below decides
            near = cKDTree(self.ref_xy).query_ball_point(self.query_xy[q_idx[cols_ok]], r=float(self.radius) * (1 + 1e-9),
                                                         return_sorted=False) if len(cols_ok) and len(self.ref_xy) else []
            counts = np.fromiter((len(n) for n in near), np.int64, len(near))
            cols = np.repeat(cols_ok, counts)
            refs = np.fromiter((r for n in near for r in n), np.int64, int(counts.sum()))
        else:
            assert self.iv is not None
            iq, ilo, ihi = self.iv
            inside = iq < self.n_query
            col = np.where(inside, col_of_query[np.where(inside, iq, 0)], -1)
            keep = col >= 0
            col, lo, hi = col[keep], ilo[keep], ihi[keep]
            counts = hi - lo + 1
            cols = np.repeat(col, counts)
            starts = np.repeat(lo - np.r_[0, np.cumsum(counts)[:-1]], counts)
            refs = starts + np.arange(int(counts.sum()), dtype=np.int64)
        row_of_ref = np.full(self.n_ref, -1, np.int64)
        r_ok = (r_idx >= 0) & (r_idx < self.n_ref)
        row_of_ref[r_idx[r_ok]] = np.flatnonzero(r_ok)
        valid = (refs >= 0) & (refs < self.n_ref)
        cols, refs = cols[valid], refs[valid]
        rows = row_of_ref[refs]
        keep = rows >= 0
        cols, refs, rows = cols[keep], refs[keep], rows[keep]
        keep = self.correct(q_idx[cols], refs)
        cols, rows = cols[keep], rows[keep]
        key = np.sort(cols * max(len(r_idx), 1) + rows)
        key = key[np.r_[True, key[1:] != key[:-1]]] if len(key) else key  # np.unique would import numpy.ma (20 ms)
        return key % max(len(r_idx), 1), key // max(len(r_idx), 1)

    def band(self, r_idx: np.ndarray, q_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First and last row (positions in ``r_idx``) that are positive for each query in
        ``q_idx`` (lo > hi where none): the band drawn under a difference matrix."""
        return band_of(*self.positives(r_idx, q_idx), len(q_idx))


def band_of(rows: np.ndarray, cols: np.ndarray, n_cols: int) -> tuple[np.ndarray, np.ndarray]:
    """Per column of ``n_cols``, the first and last of the positive pairs' rows (1 and 0,
    lo > hi, where a column has none)."""
    lo, hi = np.full(n_cols, np.iinfo(np.int64).max, np.int64), np.full(n_cols, -1, np.int64)
    np.minimum.at(lo, cols, rows)
    np.maximum.at(hi, cols, rows)
    none = hi < 0
    lo[none], hi[none] = 1, 0
    return lo, hi


# ---------------------------------------------------------------------- helpers
class _Lookup:
    """A CSV cell -> index: an integer index checked against the traverse, or a file name."""

    def __init__(self, names: Sequence[str] | None, n: int, role: str, path: Path) -> None:
        self.n, self.role, self.path = n, role, path
        self.names = names
        self.index: dict[str, int] | None = None

    def bound(self, cell: str, line: int) -> int:
        """A range end: an index may reach past the end of the traverse (the range is
        clipped there); a negative one is refused, as a negative index is."""
        if _is_int(cell) and int(cell.strip()) < 0:
            raise GroundTruthError(f"{self.path}:{line}: {self.role} index {int(cell.strip())} is negative; indices count "
                                   "the folder's images in natural order from 0")
        return int(cell.strip()) if _is_int(cell) else self(cell, line)

    def __call__(self, cell: str, line: int) -> int:
        text = cell.strip()
        if _is_int(text):
            i = int(text)
            if not 0 <= i < self.n:
                raise GroundTruthError(f"{self.path}:{line}: {self.role} index {i} is outside the {self.role} traverse "
                                       f"(0..{self.n - 1}); indices count the folder's images in natural order from 0")
            return i
        if self.names is None:
            raise GroundTruthError(f"{self.path}:{line}: {self.role} {text!r} is not an index and the image names are not "
                                   "known here; use indices")
        if self.index is None:
            self.index = {}
            for i, name in enumerate(self.names):
                self.index.setdefault(Path(name).name, i)
        i = self.index.get(Path(text).name, -1)
        if i < 0:
            raise GroundTruthError(f"{self.path}:{line}: {self.role} image {text!r} is not in the {self.role} folder; "
                                   "fix the file name (or use the 0-based index)")
        return i


def _merge_intervals(q: np.ndarray, lo: np.ndarray, hi: np.ndarray, *, n_ref: int) -> tuple[np.ndarray, ...]:
    """Clip to the traverse, drop empty ones, sort by (query, lo) and merge overlaps, so
    that a binary search finds the one interval that can hold a reference."""
    q, lo, hi = (np.asarray(a, np.int64) for a in (q, lo, hi))
    lo, hi = np.maximum(lo, 0), np.minimum(hi, n_ref - 1)
    keep = lo <= hi
    q, lo, hi = q[keep], lo[keep], hi[keep]
    order = np.lexsort((lo, q))
    q, lo, hi = q[order], lo[order], hi[order]
    out_q: list[int] = []
    out_lo: list[int] = []
    out_hi: list[int] = []
    for a, b, c in zip(q.tolist(), lo.tolist(), hi.tolist()):
        if out_q and out_q[-1] == a and b <= out_hi[-1] + 1:
            out_hi[-1] = max(out_hi[-1], c)
        else:
            out_q.append(a)
            out_lo.append(b)
            out_hi.append(c)
    return np.array(out_q, np.int64), np.array(out_lo, np.int64), np.array(out_hi, np.int64)


def _bool_matrix(m: np.ndarray, path: Path, name: str, n_ref: int, n_query: int) -> np.ndarray:
    m = np.asarray(m)
    if m.dtype != bool:
        if not np.issubdtype(m.dtype, np.integer):
            raise GroundTruthError(f"{path}: dataset {name!r} holds {m.dtype} values; store a boolean (or 0/1 integer) "
                                   "matrix, e.g. (distance <= radius), not scores or distances")
        bad = (m != 0) & (m != 1)
        if bad.any():
            r, q = np.argwhere(bad)[0]
            raise GroundTruthError(f"{path}: dataset {name!r} has value {m[r, q]} at (reference {r}, query {q}); "
                                   "store 0/1 or booleans")
        m = m.astype(bool)
    if m.shape != (n_ref, n_query):
        hint = " (transposed? rows must be reference images)" if m.shape == (n_query, n_ref) else ""
        raise GroundTruthError(f"{path}: dataset {name!r} is {m.shape}, expected (reference={n_ref}, query={n_query}){hint}")
    return m


def _nearest(ref_xy: np.ndarray, q_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from scipy.spatial import cKDTree

    if len(ref_xy) == 0:
        return np.full(len(q_xy), -1, np.int64), np.full(len(q_xy), np.inf)
    dist, idx = cKDTree(ref_xy).query(q_xy, k=1)
    return np.asarray(idx, np.int64), np.asarray(dist, np.float64)


def _traverse_positions(poses: Any, n_ref: int, n_query: int, ref_names: Sequence[str] | None,
                        query_names: Sequence[str] | None, loop_closure: bool) -> tuple[np.ndarray, np.ndarray]:
    """Reference and query positions from one pose file (frames or names, traverse column)."""
    from placeloc.evaluation.poses import PoseError

    by_names = poses.frames is None
    two = poses.traverse is not None
    if not loop_closure and not two and not by_names:
        raise PoseError(f"{poses.path}: frame numbers cannot say which traverse a row belongs to; add a traverse column "
                        "(reference/query) or key the rows by image file name")

    def rows(names: Sequence[str] | None, n: int, role: str) -> np.ndarray:
        trav = role if two and not loop_closure else (role if two and role in set(poses.traverse) else None)
        if by_names:
            if names is None:
                raise PoseError(f"{poses.path}: rows are keyed by image name but the {role} image names are not known")
            return poses.rows_for_names(names, what=f"{role} images", traverse=trav)
        return poses.rows_for_frames(n, what=f"{role} frames", traverse=trav)

    ref_xy = poses.xy[rows(ref_names, n_ref, "reference")]
    q_xy = ref_xy if loop_closure else poses.xy[rows(query_names, n_query, "query")]
    return ref_xy, q_xy
