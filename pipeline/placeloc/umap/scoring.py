"""Scoring query line images against the rendered database (eq. (1) of the UMap paper,
read as intersection over union; see :func:`placeloc.umap.bits.iou_scores`)."""

from __future__ import annotations

import math

import numpy as np

from placeloc.umap.bits import best_iou, iou_scores


class Scorer:
    """Eq. (1) for one query frame against all (or some) database views.

    ``view_heading`` holds one entry per query line image of a frame: nan for a pinhole
    query (heading unknown: every database row is a candidate), or the heading each view of
    a panorama was cut at (only database rows of that heading are compared with it)."""

    def __init__(self, bits: np.ndarray, counts: np.ndarray, poses: np.ndarray, view_heading: np.ndarray, *,
                 pooled: np.ndarray | None = None, shape: tuple[int, int] | None = None) -> None:
        # pooled: the views' 8 x 8 cell images (placeloc.umap.bits.pool_or), shape: (height,
        # width) of a view; with both, a search over a whole group reads only views that can win
        self.bits, self.counts, self.poses = bits, counts, poses
        self.pooled, self.shape = pooled, shape
        self.view_heading = view_heading
        # rows of each cut-view heading (panoramas), or all rows (pinhole: heading unknown)
        self.groups = [np.flatnonzero(np.isclose(poses[:, 3] % 360, hd % 360)) if not math.isnan(hd) else np.arange(len(poses))
                       for hd in view_heading]

    def best(self, lines: np.ndarray, rows: np.ndarray | None = None) -> tuple[int, float]:
        """(row, score) of the best database view for one frame's line images ``lines``
        (one packed image per entry of ``view_heading``), among ``rows`` (None: all)."""
        best_i, best_s = -1, -1.0
        for v, group in enumerate(self.groups):
            if rows is None:
                cand = group
            elif len(group) == len(self.poses):
                cand = rows
            else:
                cand = np.intersect1d(group, rows, assume_unique=True)
            if cand.size == 0:
                continue
            if self.pooled is not None and self.shape is not None and cand.size > 4096:
                i, sc_best = best_iou(self.bits, self.counts, self.pooled, lines[v], *self.shape,
                                      rows=None if cand.size == len(self.poses) else cand)
            else:
                sc = iou_scores(self.bits, self.counts, lines[v], cand)
                k = int(np.argmax(sc))
                i, sc_best = int(cand[k]), float(sc[k])
            if sc_best > best_s:
                best_i, best_s = i, sc_best
        return best_i, best_s

    def scores(self, lines: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Score of each of ``rows``; a panorama's rows are compared with the view cut at
        their own heading (-1 for a row no view was cut for)."""
        if len(self.view_heading) == 1 and math.isnan(self.view_heading[0]):
            return iou_scores(self.bits, self.counts, lines[0], rows)
        sc = np.full(len(rows), -1.0)
        for v, hd in enumerate(self.view_heading):
            on = np.isclose(self.poses[rows, 3] % 360, hd % 360)
            if on.any():
                sc[on] = iou_scores(self.bits, self.counts, lines[v], rows[on])
        return sc

    def pick(self, lines: np.ndarray, rows: np.ndarray, pred: np.ndarray, *, tie_tol: float) -> tuple[int, float]:
        """Best-scoring row; rows scoring within ``tie_tol`` of the best are ties (a wall
        without doors looks the same from everywhere along it) and go to the one nearest the
        plan point ``pred``."""
        sc = self.scores(lines, rows)
        top = float(sc.max())
        tied = np.flatnonzero(sc >= top - tie_tol)
        j = tied[np.argmin(np.hypot(*(self.poses[rows[tied], :2] - pred).T))]
        return int(rows[j]), float(sc[j])
