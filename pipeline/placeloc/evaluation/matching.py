"""Scoring ranked place matches against ground truth, for every method that ranks reference
images per query, and the per-query CSV.

Conventions (the keys of ``metrics.json``, the ``ranked`` contract's schema):

- ``recall_at_N``: Recall@N as the field reports it (Lowry et al.'s survey, VPR-Bench,
  Berton et al.): a query is right at N when ANY of its N best candidates is a positive;
  candidates are the plain ranking (neighbouring frames allowed). Denominator: all
  queries (a query without any positive is a miss).
- ``recall_at_N_with_positive``: the same over the queries that have at least one
  positive (``queries_with_ground_truth`` of them), the denominator most benchmarks use
  since their every query has one; written only when some query has none (else it is
  ``recall_at_N``).
- ``separated_recall_at_N`` (N >= 2): as the standard one but over candidates kept at
  least a method-specific distance apart (SeqSLAM: ``enhance_window + 1`` reference
  frames), so the N candidates are N distinct places. The best candidate is the same in
  both rankings, so at N = 1 it is ``recall_at_1`` and is not written.
- Precision-recall (``auc_pr``, ``recall_at_100_precision``, ``max_f1``): one match per
  query (the best candidate) accepted when its confidence is at least a threshold;
  recall over all queries (see :mod:`placeloc.evaluation.metrics`).
- Soft ground truth: candidates in the soft set only are removed from every ranking
  before scoring (not counted wrong, not required).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from placeloc.core.artifacts import atomic_open
from placeloc.evaluation.ground_truth import GroundTruth
from placeloc.evaluation.metrics import DEFAULT_RECALL_N, PRCurve, drop_soft, first_correct_rank, pr_curve, recall_at_n


@dataclass
class MatchScores:
    """Per-query results in ORIGINAL indices (positions in the listed folders)."""

    query: np.ndarray  # (n,) original query index
    ranked: np.ndarray  # (n, K) plain ranking, -1 = none (soft-only removed)
    ranked_scores: np.ndarray  # (n, K) the method's score per candidate (NaN = none)
    ranked_correct: np.ndarray  # (n, K) bool
    separated: np.ndarray  # (n, K2) separated candidates (soft-only removed)
    separated_correct: np.ndarray
    confidence: np.ndarray  # (n,) of the best match
    has_positive: np.ndarray  # (n,) bool
    example_positive: np.ndarray  # (n,) one positive reference (-1 = none)
    pr: PRCurve
    ns: tuple[int, ...]
    metrics: dict[str, Any] = field(default_factory=dict)

    @property
    def best(self) -> np.ndarray:
        return self.separated[:, 0]

    @property
    def best_correct(self) -> np.ndarray:
        return self.separated_correct[:, 0]


def _to_orig(cand: np.ndarray, ref_index: np.ndarray) -> np.ndarray:
    cand = np.asarray(cand, np.int64)
    return np.where(cand >= 0, ref_index[np.clip(cand, 0, None)], -1)


def score_matches(gt: GroundTruth, query_index: np.ndarray, ref_index: np.ndarray, *, separated: np.ndarray,
                  confidence: np.ndarray, ranked: np.ndarray | None = None, ranked_scores: np.ndarray | None = None,
                  ns: Sequence[int] = DEFAULT_RECALL_N, separated_differs: bool = False) -> MatchScores:
    """Score one run. ``separated`` (n, K2) and ``ranked`` (n, K) hold candidate positions
    in the method's (possibly filtered) reference list, best first, -1 = none;
    ``ref_index``/``query_index`` map list positions to original indices. Without a
    plain ``ranked`` list only N = 1 of the standard recall is known (the best candidate
    is the same in both rankings). A key is written only where its value is known and
    distinct: ``recall_at_N`` for N up to the plain candidates kept,
    ``recall_at_N_with_positive`` when some query has no positive, and
    ``separated_recall_at_N`` (``separated_differs``: the method keeps its candidates
    apart) for 2 <= N <= the separated candidates kept."""
    q = np.asarray(query_index, np.int64)
    ref_index = np.asarray(ref_index, np.int64)
    ns = tuple(int(n) for n in ns)
    sep = _to_orig(separated, ref_index)
    (sep,) = drop_soft(sep, gt.soft_only(q[:, None], sep))
    sep_ok = gt.correct(q[:, None], sep)
    plain_known = ranked is not None
    if ranked is None:
        ranked, ranked_scores = separated[:, :1], np.full((len(q), 1), np.nan)
    rk = _to_orig(ranked, ref_index)
    rk, rs = drop_soft(rk, gt.soft_only(q[:, None], rk),
                       np.full(rk.shape, np.nan) if ranked_scores is None else ranked_scores)
    rk_ok = gt.correct(q[:, None], rk)
    has_pos = gt.has_match()[q]
    example = gt.example_positive()[q]
    conf = np.asarray(confidence, np.float64)
    pr = pr_curve(conf, sep_ok[:, 0], n_queries=len(q), has_match=sep[:, 0] >= 0)
    m: dict[str, Any] = {}
    sep_r = recall_at_n(sep_ok, ns)
    std_all = recall_at_n(rk_ok, ns)
    std_pos = recall_at_n(rk_ok, ns, has_positive=has_pos)
    every_query_has_one = bool(has_pos.all())
    for n in ns:
        if n == 1 or (plain_known and n <= rk.shape[1]):
            m[f"recall_at_{n}"] = std_all[n]
            if not every_query_has_one:
                m[f"recall_at_{n}_with_positive"] = std_pos[n]
    if separated_differs:  # N = 1 is recall_at_1 (the best candidate is the same in both rankings)
        for n in ns:
            if 2 <= n <= sep.shape[1]:
                m[f"separated_recall_at_{n}"] = sep_r[n]
    m.update({"auc_pr": pr.auc, "recall_at_100_precision": pr.recall_at_100_precision, "max_f1": pr.max_f1,
              "n_queries": int(len(q)), "queries_with_ground_truth": int(has_pos.sum()),
              "n_matched": int((sep[:, 0] >= 0).sum())})
    return MatchScores(query=q, ranked=rk, ranked_scores=rs, ranked_correct=rk_ok, separated=sep,
                       separated_correct=sep_ok, confidence=conf, has_positive=has_pos, example_positive=example,
                       pr=pr, ns=ns, metrics=m)


def csv_field(text: str) -> str:
    """``text`` as one field of a row :func:`csv.writer` writes with its defaults (minimal
    quoting): in double quotes, its quotes doubled, when it holds a comma, a quote or a
    line break; as it is otherwise (a row of several fields: an empty one stays empty)."""
    if "," in text or '"' in text or "\r" in text or "\n" in text:
        return '"' + text.replace('"', '""') + '"'
    return text


def write_per_query_csv(path: str | Path, s: MatchScores, query_names: Sequence[str], ref_names: Sequence[str],
                        top_k: int | None = None) -> Path:
    """One row per query: its image, whether it has a positive (and one, for pictures),
    the best match with its confidence and correctness, the rank of the first positive,
    then the top-K plain candidates as ``ref_i, image_i, score_i, correct_i``. Names are
    indexed by original index."""
    path = Path(path)
    k = s.ranked.shape[1] if top_k is None else min(top_k, s.ranked.shape[1])
    first = first_correct_rank(s.ranked_correct)
    head = ["query", "query_image", "has_positive", "positive_reference", "positive_image", "best_reference",
            "best_image", "confidence", "correct", "first_correct_rank"]
    for i in range(1, k + 1):
        head += [f"ref_{i}", f"image_{i}", f"score_{i}", f"correct_{i}"]
    # the rows as text, column by column, each name quoted once (csv_field: csv.writer's
    # minimal quoting, tested against it); csv.writer's per-field work was half the time
    # (33 of 64 ms at 3576 queries of 20 candidates), all of it holding the GIL that
    # evaluate's picture threads need
    names = [*map(csv_field, ref_names), ""]  # index -1: no reference
    flag = ("0", "1")

    def refs(col: np.ndarray) -> list[list[str]]:  # reference numbers and names, "" where none
        idx = col.tolist()
        return [[str(r) if r >= 0 else "" for r in idx], [names[r] for r in idx]]

    query = s.query.tolist()
    cols: list[list[str]] = [list(map(str, query)), [csv_field(query_names[q]) for q in query],
                             [flag[b] for b in s.has_positive.tolist()], *refs(s.example_positive), *refs(s.best),
                             [f"{c:.6f}" for c in s.confidence.tolist()], [flag[b] for b in s.best_correct.tolist()],
                             list(map(str, first.tolist()))]
    for j in range(k):
        r, sc = s.ranked[:, j], s.ranked_scores[:, j]
        blank = ((r < 0) | ~np.isfinite(sc)).tolist()
        cols += [*refs(r), ["" if no else f"{x:.6g}" for x, no in zip(sc.tolist(), blank)],
                 [flag[b] for b in s.ranked_correct[:, j].tolist()]]
    text = ",".join(head) + "\r\n" + "".join([",".join(row) + "\r\n" for row in zip(*cols)])
    with atomic_open(path, newline="") as fh:
        fh.write(text)
    return path
