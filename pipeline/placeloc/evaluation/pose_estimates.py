"""The ``poses`` contract: a metric pose estimate per query image (UMap).

``localize.h5/result``: ``names`` (Q) image file names, ``x``, ``y`` (Q) metres, optional
``z``, ``heading_deg`` (Q, NaN: not estimated), ``score`` (Q, the method's score of the
estimate), optional ``plan_segments`` (S x 4: x0, y0, x1, y1 in metres, the walls drawn
under the estimates), ``plan_openings`` (G x 4: the ends of doors and openings, drawn as
gaps in those walls) and ``plan_labels`` with ``plan_label_xy`` (L and L x 2: names of
places, such as rooms, written on the plan there). Scored against a poses CSV (``ground_truth.kind: poses``; frame
name, x, y[, heading]; :func:`placeloc.evaluation.poses.read_poses`), which must hold a
row for every query image: checked before any stage runs.

``metrics.json`` schema (``poses``): ``within_1m_30deg`` (the headline: share of frames
within 1 m and 30 degrees, when the truth has headings), ``within_0_5m``, ``within_1m``,
``within_2m``, ``median_error_m``, ``mean_error_m``, ``max_error_m``, ``n_frames``; with
headings also ``median_yaw_error_deg``, ``yaw_within_10deg``, ``yaw_within_30deg``,
``within_0_5m_30deg``, ``within_2m_30deg``; with a ``confidence`` also
``confidence_average_precision``, ``kept_at_100_precision``,
``confidence_threshold_at_100_precision``, ``confidence_right_if``, ``confidence_label`` and
``n_without_confidence`` (:func:`confidence_metrics`); ``headline``.

An optional ``confidence`` (Q, higher = more trusted, NaN: the method could not tell) says
which answers to trust; its ``confidence_label`` attribute names it in pictures. Results
without it are scored exactly as before it existed. An optional ``alternative`` (Q x 2,
metres; NaN rows: none) is a second place the method could not rule out for a doubtful
answer (UMap: the rival of an answer whose margin is below ``doubtful_margin``), drawn on
the plan beside the answer; it is not scored here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from placeloc.core.safe_io import read_run_table
from placeloc.evaluation import raster as R
from placeloc.evaluation.contracts import Field, PoseEvaluation, Result, write_result

# common config sections the evaluate stage reads
SECTIONS = ("ground_truth", "plots")
# evaluate draws show()'s pictures too (strips); False: finish() already drew them
SHOW_AT_EVALUATE = False
# show()'s --sample and --failures choose the queries it draws (strips); False: it draws the whole result
# at once, and they choose nothing (placeloc show says so)
CHOOSES_QUERIES = False

SCHEMA = {
    "names": Field("str", ("Q",)),
    "x": Field("float", ("Q",)),
    "y": Field("float", ("Q",)),
    "z": Field("float", ("Q",), optional=True),
    "heading_deg": Field("float", ("Q",)),
    "score": Field("float", ("Q",)),
    "plan_segments": Field("float", ("S", "4"), optional=True),
    "plan_openings": Field("float", ("G", "4"), optional=True),
    "plan_labels": Field("str", ("L",), optional=True),
    "plan_label_xy": Field("float", ("L", "2"), optional=True),
    "confidence": Field("float", ("Q",), optional=True),
    "alternative": Field("float", ("Q", "2"), optional=True),
}

METRICS_DOC = {
    "within_1m_30deg": "share of frames within 1 m and 30 degrees of the truth (headline)",
    "within_0_5m / within_1m / within_2m": "share of frames within that distance",
    "median_error_m": "median position error in metres",
    "confidence_average_precision": "average precision of the right answers ranked by the method's confidence "
                                    "(right: within 1 m and 30 degrees, or 1 m without true headings)",
    "kept_at_100_precision": "largest share of all frames a confidence threshold keeps with every kept answer right",
    "confidence_threshold_at_100_precision": "the lowest confidence kept at that point (n/a: none can be kept)",
    "seconds_per_frame": "wall seconds of every stage before evaluate (extraction included) per frame",
    "within_1m_30deg_or_rival": "share of frames whose answer is right, or doubtful with its rival (the alternative "
                                "ringed on the plan) right: what checking both places of each doubtful answer finds (UMap)",
    "doubtful_answers / doubtful_wrong / doubtful_wrong_rival_right": "answers whose margin is below doubtful_margin; of "
                                                                      "those, the wrong ones; of those, the ones whose "
                                                                      "rival is right (UMap)",
}
# counts (kept apart from the scores in metrics.json)
COUNTS = ("n_frames",)


def write(ctx: Any, *, names: Sequence[str], x: np.ndarray, y: np.ndarray, heading_deg: np.ndarray, score: np.ndarray,
          z: np.ndarray | None = None, plan_segments: np.ndarray | None = None, label: str = "estimates",
          confidence: np.ndarray | None = None, confidence_label: str = "confidence",
          alternative: np.ndarray | None = None, plan_openings: np.ndarray | None = None,
          plan_labels: Sequence[str] | None = None, plan_label_xy: np.ndarray | None = None) -> None:
    """Write the contract into ``ctx.out/result``; ``label`` names the estimates in pictures.
    ``confidence`` (per frame, higher = more trusted, NaN = cannot tell), when given, is
    named by ``confidence_label`` (e.g. "score margin over the best rival pose");
    ``alternative`` (Q, 2) a doubtful answer's second place (NaN rows: none);
    ``plan_openings`` (G, 4) door and opening ends; ``plan_labels`` names written on the
    plan at ``plan_label_xy`` (L, 2)."""
    if (plan_labels is None) != (plan_label_xy is None) or (
            plan_labels is not None and len(plan_labels) != len(np.asarray(plan_label_xy).reshape(-1, 2))):
        raise ValueError("plan_labels and plan_label_xy go together, one position a label")
    attrs = {"label": label}
    if confidence is not None:
        attrs["confidence_label"] = confidence_label
    write_result(ctx.out, "poses", {
        "names": list(names), "x": np.asarray(x, np.float64), "y": np.asarray(y, np.float64),
        "z": None if z is None else np.asarray(z, np.float64), "heading_deg": np.asarray(heading_deg, np.float64),
        "score": np.asarray(score, np.float64),
        "plan_segments": None if plan_segments is None else np.asarray(plan_segments, np.float64).reshape(-1, 4),
        "confidence": None if confidence is None else np.asarray(confidence, np.float64),
        "alternative": None if alternative is None else np.asarray(alternative, np.float64).reshape(-1, 2),
        "plan_openings": None if plan_openings is None else np.asarray(plan_openings, np.float64).reshape(-1, 4),
        "plan_labels": None if plan_labels is None else [str(n) for n in plan_labels],
        "plan_label_xy": None if plan_label_xy is None else np.asarray(plan_label_xy, np.float64).reshape(-1, 2)},
        attrs=attrs)


# ---------------------------------------------------------------------------------------
# ground truth
# ---------------------------------------------------------------------------------------
def true_poses(section: dict[str, Any], names: Sequence[str]) -> tuple[Any, np.ndarray]:
    """The poses file and the row of each query name in it (one error naming the file,
    the missing frame and the fix)."""
    from placeloc.evaluation.ground_truth import GroundTruthError
    from placeloc.evaluation.poses import PoseError, read_poses

    if section.get("kind") != "poses":
        raise GroundTruthError(f"ground_truth.kind is {section.get('kind')!r}; pose estimates are scored against poses: "
                               "set ground_truth.kind: poses and ground_truth.path to a CSV with frame, x, y[, heading]")
    try:
        gt = read_poses(section["path"], what="ground_truth.path")
        return gt, gt.rows_for_names(list(names), what="query frames")
    except PoseError as exc:
        raise GroundTruthError(str(exc)) from None


def check_ground_truth(config: dict[str, Any], method: Any) -> None:
    """Before any stage: the poses file parses and holds a row for every query image."""
    from placeloc.core.images import ImageError, list_images

    section = config.get("ground_truth") or {}
    if section.get("kind", "none") == "none":
        return
    names: list[str] = []
    if config.get("query") and config["query"].get("images"):
        try:
            names = list(list_images(config["query"]["images"]).names)
        except ImageError:
            return  # the image check reports this one
    true_poses(section, names)


# ---------------------------------------------------------------------------------------
# metrics (plain arrays)
# ---------------------------------------------------------------------------------------
def error_metrics(err: np.ndarray) -> dict[str, Any]:
    """Max, mean, median plan error (metres) and the share of frames within 0.5 m and 1 m."""
    err = np.asarray(err, float)
    return {"max_error_m": float(err.max()), "mean_error_m": float(err.mean()), "median_error_m": float(np.median(err)),
            "within_0_5m": float(np.mean(err <= 0.5)), "within_1m": float(np.mean(err <= 1.0)), "n_frames": int(len(err))}


def yaw_errors(est_deg: np.ndarray, truth_deg: np.ndarray) -> np.ndarray:
    """Absolute heading differences in degrees, wrapped into [0, 180]."""
    return np.abs((np.asarray(est_deg, float) - np.asarray(truth_deg, float) + 180.0) % 360.0 - 180.0)


def recall_metrics(err_m: np.ndarray, yaw_err_deg: np.ndarray | None) -> dict[str, Any]:
    """Share of frames within 2 m, and when headings are known the median yaw error, the
    share within 10 and 30 degrees, and within 0.5 m / 1 m / 2 m *and* 30 degrees."""
    err_m = np.asarray(err_m, float)
    out: dict[str, Any] = {"within_2m": float(np.mean(err_m <= 2.0))}
    if yaw_err_deg is not None:
        y = np.asarray(yaw_err_deg, float)
        out.update({"median_yaw_error_deg": float(np.median(y)), "yaw_within_10deg": float(np.mean(y <= 10.0)),
                    "yaw_within_30deg": float(np.mean(y <= 30.0)),
                    "within_0_5m_30deg": float(np.mean((err_m <= 0.5) & (y <= 30.0))),
                    "within_1m_30deg": float(np.mean((err_m <= 1.0) & (y <= 30.0))),
                    "within_2m_30deg": float(np.mean((err_m <= 2.0) & (y <= 30.0)))})
    return out


# what makes an answer right when its confidence is judged: the headline's 1 m and 30 degrees
RIGHT_M, RIGHT_DEG = 1.0, 30.0
# wrong answers named on the plan picture: enough to find the failures of a home's tour,
# few enough that the names stay legible
NAMED_WRONG = 12


def right_answers(err_m: np.ndarray, yaw_err_deg: np.ndarray | None) -> np.ndarray:
    """Per frame, whether the estimate is within ``RIGHT_M`` of the truth and, when the truth
    has headings, within ``RIGHT_DEG`` of its heading (without headings: the distance alone)."""
    right = np.asarray(err_m, float) <= RIGHT_M
    return right if yaw_err_deg is None else right & (np.asarray(yaw_err_deg, float) <= RIGHT_DEG)


@dataclass(frozen=True)
class ConfidenceCurve:
    """The answers kept as a confidence threshold falls: one point per threshold a user can
    set, i.e. per run of equal confidences (highest first), each kept or dropped whole; the
    frames without a confidence (NaN) form the last run. ``threshold``: the run's confidence
    (NaN for the last run of frames without one); ``kept``, ``right``: frames kept and right
    answers among them, counted up to and including the run; ``n``: all frames."""

    threshold: np.ndarray
    kept: np.ndarray
    right: np.ndarray
    n: int

    @property
    def kept_share(self) -> np.ndarray:
        return self.kept / max(self.n, 1)

    @property
    def precision(self) -> np.ndarray:
        return self.right / np.maximum(self.kept, 1)

    @property
    def last_all_right(self) -> int:
        """The last run whose kept answers are all right (-1: the first run holds a wrong one).
        The runs at 100 % precision lead: once a wrong answer is kept it stays kept."""
        perfect = np.flatnonzero(self.right == self.kept)
        return int(perfect[-1]) if len(perfect) and perfect[0] == 0 else -1


def confidence_curve(confidence: np.ndarray, right: np.ndarray) -> ConfidenceCurve:
    """:class:`ConfidenceCurve` of answers with ``confidence`` (NaN: ranked below every
    finite value) that are ``right`` (bool). Not :func:`placeloc.evaluation.metrics.pr_curve`:
    that one has no run of NaN frames and gives no kept count where the precision is 0."""
    conf = np.asarray(confidence, np.float64)
    right = np.asarray(right, bool)
    nan = np.isnan(conf)
    key = np.where(nan, 0.0, -conf)
    order = np.lexsort((key, nan))  # frames with a confidence first, each by confidence, highest first
    key, nan = key[order], nan[order]
    last = np.r_[(key[1:] != key[:-1]) | (nan[1:] != nan[:-1]), True] if len(conf) else np.zeros(0, bool)
    kept = np.arange(1, len(conf) + 1)[last]
    return ConfidenceCurve(conf[order][last], kept, np.cumsum(right[order])[last], len(conf))


def confidence_metrics(confidence: np.ndarray, right: np.ndarray) -> dict[str, Any]:
    """How well ``confidence`` ranks the ``right`` answers above the wrong ones.

    - ``kept_at_100_precision``: the largest share of all frames that a threshold keeps with
      every kept answer right (0 when the most confident run holds a wrong answer);
    - ``confidence_threshold_at_100_precision``: the lowest confidence kept there (None when
      nothing can be kept, or when every frame is right and the last run kept has no
      confidence);
    - ``confidence_average_precision``: non-interpolated average precision (as in
      scikit-learn's ``average_precision_score``): over the threshold runs, the precision of
      the answers kept weighted by the share of all right answers the run adds; 1 when every
      right answer ranks above every wrong one, the share of right answers when the
      confidence is one value for all; None when no answer is right;
    - ``n_without_confidence``: frames whose confidence is NaN."""
    curve = confidence_curve(confidence, right)
    best = curve.last_all_right
    threshold = float(curve.threshold[best]) if best >= 0 else float("nan")
    n_right = int(curve.right[-1]) if len(curve.right) else 0
    added = np.diff(np.r_[0, curve.right])
    return {"confidence_average_precision": float(np.sum(added * curve.precision) / n_right) if n_right else None,
            "kept_at_100_precision": float(curve.kept_share[best]) if best >= 0 else 0.0,
            "confidence_threshold_at_100_precision": None if np.isnan(threshold) else threshold,
            "n_without_confidence": int(np.isnan(np.asarray(confidence, np.float64)).sum())}


# ---------------------------------------------------------------------------------------
# evaluate, pictures
# ---------------------------------------------------------------------------------------
def evaluate(ctx: Any, res: Result) -> PoseEvaluation:
    """Read the true poses of the result's frames and :func:`score` the result."""
    from placeloc.core.errors import StageError

    section = ctx.config["ground_truth"]
    if section["kind"] == "none":
        raise StageError("ground_truth.kind is none: evaluate needs the true poses (ground_truth.kind: poses); "
                         "`placeloc show RUN_DIR` draws the estimates without it")
    gt, rows = true_poses(section, res["names"])
    ev = score(res, gt, rows)
    problem = truth_off_the_map(ev.truth, res.get("plan_segments"))
    if problem is not None:
        import logging

        logging.getLogger("placeloc").warning("%s: %s", section["path"], problem)
    return ev


def truth_off_the_map(truth: np.ndarray, plan_segments: np.ndarray | None, margin_m: float = 1.0) -> str | None:
    """A sentence when most true positions lie more than ``margin_m`` outside the extent of
    the map's walls (``plan_segments`` x0 y0 x1 y1): poses in centimetres or millimetres, or
    in another frame than the map's, which otherwise show only as errors of hundreds of
    metres. None when at least half lie on the map, or without a map."""
    if plan_segments is None or not len(plan_segments) or not len(truth):
        return None
    pts = np.vstack([plan_segments[:, :2], plan_segments[:, 2:4]])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    t = np.asarray(truth, float)
    off = np.any((t < lo - margin_m) | (t > hi + margin_m), axis=1)
    if off.sum() * 2 <= len(t):
        return None
    span_map = float(np.hypot(*(hi - lo)))
    span_truth = float(np.hypot(*(t.max(axis=0) - t.min(axis=0))))
    ratio = span_truth / max(span_map, 1e-9)
    unit = next((f" (their spread is {ratio:.0f} times the map's: {name}?)" for name, k in
                 (("centimetres", 100), ("millimetres", 1000), ("feet", 3.28)) if 0.7 * k <= ratio <= 1.4 * k), "")
    return (f"{int(off.sum())} of {len(t)} true positions lie outside the map (x {lo[0]:.1f} to {hi[0]:.1f}, y {lo[1]:.1f} "
            f"to {hi[1]:.1f} m; the truth spans x {t[:, 0].min():.1f} to {t[:, 0].max():.1f}, y {t[:, 1].min():.1f} to "
            f"{t[:, 1].max():.1f}){unit}; give the poses in metres in the map's frame")


def score(res: Result, gt: Any, rows: np.ndarray) -> PoseEvaluation:
    """Score a ``poses`` result against the true poses ``gt`` (row ``rows[k]`` for frame k):
    position errors in metres and, with true headings, yaw errors in degrees."""
    truth = gt.xy[rows]
    est = np.stack([res["x"], res["y"]], axis=1)
    err = np.hypot(*(est - truth).T)
    truth_heading = np.degrees(gt.heading[rows]) if gt.heading is not None else None
    yaw_err = yaw_errors(res["heading_deg"], truth_heading) if truth_heading is not None else None
    metrics = error_metrics(err)
    metrics.update(recall_metrics(err, yaw_err))
    if res.get("confidence") is not None:
        metrics.update(confidence_metrics(res["confidence"], right_answers(err, yaw_err)))
        metrics["confidence_right_if"] = "within_1m_30deg" if yaw_err is not None else "within_1m"
        metrics["confidence_label"] = _confidence_label(res)
    metrics["headline"] = (["within_1m_30deg"] if yaw_err is not None else []) + [
        "within_0_5m", "within_1m", "within_2m", "median_error_m", "seconds_per_frame"]
    ev = PoseEvaluation("poses", res, metrics=metrics, label=str(res.attrs.get("label", "")), truth=truth, est=est,
                        err=err, yaw_err=yaw_err, truth_heading=truth_heading, poses=gt, rows=rows)
    ev.arrays = {"error_m": err, "truth_xy": truth, **({"yaw_error_deg": yaw_err} if yaw_err is not None else {})}
    return ev


def finish(ctx: Any, ev: PoseEvaluation, plots: bool = True) -> None:
    """per_query.csv (estimate, truth and error per frame; the confidence last when the
    result has one), error_cdf.png, estimates_on_plan.png and, with a confidence,
    confidence.png."""
    import csv

    from placeloc.core.artifacts import atomic_open

    res = ev.result
    confidence = res.get("confidence")
    with atomic_open(ctx.output("per_query.csv"), newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "x", "y", "heading_deg", "true_x", "true_y", "true_heading_deg", "error_m", "yaw_error_deg",
                    "score"] + ([] if confidence is None else ["confidence"]))
        for k, name in enumerate(res["names"]):
            th = ev.truth_heading
            w.writerow([name, f"{res['x'][k]:.3f}", f"{res['y'][k]:.3f}", f"{res['heading_deg'][k]:.1f}",
                        f"{ev.truth[k, 0]:.3f}", f"{ev.truth[k, 1]:.3f}", "" if th is None else f"{th[k]:.1f}",
                        f"{ev.err[k]:.3f}", "" if ev.yaw_err is None else f"{ev.yaw_err[k]:.1f}", f"{res['score'][k]:.5f}"]
                       + ([] if confidence is None else ["" if np.isnan(confidence[k]) else f"{confidence[k]:.5f}"]))
    if not plots:
        return
    from placeloc.evaluation.pictures import draw  # on threads beside the stage's other work (pictures.py)

    label = ev.label
    draw(plot_error_cdf, ctx.output("error_cdf.png"), ev.err, label)
    draw(plot_estimates_on_plan, ctx.output("estimates_on_plan.png"), ev.truth, ev.est, [], _segments6(res), label,
         ev.truth_heading, res["heading_deg"], names=res["names"], alternative=res.get("alternative"), **_plan_marks(res))
    if confidence is not None:
        from placeloc.evaluation.plots import plot_kept_precision

        right = right_answers(ev.err, ev.yaw_err)
        curve = confidence_curve(confidence, right)
        draw(plot_kept_precision, ctx.output("confidence.png"), curve.kept, curve.right, curve.n,
                            confidence_label=_confidence_label(res), label=label,
                            right_means="within 1 m and 30°" if ev.yaw_err is not None else "within 1 m",
                            kept_at_100=int(curve.kept[curve.last_all_right]) if curve.last_all_right >= 0 else 0,
                            threshold=ev.metrics["confidence_threshold_at_100_precision"])


