"""The ``ranked`` contract: per query, K reference candidates best first, with scores and
a confidence of the best (SeqSLAM, retrieval).

Scored against any image-matching ground truth (synchronous, csv, hdf5, poses + radius;
:mod:`placeloc.evaluation.ground_truth`) by :func:`placeloc.evaluation.matching.score_matches`.

``metrics.json`` schema (``ranked``):

- ``recall_at_N`` (N from ``ground_truth.recall_at``, up to the K candidates kept): standard
  Recall@N, a query is right when any of its N best candidates is a positive
  (neighbouring frames allowed), over all queries; ``recall_at_N_with_positive``: over the
  queries that have a positive, only when some query has none (else it is the same number).
- ``separated_recall_at_N`` (N >= 2): only for a method whose candidates are kept at least
  ``separation`` reference frames apart (the result's attribute; SeqSLAM: ``enhance_window
  + 1``), so the N candidates are N distinct places (at N = 1 it is ``recall_at_1``).
- ``auc_pr``, ``recall_at_100_precision``, ``max_f1``: precision-recall over the
  confidence of each query's best candidate, recall over all queries.
- ``seconds_per_frame`` (every stage before evaluate over the queries), ``stage_seconds``;
  counts ``n_queries``, ``queries_with_ground_truth``, ``n_matched``, ``n_reference``;
  ``headline``: the keys ``placeloc run`` prints.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from placeloc.evaluation.contracts import Field, RankedEvaluation, Result, names_by_index, write_result

# common config sections the evaluate stage reads
SECTIONS = ("ground_truth", "plots")
# evaluate draws show()'s pictures too (strips); False: finish() already drew them
SHOW_AT_EVALUATE = True
# show()'s --sample and --failures choose the queries it draws (strips); False: it draws the whole result
# at once, and they choose nothing (placeloc show says so)
CHOOSES_QUERIES = True

SCHEMA = {
    "query_index": Field("int", ("Q",)),
    "query_names": Field("str", ("Q",)),
    "reference_index": Field("int", ("R",)),
    "reference_names": Field("str", ("R",)),
    "candidates": Field("int", ("Q", "K")),
    "scores": Field("float", ("Q", "K")),
    "confidence": Field("float", ("Q",)),
    # optional: a plain (unseparated) ranking beside separated candidates
    "plain_candidates": Field("int", ("Q", "P"), optional=True),
    "plain_scores": Field("float", ("Q", "P"), optional=True),
}

# counts and settings (kept apart from the scores in metrics.json)
COUNTS = ("n_queries", "queries_with_ground_truth", "n_matched", "n_reference")

METRICS_DOC = {
    "recall_at_N": "standard Recall@N: any of the N best candidates (plain ranking) is a positive, over all queries",
    "recall_at_N_with_positive": "the same over the queries that have at least one positive (only when some have none)",
    "separated_recall_at_N": "Recall@N over candidates kept at least `separation` reference frames apart (N distinct places)",
    "seconds_per_frame": "wall seconds of every stage before evaluate (extraction included) per query",
    "auc_pr": "area under precision-recall over the best candidate's confidence (recall over all queries)",
    "recall_at_100_precision": "largest recall at which every accepted best match is right",
    "max_f1": "best F1 over the confidence thresholds",
}


def write(ctx: Any, *, reference: Any, query: Any, candidates: np.ndarray, scores: np.ndarray, confidence: np.ndarray,
          higher_is_better: bool, separation: int = 0, plain_candidates: np.ndarray | None = None,
          plain_scores: np.ndarray | None = None, zero_confidence: str | None = None) -> None:
    """Write the contract into ``ctx.out/result`` and ``matches.csv`` (one row per query:
    its best reference). ``reference`` and ``query`` are the traverses' groups of the
    extract artifact (``index`` and ``names`` as the engine wrote them); ``candidates`` and
    ``plain_candidates`` hold LOCAL reference rows (row ``i`` of the reference's arrays;
    -1 = none), one row per query row: the contract stores them as original indices, with
    the names, so images skipped with ``on_error: skip`` never shift an answer.
    ``zero_confidence``: what a confidence of exactly 0 means for the method, where it means
    more than "as unsure as can be" (the strips print it beside such a match)."""
    from placeloc.core.artifacts import read_strings
    from placeloc.core.imagework import local_to_original

    reference_index, query_index = reference["index"][()], query["index"][()]
    reference_names, query_names = read_strings(reference["names"]), read_strings(query["names"])
    candidates = local_to_original(reference_index, candidates)
    if plain_candidates is not None:
        plain_candidates = local_to_original(reference_index, plain_candidates)
    write_result(ctx.out, "ranked", {
        "query_index": np.asarray(query_index, np.int64), "query_names": list(query_names),
        "reference_index": np.asarray(reference_index, np.int64), "reference_names": list(reference_names),
        "candidates": np.asarray(candidates, np.int64), "scores": np.asarray(scores, np.float32),
        "confidence": np.asarray(confidence, np.float32),
        "plain_candidates": None if plain_candidates is None else np.asarray(plain_candidates, np.int64),
        "plain_scores": None if plain_scores is None else np.asarray(plain_scores, np.float32)},
        attrs={"higher_is_better": bool(higher_is_better), "separation": int(separation),
               **({"zero_confidence": str(zero_confidence)} if zero_confidence else {}),
               "n_reference_listed": int(ctx_listed(ctx, "reference", reference_index)),
               "n_query_listed": int(ctx_listed(ctx, "query", query_index))})
    write_matches_csv(ctx.output("matches.csv"), np.asarray(candidates)[:, 0], np.asarray(confidence),
                      np.asarray(query_index), list(query_names), np.asarray(reference_index), list(reference_names))


def ctx_listed(ctx: Any, role: str, index: np.ndarray) -> int:
    """How many images the traverse lists (skipped ones included), so original indices stay valid."""
    images = ctx.images.get(role)
    if images is not None:
        return len(images.paths)
    return int(np.max(index)) + 1 if len(index) else 0


def write_matches_csv(path: Path, best: np.ndarray, confidence: np.ndarray, query_index: np.ndarray,
                      query_names: list[str], reference_index: np.ndarray, reference_names: list[str]) -> None:
    """``matches.csv``: per query its best reference by original index and file name."""
    import csv

    from placeloc.core.artifacts import atomic_open

    name_of = {int(i): n for i, n in zip(reference_index, reference_names)}
    with atomic_open(path, newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["query", "reference", "confidence", "query_image", "reference_image"])
        for q, qn, r, c in zip(query_index, query_names, best, confidence):
            if r < 0:
                w.writerow([int(q), "", "", qn, ""])
            else:
                w.writerow([int(q), int(r), f"{c:.6f}", qn, name_of.get(int(r), "")])


# ---------------------------------------------------------------------------------------
# ground truth
# ---------------------------------------------------------------------------------------
def check_ground_truth(config: dict[str, Any], method: Any) -> None:
    """Build the ground truth in full against the listed images: every problem (format,
    columns, indices or names outside the traverses, matrix shape, missing positions) is
    one error naming the file, row and fix."""
    from placeloc.core.images import ImageError, check_position_pairing, list_images
    from placeloc.evaluation.ground_truth import GroundTruth

    section = config.get("ground_truth") or {}
    if section.get("kind", "none") == "none":
        return
    try:
        ref = list_images(config["reference"]["images"])
        query = list_images(config["query"]["images"]) if config.get("query") else None
    except (ImageError, TypeError, KeyError):
        return  # the image check reports this one
    if section["kind"] == "synchronous" and query is not None:
        check_position_pairing(ref, query)
    GroundTruth.from_config(section, len(ref), len(query) if query else len(ref), ref_names=ref.names,
                            query_names=query.names if query else None)


def _full_names(ctx: Any, res: Result, role: str) -> list[str]:
    """File names of every listed image of ``role``, indexed by original index."""
    images = ctx.images.get(role)
    if images is not None:
        return list(images.names)
    key = "reference" if role == "reference" else "query"
    return names_by_index(res[f"{key}_index"], res[f"{key}_names"], int(res.attrs.get(f"n_{key}_listed", 0)))


# ---------------------------------------------------------------------------------------
# evaluate
# ---------------------------------------------------------------------------------------
def evaluate(ctx: Any, res: Result) -> RankedEvaluation:
    """Read the ground truth against the listed images and :func:`score` the result."""
    from placeloc.core.errors import StageError
    from placeloc.evaluation.ground_truth import GroundTruth

    section = ctx.config["ground_truth"]
    if section["kind"] == "none":
        raise StageError("ground_truth.kind is none: evaluate needs ground truth (synchronous, csv, hdf5 or poses); "
                         "`placeloc show RUN_DIR` draws the matches without it")
    ref_names = _full_names(ctx, res, "reference")
    q_names = _full_names(ctx, res, "query")
    gt = GroundTruth.from_config(section, len(ref_names), len(q_names), ref_names=ref_names, query_names=q_names)
    ev = score(res, gt, ns=tuple(int(n) for n in section["recall_at"]), ref_names=ref_names, q_names=q_names)
    n_q, n_gt = int(ev.metrics["n_queries"]), int(ev.metrics["queries_with_ground_truth"])
    if n_gt < n_q:
        # said, not only counted: a ground-truth file that lists only some queries (half a
        # route labelled) silently turned every match of the others into a false positive
        where = f" in {section['path']}" if section.get("path") else ""
        logging.getLogger("placeloc").info(
            "ground truth: %d of %d queries have no true match%s; their matches count as wrong in auc_pr and "
            "recall_at_100_precision, and recall_at_N_with_positive leaves them out", n_q - n_gt, n_q, where)
    return ev


def score(res: Result, gt: Any, *, ns: Sequence[int], ref_names: list[str], q_names: list[str]) -> RankedEvaluation:
    """Score a ``ranked`` result against ``gt`` (arrays in, metrics out): Recall@N over the
    plain ranking (the result's ``plain_candidates`` when its candidates are separated),
    the separated Recall@N where it can differ, and precision-recall over the confidence."""
    from placeloc.evaluation import matching

    ns = tuple(sorted(set(int(n) for n in ns)))
    separation = int(res.attrs.get("separation", 0))
    cand = res["candidates"]
    if separation == 0:
        plain, plain_scores = cand, res["scores"]
    else:
        plain, plain_scores = res.get("plain_candidates"), res.get("plain_scores")
    identity = np.arange(len(ref_names), dtype=np.int64)
    s = matching.score_matches(gt, res["query_index"], identity, separated=cand, confidence=res["confidence"],
                               ranked=plain, ranked_scores=plain_scores, ns=ns, separated_differs=separation > 0)
    m = dict(s.metrics)
    m["n_reference"] = int(len(res["reference_index"]))
    m["headline"] = [f"recall_at_{n}" for n in ns if f"recall_at_{n}" in m] + ["auc_pr", "recall_at_100_precision",
                                                                               "seconds_per_frame"]
    return RankedEvaluation("ranked", res, metrics=m, gt=gt, ns=tuple(n for n in ns if f"recall_at_{n}" in m),
                            ref_names=ref_names, q_names=q_names, separation=separation, scores=s)


def finish(ctx: Any, ev: RankedEvaluation, plots: bool = True) -> None:
    """evaluate.h5's PR curve and correctness, per_query.csv, pr_curve.png and recall_at_n.png."""
    from placeloc.evaluation import matching
    from placeloc.evaluation.pictures import draw

    s = ev.scores
    pr_group = ctx.out.create_group("pr")
    for name, arr in (("threshold", s.pr.thresholds), ("precision", s.pr.precision), ("recall", s.pr.recall)):
        pr_group.create_dataset(name, data=arr)
    ctx.out.create_dataset("correct", data=s.best_correct)
    if plots:  # handed to the picture threads first, so they are drawn while the table is written
        # imported here: without pictures the drawing modules' import was most of a small
        # run's evaluate (11 of 25 ms on the demo)
        from placeloc.evaluation import plots as P

        n_q, ns = len(s.query), ev.ns
        draw(P.plot_pr_curves, {ev.label: (s.pr.recall, s.pr.precision), **ev.pr_curves}, ctx.output("pr_curve.png"),
             title=f"Precision-recall over the best match's confidence, {n_q} queries")
        curves = {f"{ev.label}, standard (plain ranking)": (ns, [ev.metrics.get(f"recall_at_{n}") for n in ns])}
        if ev.separation:
            sep_ns = [n for n in ns if n == 1 or f"separated_recall_at_{n}" in ev.metrics]
            curves[f"{ev.label}, candidates >= {ev.separation} frames apart"] = (
                sep_ns, [ev.metrics["recall_at_1"] if n == 1 else ev.metrics[f"separated_recall_at_{n}"] for n in sep_ns])
        draw(P.plot_recall_at_n, curves, ctx.output("recall_at_n.png"), title=f"Recall@N over all {n_q} queries")
    matching.write_per_query_csv(ctx.output("per_query.csv"), s, ev.q_names, ev.ref_names)


def headline(metrics: dict[str, Any]) -> list[str]:
    return list(metrics.get("headline") or ["recall_at_1", "auc_pr", "recall_at_100_precision"])


def show(run_dir: Path, res: Result | None = None, *, sample: int = 8, failures: int = 8,
         out_dir: Path | None = None, ev: RankedEvaluation | None = None,
         config: dict[str, Any] | None = None) -> list[Path]:
    """Strips query | best match | a true one (from the evaluation ``ev`` when evaluate
    draws them, else from per_query.csv, else from the result), written into ``out_dir``
    (default ``run_dir``); the image folders from ``config`` (the evaluate stage's), else
    the run's artifacts."""
    from placeloc.evaluation.show import draw_strips, zero_confidence_note

    return draw_strips(run_dir, sample=sample, failures=failures, out_dir=out_dir,
                       rows=None if ev is None else strip_rows(ev), config=config,
                       zero_note=zero_confidence_note(run_dir, ev.result if ev is not None else res))


def strip_rows(ev: RankedEvaluation) -> list[Any]:
    """The rows per_query.csv holds for the strips (query, best match, confidence as written
    there, correctness, a true reference), straight from the evaluation."""
    from placeloc.evaluation.show import Row

    s, q_names, ref_names = ev.scores, ev.q_names, ev.ref_names
    return [Row(q_names[q], ref_names[b] if b >= 0 else "", float(f"{c:.6f}"), bool(ok), ref_names[p] if p >= 0 else "")
            for q, b, c, ok, p in zip(s.query.tolist(), s.best.tolist(), s.confidence.tolist(), s.best_correct.tolist(),
                                      s.example_positive.tolist())]
