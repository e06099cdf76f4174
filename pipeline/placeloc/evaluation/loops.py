"""The ``loops`` contract: loop closure within one traverse, scored as the field scores it.

Per frame (``frame_index``, original positions) the method names another, earlier frame
that closes a loop (``match``, -1: none) with a ``confidence`` (higher = surer); the
attribute ``threshold`` is the method's own acceptance rule (PIRF-nav2: tau), optional
``seconds``/``map_size`` per frame give the time per frame against the map's size.

Ground truth (``ground_truth.kind``):

- ``matrix``: a binary N x N matrix, N = frames, entry (i, j) = 1 when frame i closes a
  loop with frame j, in ``.npy``, ``.npz``, ``.mat`` (MATLAB, read with scipy.io; v7.3
  files with h5py), ``.txt`` / ``.csv`` (N rows of N numbers) or ``.h5``. As the public
  City Centre, New College, Lip6, Malaga, KITTI and St Lucia sets ship it: a named
  variable (``truth``, ``gt``, ``GT``, ``GThard``) or the only square one; either triangle
  (an upper-triangular file is transposed; a symmetric one gives the same lower part);
  uint8, float or bool 0/1. A matrix shorter than the frames is padded (frames beyond it
  have no loop) with a warning; a longer one is refused. ``hdf5`` is read the same way.
- ``poses``: positions (``ground_truth.path``, as :mod:`placeloc.evaluation.poses` reads
  them) and ``ground_truth.radius`` metres: frames i and j close a loop when they lie
  within the radius.
- ``csv``: pairs or ranges as :mod:`placeloc.evaluation.ground_truth` reads them, the
  ``query`` column being the later frame and the reference the earlier one.

Scoring (that of the evaluation kit distributed with those sets): only pairs with
``j <= i - exclude_recent`` count (``ground_truth.exclude_recent`` frames; recent frames are
never loop candidates, and a match inside that window is ignored); a match (i, j) is a
true positive when the ground truth has a one in row i within ``ground_truth.tolerance``
columns of j. Sweeping a threshold over the confidence, precision = TP / (TP + FP) over
the accepted frames, recall = TP / (frames whose row has any one).

``metrics.json`` schema (``loops``): ``recall_at_100_precision`` (MR, the headline),
``auc_pr``, ``max_f1``, ``precision_at_threshold`` / ``recall_at_threshold`` at the method's
own threshold (None without one), ``n_frames``, ``frames_with_loop``, ``n_candidates``,
``n_accepted`` (and ``n_accepted_right``), ``exclude_recent``, ``tolerance``,
``seconds_per_frame`` (every stage before evaluate, extraction included, over the frames),
``loop_seconds_per_frame`` and ``loop_seconds_per_frame_end`` (the method's own per-frame
record; the mean over the last tenth, where the map is largest) with ``map_size_end``;
``headline``.
"""

from __future__ import annotations

import io
import logging
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from placeloc.core.safe_io import UnsafeInputError, load_arrays, read_input_text, read_run_table
from placeloc.evaluation.contracts import Field, LoopEvaluation, Result, names_by_index, write_result
from placeloc.evaluation.ground_truth import GroundTruthError

log = logging.getLogger("placeloc")

# common config sections the evaluate stage reads
SECTIONS = ("ground_truth", "plots")
# evaluate draws show()'s pictures too (strips); False: finish() already drew them
SHOW_AT_EVALUATE = True
# show()'s --sample and --failures choose the queries it draws (strips); False: it draws the whole result
# at once, and they choose nothing (placeloc show says so)
CHOOSES_QUERIES = True

SCHEMA = {
    "frame_index": Field("int", ("N",)),
    "frame_names": Field("str", ("N",)),
    "match": Field("int", ("N",)),
    "confidence": Field("float", ("N",)),
    "seconds": Field("float", ("N",), optional=True),
    "map_size": Field("int", ("N",), optional=True),
}