def _confidence_label(res: Result) -> str:
    return str(res.attrs.get("confidence_label", "confidence"))


def _segments6(res: Result) -> np.ndarray:
    """plan_segments (x0, y0, x1, y1) in the (x0, y0, z0, x1, y1, z1) layout the plan plot reads."""
    s = res.get("plan_segments")
    if s is None or not len(s):
        return np.zeros((0, 6))
    z = np.zeros(len(s))
    return np.column_stack([s[:, 0], s[:, 1], z, s[:, 2], s[:, 3], z])


def _plan_marks(res: Result) -> dict[str, Any]:
    """The plan picture's doors and place names from a result (absent: none)."""
    return {"openings": res.get("plan_openings"), "labels": res.get("plan_labels"), "label_xy": res.get("plan_label_xy")}


def headline(metrics: dict[str, Any]) -> list[str]:
    return list(metrics.get("headline") or ["within_1m", "median_error_m"])


def show(run_dir: Path, res: Result | None = None, *, sample: int = 8, failures: int = 8,
         out_dir: Path | None = None, ev: Any = None,
         config: dict[str, Any] | None = None) -> list[Path]:
    """The estimates on the plan: against the truth when evaluate has run (per_query.csv),
    else the estimates alone."""
    import csv

    from placeloc.evaluation.contracts import localize_result

    run_dir = Path(run_dir)
    out_dir = Path(out_dir) if out_dir is not None else run_dir
    res = res or localize_result(run_dir)
    est = np.stack([res["x"], res["y"]], axis=1)
    truth = truth_heading = None
    per_query = next((d / "per_query.csv" for d in (out_dir, run_dir) if (d / "per_query.csv").is_file()), out_dir / "x")
    if per_query.is_file():
        rows = {r["frame"]: r for r in csv.DictReader(read_run_table(per_query.parent, per_query.name))}  # no link followed
        if all(n in rows for n in res["names"]):
            truth = np.array([[float(rows[n]["true_x"]), float(rows[n]["true_y"])] for n in res["names"]])
            if all(rows[n]["true_heading_deg"] for n in res["names"]):
                truth_heading = np.array([float(rows[n]["true_heading_deg"]) for n in res["names"]])
    path = out_dir / "estimates_on_plan.png"
    plot_estimates_on_plan(path, truth, est, [], _segments6(res), str(res.attrs.get("label", "estimates")), truth_heading,
                           res["heading_deg"], names=res["names"], alternative=res.get("alternative"), **_plan_marks(res))
    return [path]


