"""Place-recognition metrics, as the field uses them.

Inputs are per query: the ranked candidate references (``-1`` = none), a confidence for
the top candidate (higher = more sure) and whether each candidate is correct.

- Recall@K: queries with a correct reference among their K best, over *all* queries; a
  query with no match (too early for a full sequence, say) is a miss.
- Precision-recall: one point per distinct confidence threshold ``c``; the queries with
  ``confidence >= c`` (and a match) are accepted; precision = correct accepted / accepted,
  recall = correct accepted / all queries.
- AUC: area under the PR curve by the trapezoid rule over recall, starting at recall 0
  with the precision of the first (most confident) point.
- Recall at 100 % precision: the largest recall of a point with precision 1 (0 if none).
- Max F1 over the points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from placeloc.core.common_params import GroundTruthParams


@dataclass
class PRCurve:
    thresholds: np.ndarray  # descending
    precision: np.ndarray
    recall: np.ndarray

    @property
    def auc(self) -> float:
        if self.recall.size == 0:
            return 0.0
        r = np.concatenate([[0.0], self.recall])
        p = np.concatenate([[self.precision[0]], self.precision])
        return float(np.sum(np.diff(r) * (p[1:] + p[:-1]) * 0.5))

    @property
    def recall_at_100_precision(self) -> float:
        ok = self.precision >= 1.0 - 1e-12
        return float(self.recall[ok].max()) if ok.any() else 0.0

    @property
    def max_f1(self) -> float:
        denom = self.precision + self.recall
        f1 = np.where(denom > 0, 2 * self.precision * self.recall / np.where(denom > 0, denom, 1), 0.0)
        return float(f1.max()) if f1.size else 0.0


def pr_curve(confidence: np.ndarray, correct: np.ndarray, n_queries: int | None = None,
             has_match: np.ndarray | None = None) -> PRCurve:
    """PR points over every distinct confidence threshold.

    ``correct[i]``: the top candidate of query i is right (False if it has no match).
    ``has_match[i]``: query i produced a candidate at all (unmatched queries are never
    accepted). Recall divides by ``n_queries`` (default: all queries).
    """
    confidence = np.asarray(confidence, np.float64)
    correct = np.asarray(correct, bool)
    n = len(confidence) if n_queries is None else int(n_queries)
    keep = np.ones(len(confidence), bool) if has_match is None else np.asarray(has_match, bool)
    conf, corr = confidence[keep], correct[keep]
    if conf.size == 0 or n == 0:
        return PRCurve(np.zeros(0), np.zeros(0), np.zeros(0))
    order = np.argsort(-conf, kind="stable")
    conf, corr = conf[order], corr[order]
    tp = np.cumsum(corr)
    accepted = np.arange(1, conf.size + 1)
    # Only the last index of each run of equal confidences is a reachable threshold.
    last = np.r_[conf[1:] != conf[:-1], True]
    return PRCurve(conf[last], (tp / accepted)[last], (tp / n)[last])


def recall_at_k(candidates_correct: np.ndarray, ks: tuple[int, ...] = (1, 5, 10)) -> dict[int, float]:
    """``candidates_correct``: (n_queries, K) bool, ranked. Recall over all rows."""
    n = candidates_correct.shape[0]
    out = {}
    for k in ks:
        kk = min(k, candidates_correct.shape[1])
        out[k] = float(candidates_correct[:, :kk].any(axis=1).sum() / n) if n else 0.0
    return out


def split_row_minima(block: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``block`` (a difference matrix's columns, rows = reference), the smallest
    value at the listed positive cells (``rows``, ``cols``) and the smallest at every other
    cell (inf where a row has none): what :func:`dissimilarity_ratios` divides. One pass over
    the block plus one over the positives, never a boolean mask of the block's size.
    ``block`` is overwritten (its positive cells become inf): pass a block of one's own."""
    at_positive = np.full(block.shape[0], np.inf)
    np.minimum.at(at_positive, rows, block[rows, cols].astype(np.float64))
    block[rows, cols] = np.inf
    elsewhere = block.min(axis=1, initial=np.inf).astype(np.float64) if block.shape[1] else np.full(block.shape[0], np.inf)
    return at_positive, elsewhere