METRICS_DOC = {
    "recall_at_100_precision": "largest recall with every accepted loop closure right (MR)",
    "auc_pr": "area under precision-recall over the confidence",
    "precision_at_threshold": "precision of the loop closures the method itself accepts",
    "recall_at_threshold": "recall of the loop closures the method itself accepts",
    "max_f1": "best F1 over the confidence thresholds",
    "seconds_per_frame": "wall seconds of every stage before evaluate (extraction included) per frame",
    "loop_seconds_per_frame": "the method's own time per frame from its per-frame record (no extraction); "
                              "loop_seconds_per_frame_end: over the last tenth, where the map is largest",
}
# counts and settings (kept apart from the scores in metrics.json)
COUNTS = ("n_frames", "frames_with_loop", "n_candidates", "n_accepted", "n_accepted_right", "exclude_recent", "tolerance",
          "map_size_end", "threshold")
MATRIX_NAMES = ("truth", "gt", "GT", "GThard", "gt_hard", "ground_truth")


def write(ctx: Any, *, frames: Any, match: np.ndarray, confidence: np.ndarray, threshold: float | None,
          seconds: np.ndarray | None = None, map_size: np.ndarray | None = None,
          zero_confidence: str | None = None) -> None:
    """Write the contract into ``ctx.out/result``. ``frames`` is the traverse's group of the
    extract artifact (``index`` and ``names`` as the engine wrote them); ``match`` holds
    LOCAL rows (the earlier frame's row in the traverse's arrays; -1 = none), one per row:
    the contract stores original indices, with the names. ``zero_confidence``: what a
    confidence of exactly 0 means for the method (the strips print it beside such a match)."""
    from placeloc.core.artifacts import read_strings
    from placeloc.core.imagework import local_to_original

    frame_index, frame_names = frames["index"][()], read_strings(frames["names"])
    match = local_to_original(frame_index, match)
    images = ctx.images.get("reference")
    n_listed = len(images.paths) if images is not None else (int(np.max(frame_index)) + 1 if len(frame_index) else 0)
    attrs: dict[str, Any] = {"n_listed": n_listed}
    if threshold is not None:
        attrs["threshold"] = float(threshold)
    if zero_confidence:
        attrs["zero_confidence"] = str(zero_confidence)
    write_result(ctx.out, "loops", {
        "frame_index": np.asarray(frame_index, np.int64), "frame_names": list(frame_names),
        "match": np.asarray(match, np.int64), "confidence": np.asarray(confidence, np.float32),
        "seconds": None if seconds is None else np.asarray(seconds, np.float64),
        "map_size": None if map_size is None else np.asarray(map_size, np.int64)}, attrs=attrs)


# ---------------------------------------------------------------------------------------
# ground truth
# ---------------------------------------------------------------------------------------
def read_matrix(path: str | Path, n_frames: int) -> np.ndarray:
    """A loop-closure matrix file -> (n_frames, n_frames) bool, lower triangle (i > j)."""
    path = Path(path)
    suffix = path.suffix.lower()
    arrays: dict[str, np.ndarray] = {}
    # the matrix is n_frames x n_frames: no array of the file may need more than that at 8
    # bytes an element, checked from its header before it is read
    budget = max(n_frames * n_frames * 8, 1 << 16)
    try:
        if suffix in (".npy", ".npz", ".mat", ".h5", ".hdf5"):
            arrays = load_arrays(path, "ground_truth.path", budget)
            if "array" in arrays and suffix == ".npy":
                arrays = {"matrix": arrays.pop("array")}
        elif suffix in (".txt", ".csv"):
            arrays = {"matrix": _read_text_matrix(path)}
        else:
            raise GroundTruthError(f"ground_truth.path: {path} is not a loop-closure matrix file; give .npy, .npz, .mat, "
                                   ".txt, .csv or .h5")
    except UnsafeInputError as exc:
        raise GroundTruthError(str(exc)) from None
    except (OSError, ValueError) as exc:
        raise GroundTruthError(f"ground_truth.path: {path} cannot be read as a {suffix} matrix "
                               f"({' '.join(str(exc).split())})") from None
    name = next((k for k in MATRIX_NAMES if k in arrays), None)
    if name is None:
        square = [k for k, v in arrays.items() if np.ndim(v) == 2 and np.shape(v)[0] == np.shape(v)[1]]
        if len(square) != 1:
            raise GroundTruthError(f"{path}: holds {sorted(arrays) or 'nothing'}; expected one square N x N matrix "
                                   f"(or one named {', '.join(MATRIX_NAMES)})")
        name = square[0]
    m = np.asarray(arrays[name])
    if m.ndim != 2 or m.shape[0] != m.shape[1]:
        raise GroundTruthError(f"{path}: {name!r} is {m.shape}; a loop-closure matrix is square, N x N with N = frames")
    if m.dtype.kind not in "biuf":
        raise GroundTruthError(f"{path}: {name!r} holds {m.dtype}; store 0/1 (or booleans)")
    bad = (m != 0) & (m != 1)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise GroundTruthError(f"{path}: {name!r} has value {m[i, j]} at ({i}, {j}); store 0/1 (frame i closes a loop "
                               "with frame j)")
    m = m.astype(bool)
    n = m.shape[0]
    if n > n_frames:
        raise GroundTruthError(f"{path}: the matrix is {n} x {n} but the traverse has {n_frames} frames; give the "
                               "matrix of this sequence (or the images it was made for)")
    if n < n_frames:
        log.warning("%s: the matrix is %d x %d for %d frames; the last %d frames are taken to close no loop",
                    path, n, n, n_frames, n_frames - n)
        m = np.pad(m, ((0, n_frames - n), (0, n_frames - n)))
    return np.tril(m, -1) | np.tril(m.T, -1)