def worst_wrong(err_m: np.ndarray, wrong: np.ndarray, limit: int = NAMED_WRONG) -> list[int]:
    """The frames of the ``wrong`` answers, the largest position error first (ties in frame
    order), at most ``limit``: those the plan picture names."""
    return [int(k) for k in np.argsort(-np.asarray(err_m, float), kind="stable") if wrong[k]][:limit]


# the error axis' ticks, where they fall within it: plain numbers on a log scale
ERROR_TICKS = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000)
GREEN, ORANGE, BLUE, RED = R.CYCLE[2], R.CYCLE[1], R.CYCLE[0], R.CYCLE[3]


def _error_axes(c: R.Canvas, box: tuple[float, float, float, float], largest: float, title: str) -> R.Axes:
    """A log error axis from 1 cm to past ``largest`` (at least 2 m) with plain-number
    ticks, shares 0 to 1 up the side, framed and labelled."""
    lo, hi = 0.01, max(2.0, float(largest) * 1.5)
    ax = R.Axes(c, box, (lo, hi), (0.0, 1.02), xlog=True)
    ticks = [t for t in ERROR_TICKS if lo <= t <= hi]
    shares = np.round(np.arange(0, 1.01, 0.2), 1)
    ax.frame(ticks, shares, xlabels=[f"{t:g}" for t in ticks], size=12)
    ax.labels("position error [m] (log scale)", "share of frames", title, size=13, title_size=14)
    return ax