def dissimilarity_ratios(min_correct: np.ndarray, min_wrong: np.ndarray) -> np.ndarray:
    """Milford and Wyeth's dissimilarity ratio ("SeqSLAM: Visual route-based navigation for
    sunny summer days and stormy winter nights", ICRA 2012) per reference image: the
    difference to its correct query over the
    smallest difference to any wrong query. Smaller is better; >= 1 means a wrong query
    looked at least as alike. References with no correct or no wrong query are NaN."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.asarray(min_correct, np.float64) / np.asarray(min_wrong, np.float64)
    ratio[~np.isfinite(min_correct) | ~np.isfinite(min_wrong)] = np.nan
    ratio[(min_wrong <= 0) & (min_correct <= 0)] = 1.0
    return ratio


def summarise_ratios(ratio: np.ndarray) -> tuple[float, int]:
    """Mean ratio and count of ratios >= 1 over the references that have one."""
    ok = ~np.isnan(ratio)
    if not ok.any():
        return float("nan"), 0
    return float(ratio[ok].mean()), int((ratio[ok] >= 1.0).sum())


# ---------------------------------------------------------------------------------------
# Ranked candidates against ground truth: standard Recall@N, soft ground truth, denominators
# ---------------------------------------------------------------------------------------
# The shared default (one home: ground_truth.recall_at in placeloc.core.common_params).
DEFAULT_RECALL_N: tuple[int, ...] = GroundTruthParams().recall_at


def drop_soft(candidates: np.ndarray, soft_only: np.ndarray, *extra: np.ndarray) -> tuple[np.ndarray, ...]:
    """Remove the candidates that fall in the soft set only (neither right nor wrong) from
    each ranked row, shifting the rest up and padding with -1 (and NaN in ``extra``
    per-candidate arrays, e.g. scores). This is what setting their similarity to the
    minimum does in the tutorial of Schubert et al.: they can no longer take a rank."""
    candidates = np.asarray(candidates)
    keep = ~np.asarray(soft_only, bool) & (candidates >= 0)
    order = np.argsort(~keep, axis=1, kind="stable")  # kept first, rank order preserved
    cand = np.take_along_axis(candidates, order, axis=1)
    kept = np.take_along_axis(keep, order, axis=1)
    out = [np.where(kept, cand, -1)]
    for arr in extra:
        a = np.take_along_axis(np.asarray(arr, np.float64), order, axis=1)
        out.append(np.where(kept, a, np.nan))
    return tuple(out)


def recall_at_n(ranked_correct: np.ndarray, ns: tuple[int, ...] = DEFAULT_RECALL_N,
                has_positive: np.ndarray | None = None) -> dict[int, float]:
    """Standard Recall@N: the share of queries with at least one positive among their N
    best candidates (any of them, neighbouring frames allowed).

    ``ranked_correct``: (n_queries, K) bool, best first. Denominator: all rows, or only the
    rows where ``has_positive`` is True when it is given (queries without any positive
    cannot be right, so over all queries the best possible recall is below 1 when such
    queries exist). N beyond K uses all K candidates.
    """
    c = np.asarray(ranked_correct, bool)
    if has_positive is not None:
        c = c[np.asarray(has_positive, bool)]
    n = c.shape[0]
    first = np.where(c.any(axis=1), np.argmax(c, axis=1), np.iinfo(np.int64).max)
    return {int(k): (float((first < k).sum() / n) if n else 0.0) for k in ns}


def first_correct_rank(ranked_correct: np.ndarray) -> np.ndarray:
    """1-based rank of the first positive candidate per query (0 = none in the list)."""
    c = np.asarray(ranked_correct, bool)
    return np.where(c.any(axis=1), np.argmax(c, axis=1) + 1, 0)


def tail_count(n: int, fraction: float) -> int:
    """How many of ``n`` per-frame values the last ``fraction`` of a run holds (at least one)."""
    return max(1, int(round(n * fraction)))


def tail_mean(values: np.ndarray, fraction: float) -> float:
    """Mean of the last ``fraction`` of ``values`` (:func:`tail_count` of them): per-frame
    mapping cost near the end of a run, where the dictionary is largest."""
    values = np.asarray(values, np.float64)
    if len(values) == 0:
        return float("nan")
    return float(values[-tail_count(len(values), fraction):].mean())