def _read_text_matrix(path: Path) -> np.ndarray:
    text = read_input_text(path, "ground_truth.path")
    delimiter = "," if "," in text.split("\n", 1)[0] else None
    return np.loadtxt(io.StringIO(text), delimiter=delimiter, ndmin=2)


def loop_truth(section: dict[str, Any], names: Sequence[str]) -> Any:
    """The loop-closure ground truth of ``names`` (every listed frame) as a sparse lower
    triangular boolean matrix (scipy CSR): row i holds the earlier frames j that close a
    loop with i."""
    from scipy import sparse

    kind, n = section.get("kind", "none"), len(names)
    if kind in ("matrix", "hdf5"):
        return sparse.csr_matrix(read_matrix(section["path"], n))
    if kind == "poses":
        from scipy.spatial import cKDTree

        from placeloc.evaluation.ground_truth import GroundTruth

        gt = GroundTruth.from_positions(section["path"], n, n, radius=float(section["radius"]), ref_names=list(names),
                                        query_names=None, loop_closure=True)
        pairs = cKDTree(gt.ref_xy).query_pairs(float(section["radius"]), output_type="ndarray")
        i, j = pairs.max(axis=1), pairs.min(axis=1)
        return sparse.csr_matrix((np.ones(len(i), bool), (i, j)), shape=(n, n))
    if kind == "csv":
        from placeloc.evaluation.ground_truth import GroundTruth

        gt = GroundTruth.from_config(section, n, n, ref_names=list(names), query_names=None)
        rows, cols = [], []
        for q0 in range(0, n, 1024):  # (reference x query) blocks -> (frame i = query, earlier frame j = reference)
            r, q = np.nonzero(gt.block(0, n, q0, min(n, q0 + 1024)))
            rows.append(q + q0)
            cols.append(r)
        i, j = np.concatenate(rows), np.concatenate(cols)
        m = sparse.csr_matrix((np.ones(len(i), bool), (i, j)), shape=(n, n))
        return sparse.tril(m, -1).tocsr() + sparse.tril(m.T, -1).tocsr()
    raise GroundTruthError(f"ground_truth.kind {kind!r} cannot score loop closures; use matrix (a binary N x N file), "
                           "poses (positions with ground_truth.radius) or csv (pairs or ranges: frame, earlier frame)")


def check_ground_truth(config: dict[str, Any], method: Any) -> None:
    """Read the loop-closure ground truth against the listed frames before any stage runs."""
    from placeloc.core.images import ImageError, list_images

    section = config.get("ground_truth") or {}
    if section.get("kind", "none") == "none" or not config.get("reference"):
        return
    try:
        frames = list_images(config["reference"]["images"])
    except (ImageError, TypeError, KeyError):
        return
    loop_truth(section, frames.names)