def _cdf_steps(err: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cumulative share of ``err`` (floored at 1 cm for the log axis) as the corners of
    its steps: at each sorted error the share rises to include it."""
    e = np.sort(np.maximum(np.asarray(err, float), 0.01))
    share = np.arange(1, len(e) + 1) / len(e)
    return np.repeat(e, 2)[1:], np.repeat(share, 2)[:-1]


def plot_error_cdf(path: Path, err: np.ndarray, mode: str) -> Path:
    """Share of frames within each error, on a log axis with plain-number ticks, the 0.5 m
    and 1 m marks labelled with their shares."""
    err = np.asarray(err, float)
    c = R.Canvas(720, 480)
    ax = _error_axes(c, (70, 36, 700, 416), float(np.max(err[np.isfinite(err)], initial=0.0)),
                     f"Cumulative position error, {mode} ({len(err)} frames)")
    if len(err):
        ax.line(*_cdf_steps(err), BLUE, 2.5)
    for mark, colour, height in ((0.5, GREEN, 0.05), (1.0, ORANGE, 0.15)):
        share = float(np.mean(err <= mark)) if len(err) else 0.0
        ax.line(np.array([mark, mark]), np.array([0.0, 1.02]), colour, 1.6, "--")
        ax.text(mark * 1.05, height, f"{share:.0%} within {mark:g} m", 12, fill=colour, anchor="ls", box=(255, 255, 255))
    return c.save(path)


def plot_error_cdfs(path: Path, errors: dict[str, np.ndarray], title: str) -> Path:
    """Several runs' cumulative position errors on one log axis (a sweep's ``sweep.png``),
    each labelled with its share within 1 m and its median, the 1 m mark dashed. Runs with
    the same curve draw over each other: the legend says so by their equal figures."""
    runs = {label: np.asarray(e, float)[np.isfinite(np.asarray(e, float))] for label, e in errors.items()}
    runs = {label: e for label, e in runs.items() if len(e)}
    largest = max((float(e.max()) for e in runs.values()), default=0.0)
    c = R.Canvas(900, 560)
    ax = _error_axes(c, (70, 36, 880, 496), largest, title)
    ax.line(np.array([1.0, 1.0]), np.array([0.0, 1.02]), (102, 102, 102), 1.3, "--")
    entries = []
    for i, (label, e) in enumerate(runs.items()):
        colour, style = R.CYCLE[i % len(R.CYCLE)], R.DASHES_CYCLE[i % len(R.DASHES_CYCLE)]
        ax.line(*_cdf_steps(e), colour, 2.5, style)
        entries.append(R.LegendEntry(f"{label}: {np.mean(e <= 1.0):.0%} within 1 m, median {np.median(e):.2f} m",
                                     colour, line_width=2.5, style=style))
    ax.legend(entries, ("lower right", "upper left", "lower left", "upper right"), size=11)
    return c.save(path)


# a plan longer than this many times its width is cut into pieces drawn one above the other
PLAN_PIECE_RATIO = 3.5
# heading arrows: this long on the page (output pixels) whatever the plan's size, so they never hide an error line;
# twice as long where a picture has at most NAMED_WRONG frames (a few photos: which way each faced is what is read)
ARROW_PX = 15.0
# a plan no larger than this (metres, across and down) is shown whole: a home, where whoever located a photo wants to
# see where in the home it is; a larger one (a building's corridors) only around the frames (plan_view)
PLAN_WHOLE_M = 30.0
# the panels of the plan picture fill at most this many output pixels across and down
PLAN_AREA_PX = (1240.0, 980.0)


def plan_title(mode: str, truth: np.ndarray, est: np.ndarray, alternative: np.ndarray | None = None) -> str:
    """The plan picture's title against the truth: the frames within 1 m, and with
    alternatives (NaN rows: none) how many a look at both places finds, by distance as the
    count before it."""
    err = np.hypot(*(np.asarray(est, float) - truth).T)
    either = ""
    if alternative is not None and np.isfinite(alternative).all(axis=1).any():
        with np.errstate(invalid="ignore"):   # NaN rows: no alternative, never near
            near = np.hypot(*(np.asarray(alternative, float).reshape(-1, 2) - truth).T) <= 1.0
        either = f", {int(np.sum((err <= 1.0) | near))} counting the ringed alternatives"
    answered = np.isfinite(err)  # NaN: a frame the method gave no position for
    notes = ([f"median error {np.median(err[answered]):.2f} m"] if answered.any() else []) + (
        [f"{int(np.sum(~answered))} without an answer"] if not answered.all() else [])
    median = f" ({'; '.join(notes)})" if notes else ""
    return f"{mode}: {int(np.sum(err <= 1.0))} of {len(err)} frames within 1 m{either}{median}"


def plan_view(points: np.ndarray, walls: np.ndarray, *, margin_m: float = 2.0, reach: float = 1.5,
              whole_m: float = PLAN_WHOLE_M) -> tuple[np.ndarray, np.ndarray]:
    """The part of a plan a picture of ``points`` (N x 2: frames, answers, alternatives)
    shows, as (lo, hi) corners. A plan whose walls (M x 4: x0, y0, x1, y1) span at most
    ``whole_m`` metres across and down (a home) is shown whole, with the points. A larger
    one: the points' extent with a margin of ``margin_m`` (or 5 % of the extent, if more),
    widened to take in the walls that pass through that box, each as far as ``reach``
    margins beyond the points' extent (3 m by default): a frame in a room's corner shows the
    room's far walls up to 3 m away, and frames along part of a 90 m corridor do not show
    the whole of it. Then a pad of 2 % and 0.4 m, so that a corridor keeps its width."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    margin = np.maximum(0.05 * (hi - lo), margin_m)
    wlo, whi = lo - margin, hi + margin
    w = np.asarray(walls, float).reshape(-1, 4)
    w = w[np.isfinite(w).all(axis=1)]
    ends = np.vstack([w[:, :2], w[:, 2:]])
    if len(w) and np.all(ends.max(axis=0) - ends.min(axis=0) <= whole_m):
        lo, hi = np.minimum(lo, ends.min(axis=0)), np.maximum(hi, ends.max(axis=0))
    elif len(w):
        a, b = w[:, :2], w[:, 2:]
        # the walls whose bounding box meets the box (a wall crossing it with both ends outside included)
        meets = np.all((np.minimum(a, b) <= whi) & (np.maximum(a, b) >= wlo), axis=1)
        if meets.any():
            ends = np.clip(np.vstack([a[meets], b[meets]]), lo - reach * margin, hi + reach * margin)
            lo, hi = np.minimum(lo, ends.min(axis=0)), np.maximum(hi, ends.max(axis=0))
    pad = 0.02 * (hi - lo) + 0.4
    return lo - pad, hi + pad