# ---------------------------------------------------------------------------------------
# scoring
# ---------------------------------------------------------------------------------------
def score_loops(truth: Any, frames: np.ndarray, match: np.ndarray, *, exclude_recent: int,
                tolerance: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per frame of ``frames``: (a candidate: match >= 0 and j <= i - exclude_recent,
    correct: truth has a one in row i within ``tolerance`` of j, row has a loop, one true
    earlier frame nearest the match or -1)."""
    truth = truth.tocsr()
    frames, match = np.asarray(frames, np.int64), np.asarray(match, np.int64)
    candidate = (match >= 0) & (match <= frames - exclude_recent)
    correct = np.zeros(len(frames), bool)
    has_loop = np.zeros(len(frames), bool)
    example = np.full(len(frames), -1, np.int64)
    for k, (i, j) in enumerate(zip(frames.tolist(), match.tolist())):
        row = truth.indices[truth.indptr[i]:truth.indptr[i + 1]]
        row = row[row <= i - exclude_recent]
        if not len(row):
            continue
        has_loop[k] = True
        ref = j if candidate[k] else i
        near = row[np.argmin(np.abs(row - ref))]
        example[k] = near
        correct[k] = bool(candidate[k] and abs(int(near) - j) <= tolerance)
    return candidate, correct, has_loop, example


def exclusion_for(ctx: Any, n_kept: int) -> int:
    """``ground_truth.exclude_recent`` as this run's loop closures are scored with it (set, or
    adapted to the reference traverse's listed length, ``n_kept`` frames when the listing is
    not at hand): what a method's loop mode excludes, so it never proposes a pair the
    scoring would not count."""
    from placeloc.core.common_params import loop_exclusion

    images = ctx.images.get("reference")
    return loop_exclusion(ctx.config["ground_truth"]["exclude_recent"], len(images.paths) if images is not None else n_kept)[0]


def evaluate(ctx: Any, res: Result) -> LoopEvaluation:
    """Read the loop-closure ground truth against the listed frames and :func:`score` the result."""
    from placeloc.core.common_params import LOOP_EXCLUSION_FRAMES, loop_exclusion
    from placeloc.core.errors import StageError

    section = ctx.config["ground_truth"]
    if section["kind"] == "none":
        raise StageError("ground_truth.kind is none: loop closures are scored against a binary N x N matrix "
                         "(ground_truth.kind: matrix) or positions (kind: poses, with ground_truth.radius); "
                         "`placeloc show RUN_DIR` draws the loop closures without it")
    images = ctx.images.get("reference")
    n = len(images.paths) if images is not None else int(res.attrs.get("n_listed", len(res["frame_index"])))
    names = list(images.names) if images is not None else names_by_index(res["frame_index"], res["frame_names"], n)
    truth = loop_truth(section, names)
    exclude, exclude_rule = loop_exclusion(section["exclude_recent"], n)
    (log.info if section["exclude_recent"] is not None or exclude == LOOP_EXCLUSION_FRAMES else log.warning)(
        "loop closures: pairs fewer than %d frames apart never count: %s", exclude, exclude_rule)
    ev = score(res, truth, names=names, exclude_recent=exclude, tolerance=int(section.get("tolerance") or 0))
    ev.metrics["exclude_recent_rule"] = exclude_rule
    return ev


def score(res: Result, truth: Any, *, names: list[str], exclude_recent: int, tolerance: int) -> LoopEvaluation:
    """Score a ``loops`` result against ``truth`` (sparse, lower triangular; arrays in,
    metrics out): MR, AUC, max F1 over the confidence, and precision and recall at the
    method's own threshold when it has one."""
    from placeloc.evaluation.metrics import pr_curve, tail_mean

    frames, match, conf = res["frame_index"], res["match"], np.asarray(res["confidence"], np.float64)
    candidate, correct, has_loop, example = score_loops(truth, frames, match, exclude_recent=exclude_recent,
                                                        tolerance=tolerance)
    n_loop = int(has_loop.sum())
    pr = pr_curve(conf, correct, n_queries=max(n_loop, 1), has_match=candidate)
    m: dict[str, Any] = {"recall_at_100_precision": pr.recall_at_100_precision if n_loop else None,
                         "auc_pr": pr.auc if n_loop else None, "max_f1": pr.max_f1 if n_loop else None}
    threshold = res.attrs.get("threshold")
    accepted = candidate & (conf >= float(threshold)) if threshold is not None else candidate
    if threshold is not None:
        m["precision_at_threshold"] = float(correct[accepted].mean()) if accepted.any() else None
        m["recall_at_threshold"] = float((correct & accepted).sum() / n_loop) if n_loop else None
        m["threshold"] = float(threshold)
    m.update({"n_frames": int(len(frames)), "frames_with_loop": n_loop, "n_candidates": int(candidate.sum()),
              "n_accepted": int(accepted.sum()), "n_accepted_right": int((correct & accepted).sum()),
              "exclude_recent": exclude_recent, "tolerance": tolerance})
    if "seconds" in res and len(res["seconds"]):
        sec = np.asarray(res["seconds"], np.float64)
        m["loop_seconds_per_frame"], m["loop_seconds_per_frame_end"] = float(sec.mean()), tail_mean(sec, 0.1)
        if "map_size" in res:
            m["map_size_end"] = int(res["map_size"][-1])
    # without a threshold of its own the method's figures are the curve's: no n/a in the headline
    m["headline"] = ["recall_at_100_precision", "auc_pr"] + (
        ["precision_at_threshold", "recall_at_threshold"] if threshold is not None else ["max_f1"]) + ["seconds_per_frame"]
    pos = {int(f): k for k, f in enumerate(frames)}
    return LoopEvaluation("loops", res, metrics=m, names=names, candidate=candidate, correct=correct, has_loop=has_loop,
                          example=example, pr=pr, truth=truth, tolerance=tolerance, accepted=accepted,
                          # the match as a position in the frame list (for pictures drawn over method arrays)
                          match_local=np.array([pos.get(int(j), -1) if c else -1 for j, c in zip(match, candidate)],
                                               np.int64))


def finish(ctx: Any, ev: LoopEvaluation, plots: bool = True) -> None:
    """evaluate.h5's PR curve and per-frame correctness, per_query.csv (one row per frame),
    pr_curve.png and, with times, time_per_frame.png."""
    import csv

    from placeloc.core.artifacts import atomic_open
    from placeloc.evaluation.pictures import draw

    res, pr = ev.result, ev.pr
    g = ctx.out.create_group("pr")
    for name, arr in (("threshold", pr.thresholds), ("precision", pr.precision), ("recall", pr.recall)):
        g.create_dataset(name, data=arr)
    ctx.out.create_dataset("correct", data=ev.correct)
    ctx.out.create_dataset("has_loop", data=ev.has_loop)
    names = ev.names
    with atomic_open(ctx.output("per_query.csv"), newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["query", "query_image", "has_positive", "positive_reference", "positive_image", "best_reference",
                    "best_image", "confidence", "candidate", "accepted", "correct"])
        for k, i in enumerate(res["frame_index"]):
            j, e = int(res["match"][k]), int(ev.example[k])
            cand = bool(ev.candidate[k])
            w.writerow([int(i), names[i], int(ev.has_loop[k]), e if e >= 0 else "", names[e] if e >= 0 else "",
                        j if cand else "", names[j] if cand else "", f"{res['confidence'][k]:.6f}", int(cand),
                        int(ev.accepted[k]), int(ev.correct[k])])
    if not plots:
        return
    from placeloc.evaluation import plots as P  # only with pictures (see ranked.finish)

    m = ev.metrics
    draw(P.plot_pr_curves, {ev.label: (pr.recall, pr.precision), **ev.pr_curves}, ctx.output("pr_curve.png"),
         title=f"Loop closure precision-recall\n({m['frames_with_loop']} of {m['n_frames']} "
               f"frames close a loop; pairs < {m['exclude_recent']} frames apart never count)",
         xlabel="recall (share of the frames that close a loop, closed correctly)")
    if "seconds" in res and "map_size" in res and len(res["seconds"]):
        draw(plot_time_per_frame, ctx.output("time_per_frame.png"), res["map_size"], res["seconds"], ev.label)