def _pale(colour: R.Colour) -> R.Colour:
    """``colour`` half way to white: what half-opaque ink on a white page shows."""
    return tuple((np.asarray(colour) + 255) // 2)  # type: ignore[return-value]


def plot_estimates_on_plan(path: Path, truth: np.ndarray | None, est: np.ndarray, polys: list[np.ndarray], segments: np.ndarray,
                           mode: str, truth_heading_deg: np.ndarray | None = None,
                           est_heading_deg: np.ndarray | None = None, names: Sequence[str] | None = None,
                           alternative: np.ndarray | None = None, openings: np.ndarray | None = None,
                           labels: Sequence[str] | None = None, label_xy: np.ndarray | None = None,
                           grid: np.ndarray | None = None, title: str | None = None,
                           est_label: str | None = None, windows: np.ndarray | None = None) -> Path:
    """The plan (room polygons, or the wireframe's floor lines), true and estimated
    positions joined by error lines, headings as pale arrows of a fixed length on the page
    (drawn under the dots); a doubtful answer's ``alternative`` (Q x 2, NaN rows: none) as
    a hollow ring joined to its answer by a dotted line. With the truth and ``names``, the
    wrong answers (more than 1 m off, or more than 30 degrees where both headings are known;
    at most :data:`NAMED_WRONG`, the worst first) are named at their true position, so that
    the frame to look at is read off the picture. A long plan (a corridor) is cut into up to
    four pieces along its length, stacked (or side by side when it runs up the page), each
    to scale, so that it fills the picture instead of a thin strip in white space; the view
    covers the part of the plan the frames visit (a home: the whole plan, :func:`plan_view`).
    ``openings`` (G x 4: door and opening ends) are drawn as gaps in the walls, and ``labels``
    (room names) in grey from ``label_xy`` (their top left corner), under everything else.
    With a few frames (at most :data:`NAMED_WRONG`) the heading arrows are twice as long,
    and where there is no truth each answer is named where it lies. ``grid`` (P x 2): places
    drawn as small grey dots under everything (the places localize searches, ``placeloc
    plan``); ``windows`` (W x 4: their ends) drawn over their walls in green; ``title`` and
    ``est_label`` (the estimates' legend entry) in place of those made from the answers and
    ``mode``. Drawn in pixels
    (:mod:`.raster`)."""
    est = np.asarray(est, float)
    truth = est if truth is None else np.asarray(truth, float)  # estimates only (no ground truth): no error lines
    known = truth is not est
    alt = np.full((len(est), 2), np.nan) if alternative is None else np.asarray(alternative, float).reshape(-1, 2)
    has_alt = np.isfinite(alt).all(axis=1)
    frames = np.vstack([truth, est, alt[has_alt], np.zeros((0, 2)) if grid is None else np.asarray(grid, float).reshape(-1, 2)])
    frames = frames[np.isfinite(frames).all(axis=1)]
    if not len(frames):
        frames = np.zeros((1, 2))
    if polys:
        walls = np.vstack([np.column_stack([p, np.roll(p, -1, axis=0)]) for p in polys])
    else:
        walls = np.asarray(segments, float).reshape(-1, 6)[:, [0, 1, 3, 4]]
    lo, hi = plan_view(frames, walls)
    span = hi - lo
    along = 0 if span[0] >= span[1] else 1  # the plan's long axis
    pieces = int(np.clip(np.ceil(span[along] / span[1 - along] / PLAN_PIECE_RATIO), 1, 4))
    piece = span[along] / pieces
    extent = (piece, span[1]) if along == 0 else (span[0], piece)  # one panel's metres across and down
    # one scale (pixels a metre) for every panel and both axes: to scale, as large as the area allows
    gap = 34.0 if along == 0 else 64.0  # between panels: the upper one's x ticks, or the right one's y ticks
    if along == 0:
        scale = min(PLAN_AREA_PX[0] / extent[0], (PLAN_AREA_PX[1] - gap * (pieces - 1)) / (pieces * extent[1]))
    else:
        scale = min((PLAN_AREA_PX[0] - gap * (pieces - 1)) / (pieces * extent[0]), PLAN_AREA_PX[1] / extent[1])
    bw, bh = max(1, round(extent[0] * scale)), max(1, round(extent[1] * scale))
    content_w = bw if along == 0 else pieces * bw + (pieces - 1) * gap
    content_h = bh * pieces + gap * (pieces - 1) if along == 0 else bh

    err = np.hypot(*(est - truth).T)
    yaw_err = (yaw_errors(est_heading_deg, truth_heading_deg)
               if truth_heading_deg is not None and est_heading_deg is not None else None)
    wrong = ~right_answers(err, yaw_err) if known and names is not None else np.zeros(len(err), bool)
    named = worst_wrong(err, wrong)
    grey = (115, 115, 115)
    entries = ([R.LegendEntry("true position", BLUE, marker="o", marker_size=7.5)] if known else []) + (
        [R.LegendEntry(est_label or f"{mode} estimate", RED, marker="x", marker_size=9)] if len(est) else [])
    if has_alt.any():
        entries.append(R.LegendEntry(f"doubtful answer's alternative ({int(has_alt.sum())})", ORANGE, marker="O",
                                     marker_size=12))
    if known:
        entries.append(R.LegendEntry("error (truth to estimate)", grey, line_width=1.5))
    if truth_heading_deg is not None or est_heading_deg is not None:
        entries.append(R.LegendEntry("heading", (77, 77, 77), line_width=1.5, marker=">", marker_size=8))
    if named:
        entries.append(R.LegendEntry("wrong answer, named at its truth" + (f" ({len(named)} worst of {int(wrong.sum())})"
                                                                           if wrong.sum() > len(named) else ""),
                                     BLUE, text="ab"))
    cut = f"; the plan cut into {pieces} pieces along {'x' if along == 0 else 'y'}" if pieces > 1 else ""
    if grid is not None and len(grid):
        entries.insert(0, R.LegendEntry(f"grid place ({len(grid):,})", (160, 160, 160), marker="o", marker_size=3))
    if windows is not None and len(windows):
        entries.insert(0, R.LegendEntry(f"window ({len(windows)})", GREEN, line_width=4.0))
    title = (title if title is not None else plan_title(mode, truth, est, alt) if known else
             f"{mode}: {len(est)} estimate{'' if len(est) == 1 else 's'} (no ground truth)") + cut
    few = len(est) <= NAMED_WRONG
    arrow_px = 2.0 * ARROW_PX if few else ARROW_PX

    left, top, right = 70.0, 44.0, 24.0
    width = int(max(left + content_w + right, R.text_width(title, 14) + 40, 640))
    rows = R.legend_rows(entries, width - 40, size=12)
    bottom = 50.0 + R.legend_row_height(12) * len(rows) + 8
    c = R.Canvas(width, int(top + content_h + bottom))
    x_start = round(left + max(0.0, (width - left - right - content_w) / 2))
    c.text(width / 2, 28, title, 14, anchor="ms")
    k = c.ss
    for p in range(pieces):
        a0, a1 = lo[along] + p * piece, lo[along] + (p + 1) * piece
        xlim, ylim = ((a0, a1), (lo[1], hi[1])) if along == 0 else ((lo[0], hi[0]), (a0, a1))
        if along == 0:
            bx, by = x_start, round(top + p * (bh + gap))
        else:
            bx, by = round(x_start + p * (bw + gap)), round(top)
        # the panel drawn on its own canvas and pasted: what lies outside its piece is cut off
        panel = R.Canvas(bw, bh)
        ax = R.Axes(panel, (0, 0, bw, bh), xlim, ylim)
        if polys:
            for poly in polys:
                q = np.vstack([poly, poly[:1]])
                ax.segments(q[:-1, 0], q[:-1, 1], q[1:, 0], q[1:, 1], R.BLACK, 1.3)
        elif len(segments):
            ax.segments(segments[:, 0], segments[:, 1], segments[:, 3], segments[:, 4], R.BLACK, 0.8)
        if openings is not None and len(openings):
            # a door's span in white over its wall, then its jambs: a gap a reader sees as a way through
            o = np.asarray(openings, float).reshape(-1, 4)
            ax.segments(o[:, 0], o[:, 1], o[:, 2], o[:, 3], (255, 255, 255), 4.0)
            for ends in (o[:, :2], o[:, 2:]):
                ax.markers(ends[:, 0], ends[:, 1], R.BLACK, "o", 2.5)
        if windows is not None and len(windows):
            wn = np.asarray(windows, float).reshape(-1, 4)
            ax.segments(wn[:, 0], wn[:, 1], wn[:, 2], wn[:, 3], GREEN, 4.0)
        if grid is not None and len(grid):
            g = np.asarray(grid, float).reshape(-1, 2)
            ax.markers(g[:, 0], g[:, 1], (160, 160, 160), "o", 3)
        if labels is not None and label_xy is not None:
            for name, (lx, ly) in zip(labels, np.asarray(label_xy, float).reshape(-1, 2)):
                ax.text(lx, ly, str(name), 13, fill=(140, 140, 140), anchor="la")   # from the room's top left
        if known:
            ax.segments(truth[:, 0], truth[:, 1], est[:, 0], est[:, 1], grey, 1.5)
        for xy, hd, colour in ((truth, truth_heading_deg, BLUE), (est, est_heading_deg, RED)):
            if hd is not None:
                ax.arrows(xy[:, 0], xy[:, 1], np.asarray(hd, float), _pale(colour), arrow_px, 1.3)
        if known:
            ax.markers(truth[:, 0], truth[:, 1], BLUE, "o", 7.5)
        for e, a in zip(est[has_alt], alt[has_alt]):
            ax.line(np.array([e[0], a[0]]), np.array([e[1], a[1]]), ORANGE, 1.8, ":")
        ax.markers(est[:, 0], est[:, 1], RED, "x", 9, edge=2.2)
        ax.markers(alt[has_alt, 0], alt[has_alt, 1], ORANGE, "O", 12, edge=2.0)
        for j in named:
            ax.text(truth[j, 0], truth[j, 1], str(names[j]), 12, dx=6, dy=-6, fill=BLUE, anchor="ls")
        if not known and few and names is not None:  # no truth, a few photos: each answer named where it lies
            for j in np.flatnonzero(np.isfinite(est).all(axis=1)):
                ax.text(est[j, 0], est[j, 1], str(names[j]), 12, dx=8, dy=-8, fill=RED, anchor="ls")
        c.image.paste(panel.image, (bx * k, by * k))
        frame = R.Axes(c, (bx, by, bx + bw, by + bh), xlim, ylim)
        xt = R.nice_ticks(*xlim, most=max(3, int(bw / 90)))
        yt = R.nice_ticks(*ylim, most=max(3, int(bh / 70)))
        frame.frame(xt, yt, grid=False, size=11)
        last = p == pieces - 1
        frame.labels("x [m]" if along == 1 or last else "", "y [m]" if along == 0 or p == 0 else "", size=12)
    R.draw_legend_rows(c, rows, top + content_h + 50.0, size=12)
    return c.save(path)