def plot_time_per_frame(path: Path, map_size: np.ndarray, seconds: np.ndarray, label: str) -> Path:
    """Each frame's loop-closure time against the map's size when it arrived: does the
    method slow down as the map grows. Drawn in pixels (:mod:`.raster`)."""
    from placeloc.evaluation import raster as R

    x = np.asarray(map_size, np.float64)
    ms = np.asarray(seconds, np.float64) * 1e3
    ok = np.isfinite(x) & np.isfinite(ms)
    xhi = float(x[ok].max()) if ok.any() else 1.0
    yhi = float(ms[ok].max()) if ok.any() else 1.0
    xlim, ylim = (0.0, max(xhi, 1.0) * 1.03), (0.0, max(yhi, 1e-3) * 1.05)
    c = R.Canvas(660, 458)
    ax = R.Axes(c, (80, 54, 640, 394), xlim, ylim)
    ax.frame(R.nice_ticks(*xlim, most=7), R.nice_ticks(*ylim, most=7), size=12)
    # one series: its name in the title, where a legend box in a corner hid the slowest
    # frames (PIRF-nav2's 2.5 ms frame at map size 108 on the smoke run lay under it)
    ax.labels("map size when the frame arrived", "time per frame [ms]",
              f"Loop-closure time per frame against the size of the map\n{label}, {int(ok.sum())} frames", size=13,
              title_size=14)
    ax.markers(x[ok], ms[ok], R.CYCLE[0], "o", 4.0)
    return c.save(path)


def headline(metrics: dict[str, Any]) -> list[str]:
    return list(metrics.get("headline") or ["recall_at_100_precision", "auc_pr"])


def show(run_dir: Path, res: Result | None = None, *, sample: int = 8, failures: int = 8,
         out_dir: Path | None = None, ev: LoopEvaluation | None = None,
         config: dict[str, Any] | None = None) -> list[Path]:
    """Strips frame | matched earlier frame | a true earlier one, for the accepted loop
    closures spread over the traverse (and the most confident wrong ones); from the
    evaluation ``ev`` when evaluate draws them, else from per_query.csv or the result;
    the image folders from ``config`` (the evaluate stage's), else the run's artifacts."""
    from placeloc.evaluation.show import draw_strips, read_rows, zero_confidence_note

    run_dir = Path(run_dir)
    out_dir = Path(out_dir) if out_dir is not None else run_dir
    source = out_dir if (out_dir / "per_query.csv").is_file() else run_dir
    if ev is not None:
        rows = strip_rows(ev)
    else:
        rows = accepted_rows(source / "per_query.csv") if (source / "per_query.csv").is_file() else None
    if rows is None:
        rows = read_rows(run_dir, only_matched=True)
        threshold = (res or _result(run_dir)).attrs.get("threshold")
        if threshold is not None:  # only the loop closures the method accepts
            rows = [r for r in rows if r.confidence >= float(threshold)]
    # "loop closures" also tells draw_strips that the matched frames are in the same traverse
    return draw_strips(run_dir, sample=sample, failures=failures, rows=rows, what="loop closures", out_dir=out_dir,
                       config=config, zero_note=zero_confidence_note(run_dir, ev.result if ev is not None else res))


def strip_rows(ev: LoopEvaluation) -> list[Any]:
    """:func:`accepted_rows` straight from the evaluation: the accepted loop closures as
    per_query.csv writes them (confidence to six decimals)."""
    from placeloc.evaluation.show import Row

    res, names = ev.result, ev.names
    rows = []
    for k, i in enumerate(res["frame_index"]):
        if not ev.accepted[k]:
            continue
        j, e = int(res["match"][k]), int(ev.example[k])
        cand = bool(ev.candidate[k])
        rows.append(Row(names[i], names[j] if cand else "", float(f"{res['confidence'][k]:.6f}"), bool(ev.correct[k]),
                        names[e] if e >= 0 else ""))
    return rows


def accepted_rows(per_query: Path) -> list[Any]:
    """The loop closures the method accepted (``accepted`` 1 in per_query.csv: old enough and
    at or above its threshold) as strip rows, judged: the strips count what ``n_accepted``
    and ``n_accepted_right`` count."""
    import csv

    from placeloc.evaluation.show import Row

    return [Row(r["query_image"], r["best_image"], float(r["confidence"]), r["correct"] == "1", r["positive_image"])
            for r in csv.DictReader(read_run_table(per_query.parent, per_query.name)) if r["accepted"] == "1"]


def _result(run_dir: Path) -> Result:
    from placeloc.evaluation.contracts import localize_result

    res = localize_result(run_dir)
    assert res is not None  # show() is reached only for a run with a loops result
    return res
