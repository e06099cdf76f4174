"""The ``map`` contract: mapped coordinates of features (co-embedding and its baselines).

``localize.h5/result``: ``feature_ids`` (M), ``coords`` (M x D), ``is_landmark`` (M: known
positions the map was tied to), optional path read-out ``path_step_ids`` (T),
``path_xy`` (T x 2), ``path_heading`` (T), ``path_label_steps`` (steps whose pose was
given). Scored against a truth points CSV (``feature,x,y[,z]``; the method names the
parameter holding it in ``Method(truth_keys={"points": ...})``): errors over the
features that are not landmarks, after the method's own alignment.

``metrics.json`` schema (``map``): ``map_rmse`` (the headline), ``map_median_error``,
``map_max_error``, ``n_evaluated``, ``n_truth_unobserved``, ``landmark_rmse``,
``n_features``, ``n_landmarks``; a method's hook adds its own (co-embedding: path errors);
``headline``.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

import numpy as np

from placeloc.core.safe_io import read_input_text, read_run_table
from placeloc.evaluation.contracts import Field, MapEvaluation, Result, write_result

# common config sections the evaluate stage reads (the truth is named by the method's own parameters)
SECTIONS = ("plots",)
# evaluate draws show()'s pictures too (strips); False: finish() already drew them
SHOW_AT_EVALUATE = False
# show()'s --sample and --failures choose the queries it draws (strips); False: it draws the whole result
# at once, and they choose nothing (placeloc show says so)
CHOOSES_QUERIES = False

SCHEMA = {
    "feature_ids": Field("int", ("M",)),
    "coords": Field("float", ("M", "D")),
    "is_landmark": Field("bool", ("M",)),
    "path_step_ids": Field("int", ("T",), optional=True),
    "path_xy": Field("float", ("T", "2"), optional=True),
    "path_heading": Field("float", ("T",), optional=True),
    "path_label_steps": Field("int", ("L",), optional=True),
}

METRICS_DOC = {
    "map_rmse": "root mean square distance of the mapped features (not landmarks) from the truth, in the truth file's units (headline)",
    "map_median_error / map_max_error": "median and largest of those distances",
    "n_evaluated": "features with a true position that were mapped",
    "path_rmse": "(co-embedding) error of the path read out at the steps without a given pose",
    "seconds_per_frame": "wall seconds of every stage before evaluate per observation step (co-embedding: n_steps)",
}
# counts (kept apart from the scores in metrics.json)
COUNTS = ("n_evaluated", "n_truth_unobserved", "n_features", "n_landmarks", "n_steps")


def write(ctx: Any, *, feature_ids: np.ndarray, coords: np.ndarray, is_landmark: np.ndarray,
          path: dict[str, np.ndarray] | None = None) -> None:
    """Write the contract into ``ctx.out/result``; ``path``: step_ids, xy, heading, label_steps."""
    path = path or {}
    write_result(ctx.out, "map", {"feature_ids": np.asarray(feature_ids, np.int64), "coords": np.asarray(coords, np.float64),
                                  "is_landmark": np.asarray(is_landmark, bool),
                                  **{f"path_{k}": v for k, v in path.items() if v is not None}})


def _truth_path(config: dict[str, Any], method: Any, role: str) -> str | None:
    key = (method.truth_keys or {}).get(role)
    return None if key is None else (config.get(method.name) or {}).get(key)


def read_points(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A truth points CSV ``feature,x,y[,z]`` with a header: ids (n,) and coordinates (n, d)."""
    from placeloc.evaluation.ground_truth import GroundTruthError

    path = Path(path)
    try:
        text = read_input_text(path, "truth points")
        header = next(csv.reader(io.StringIO(text, newline="")), None)
        if header is None or len(header) < 3:
            raise GroundTruthError(f"truth points: {path} needs a header row feature,x,y[,z]")
        data = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1, ndmin=2, dtype=np.float64)
    except (OSError, ValueError) as exc:  # UnsafeInputError is a ValueError
        raise GroundTruthError(f"truth points: {path} cannot be read as feature,x,y[,z] rows "
                               f"({' '.join(str(exc).split())})") from None
    if data.size == 0:
        data = np.zeros((0, len(header)))
    if not np.all(data[:, 0] == np.round(data[:, 0])):
        raise GroundTruthError(f"truth points: {path}: the feature column must hold integer ids")
    ids = data[:, 0].astype(np.int64)
    if len(np.unique(ids)) != len(ids):
        raise GroundTruthError(f"truth points: {path} lists a feature id twice")
    return ids, data[:, 1:]


def _rmse(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(err ** 2)))


def check_ground_truth(config: dict[str, Any], method: Any) -> None:
    """Before any stage: the truth points file parses."""
    path = _truth_path(config, method, "points")
    if path is not None and Path(path).is_file():
        read_points(path)


def map_errors(feature_ids: np.ndarray, coords: np.ndarray, is_landmark: np.ndarray, truth_ids: np.ndarray,
               truth_xyz: np.ndarray) -> tuple[dict, np.ndarray, np.ndarray]:
    """Errors over the non-landmark features that have a true position.

    Returns (metrics, estimates, truths) with the evaluated rows in map order. Features with a
    true position that were never observed cannot be mapped: they are counted, not hidden.
    """
    d = coords.shape[1]
    have = np.isin(feature_ids, truth_ids) & ~is_landmark
    order = {int(f): j for j, f in enumerate(truth_ids)}
    rows = np.array([order[int(f)] for f in feature_ids[have]], dtype=np.int64)
    est, truth = coords[have], truth_xyz[rows, :d]
    err = np.linalg.norm(est - truth, axis=1)
    out: dict = {"map_rmse": _rmse(err) if len(err) else None, "map_max_error": float(err.max()) if len(err) else None,
                 "map_median_error": float(np.median(err)) if len(err) else None, "n_evaluated": int(len(err)),
                 "n_truth_unobserved": int((~np.isin(truth_ids, feature_ids)).sum())}
    lm_rows = np.array([order[int(f)] for f in feature_ids[is_landmark] if int(f) in order], dtype=np.int64)
    if len(lm_rows) == int(is_landmark.sum()):
        out["landmark_rmse"] = _rmse(np.linalg.norm(coords[is_landmark] - truth_xyz[lm_rows, :d], axis=1))
    return out, est, truth




def evaluate(ctx: Any, res: Result) -> MapEvaluation:
    """Read the truth points the method names (``truth_keys["points"]``) and :func:`score` the map."""
    key = (ctx.method.truth_keys or {}).get("points")
    truth_path = None if key is None else getattr(ctx.params, key)
    if truth_path is None:
        return score(res, None, None)
    tid, txyz = read_points(truth_path)
    if txyz.shape[1] < res["coords"].shape[1]:
        from placeloc.evaluation.ground_truth import GroundTruthError

        raise GroundTruthError(f"truth file {truth_path} has {txyz.shape[1]} coordinates per row; the map is "
                               f"{res['coords'].shape[1]}-D")
    return score(res, tid, txyz)


def score(res: Result, truth_ids: np.ndarray | None, truth_xyz: np.ndarray | None) -> MapEvaluation:
    """Score a ``map`` result against true feature positions (none: the counts only); errors
    in the truth's units (the map is aligned to the truth)."""
    ids, coords, is_lm = res["feature_ids"], res["coords"], res["is_landmark"]
    m: dict[str, Any] = {"n_features": int(len(ids)), "n_landmarks": int(is_lm.sum()), "map_rmse": None,
                         "map_max_error": None}
    ev = MapEvaluation("map", res, metrics=m, landmarks=coords[is_lm])
    if truth_ids is not None and truth_xyz is not None:
        found, est, truth = map_errors(ids, coords, is_lm, truth_ids, truth_xyz)
        m.update(found)
        ev.est, ev.truth, ev.eval_ids = est, truth, ids[np.isin(ids, truth_ids) & ~is_lm]
    m["headline"] = ["map_rmse", "map_median_error", "map_max_error", "seconds_per_frame"]
    return ev


def finish(ctx: Any, ev: MapEvaluation, plots: bool = True) -> None:
    """per_query.csv (each evaluated feature: estimate, truth, error) and map.png."""
    from placeloc.core.artifacts import atomic_open

    if ev.est is None or ev.truth is None or ev.eval_ids is None:
        return
    with atomic_open(ctx.output("per_query.csv"), newline="") as fh:
        w = csv.writer(fh)
        d = ev.est.shape[1]
        w.writerow(["feature"] + [f"x{i}" for i in range(d)] + [f"true_x{i}" for i in range(d)] + ["error"])
        for f, e, t in zip(ev.eval_ids, ev.est, ev.truth):
            w.writerow([int(f), *(f"{v:.6g}" for v in e), *(f"{v:.6g}" for v in t), f"{np.linalg.norm(e - t):.6g}"])
    if plots:
        from placeloc.evaluation.pictures import draw as draw_on_thread  # beside the stage's other work

        draw_on_thread(draw, ctx.output("map.png"), ev)


def draw(path: Path, ev: MapEvaluation) -> Path:
    m = ev.metrics
    path_part = f"; path RMSE {m['path_rmse']:.3g}" if m.get("path_rmse") is not None else ""
    title = (f"{ev.label}, top view: map RMSE {m['map_rmse']:.3g}, max {m['map_max_error']:.3g}{path_part} (truth units)\n"
             f"({m['n_evaluated']} unknown features, {m['n_landmarks']} landmarks)")
    assert ev.est is not None and ev.truth is not None
    return plot_map(path, ev.est, ev.truth, ev.landmarks, ev.path_est, ev.path_truth, title, units="truth units")


def headline(metrics: dict[str, Any]) -> list[str]:
    return list(metrics.get("headline") or ["map_rmse"])


def show(run_dir: Path, res: Result | None = None, *, sample: int = 8, failures: int = 8,
         out_dir: Path | None = None, ev: Any = None,
         config: dict[str, Any] | None = None) -> list[Path]:
    """The map against the truth (from per_query.csv when evaluate has run), else the map alone."""
    from placeloc.evaluation.contracts import localize_result

    run_dir = Path(run_dir)
    out_dir = Path(out_dir) if out_dir is not None else run_dir
    res = res or localize_result(run_dir)
    coords, is_lm = res["coords"], res["is_landmark"]
    est = truth = None
    per_query = next((d / "per_query.csv" for d in (out_dir, run_dir) if (d / "per_query.csv").is_file()), out_dir / "x")
    if per_query.is_file():
        rows = list(csv.DictReader(read_run_table(per_query.parent, per_query.name)))  # no link followed
        d = coords.shape[1]
        if rows and f"true_x{d - 1}" in rows[0]:
            est = np.array([[float(r[f"x{i}"]) for i in range(d)] for r in rows])
            truth = np.array([[float(r[f"true_x{i}"]) for i in range(d)] for r in rows])
    if est is None:
        est = truth = coords[~is_lm]
    path = out_dir / "map.png"
    title = (f"map: {len(est)} features, {int(is_lm.sum())} landmarks" +
             ("" if est is truth else f"; RMSE {np.sqrt(np.mean(np.sum((est - truth) ** 2, axis=1))):.3g} (truth units)"))
    path_xy, path_truth = res.get("path_xy"), None
    evaluated = run_dir / "evaluate.h5"
    if evaluated.is_file() and est is not truth:  # the path against its truth, as evaluate drew it
        import h5py

        with h5py.File(evaluated, "r") as f:
            if "path_truth_xy" in f and "path_est_xy" in f:
                path_xy, path_truth = f["path_est_xy"][()], f["path_truth_xy"][()]
    plot_map(path, est, truth, coords[is_lm], path_xy, path_truth, title, units="map units" if est is truth else "truth units")
    return [path]


# The unknown features get a close-up beside the whole map where they fill less than this
# share of the whole map's extent along both axes: landmarks far from them (tears-of-steel's
# lie 45 m deep, its features 5-8 m) squeezed them into a corner where no error was visible.
CLOSE_UP_SHARE = 0.25


def plot_map(path: Path, est: np.ndarray, truth: np.ndarray, landmarks: np.ndarray, path_est: np.ndarray | None,
             path_truth: np.ndarray | None, title: str, units: str) -> Path:
    """Top view of the map: a 3-D map is drawn from above (first and last axis: x and
    depth). Equal scales unless that would squash the picture into a strip (a forward-looking
    camera: depth >> width), which the y label then says. Where the unknown features fill
    less than :data:`CLOSE_UP_SHARE` of the whole along both axes, a second chart beside it
    shows them close up (the whole map's chart frames that region in grey). Drawn in pixels
    (:mod:`.raster`)."""
    from placeloc.evaluation import raster as R

    ax0, ax1 = 0, truth.shape[1] - 1
    paths = [p[:, :2] for p in (path_est, path_truth) if p is not None and len(p)]
    whole = _extent(np.vstack([est[:, [ax0, ax1]], truth[:, [ax0, ax1]], landmarks[:, [ax0, ax1]].reshape(-1, 2)] + paths))
    near = _extent(np.vstack([est[:, [ax0, ax1]], truth[:, [ax0, ax1]]]))
    close = near is not None and whole is not None and bool(
        np.all((near[1] - near[0]) < CLOSE_UP_SHARE * np.maximum(whole[1] - whole[0], 1e-12)))
    c = _map_chart(est, truth, landmarks, path_est, path_truth, title, units, whole,
                      frame=_padded(*near) if close else None)
    if not close:
        return c.save(path)
    zoom = _map_chart(est, truth, landmarks, path_est, path_truth,
                         f"the {len(est)} unknown features close up\n(the grey frame on the left)", units, near)
    left, right = np.asarray(c.result()), np.asarray(zoom.result())
    page = R.Canvas(left.shape[1] + right.shape[1], max(left.shape[0], right.shape[0]), ss=1)
    page.paste(left, 0, 0)
    page.paste(right, left.shape[1], 0)
    return page.save(path)


def _extent(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    pts = pts[np.isfinite(pts).all(axis=1)]
    return (pts.min(axis=0), pts.max(axis=0)) if len(pts) else None


def _padded(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    span = np.maximum(hi - lo, 1e-9)
    return lo - 0.05 * span, hi + 0.05 * span


def _map_chart(est: np.ndarray, truth: np.ndarray, landmarks: np.ndarray, path_est: np.ndarray | None,
               path_truth: np.ndarray | None, title: str, units: str,
               extent: tuple[np.ndarray, np.ndarray] | None,
               frame: tuple[np.ndarray, np.ndarray] | None = None) -> Any:
    """One chart of :func:`plot_map` over ``extent`` (lo, hi of the two drawn axes; what
    lies outside is left out), with ``frame`` (lo, hi) outlined in grey: the close-up's region."""
    from placeloc.evaluation import raster as R

    ax0, ax1 = 0, truth.shape[1] - 1
    names = ("x", "y") if truth.shape[1] == 2 else ("X", "Z (depth)")
    lo, hi = extent if extent is not None else (np.zeros(2), np.ones(2))
    span = np.maximum(hi - lo, 1e-9)
    to_scale = max(span) / min(span) < 3.0
    lo, hi = _padded(lo, hi)

    def inside(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1])

    # to scale, the longer side takes the whole box (its shorter side is more than a third of it here)
    box_w, box_h = R.to_scale_box(lo, hi, 620.0) if to_scale else (620.0, 620.0)
    grey, orange, green, blue, red = (64, 64, 64), R.CYCLE[1], R.CYCLE[2], R.CYCLE[0], R.CYCLE[3]
    entries = ([R.LegendEntry("true path", grey, line_width=1.8)] if path_truth is not None else []) + (
        [R.LegendEntry("estimated path", orange, line_width=1.2)] if path_est is not None else []) + [
        R.LegendEntry("error (estimate to truth)", green, line_width=1.2),
        R.LegendEntry("true position", (102, 102, 102), marker="O", marker_size=6.5),
        R.LegendEntry("estimated position", blue, marker="o", marker_size=5.5),
        R.LegendEntry("landmark (known)", red, marker="s", marker_size=9)]
    c, ax, rows = R.titled_chart(title, box_w, box_h, entries, (lo[0], hi[0]), (lo[1], hi[1]), f"{names[0]} ({units})",
                                 f"{names[1]} ({units})" + ("" if to_scale else ", axes not to scale"))
    for line, colour, width in ((path_est, orange, 1.2), (path_truth, grey, 1.8)):
        if line is None:
            continue
        keep = inside(line[:, 0], line[:, 1])
        # each run of points inside the chart on its own: a line across a gap would be made up
        for run in np.split(np.arange(len(line)), np.flatnonzero(np.diff(keep.astype(np.int8)) != 0) + 1):
            if len(run) > 1 and keep[run[0]]:
                ax.line(line[run, 0], line[run, 1], colour, width)
    ax.segments(est[:, ax0], est[:, ax1], truth[:, ax0], truth[:, ax1], green, 1.2)
    ax.markers(truth[:, ax0], truth[:, ax1], (102, 102, 102), "O", 6.5, edge=1.2)
    ax.markers(est[:, ax0], est[:, ax1], blue, "o", 5.5)
    lm = landmarks[inside(landmarks[:, ax0], landmarks[:, ax1])] if len(landmarks) else landmarks
    if len(lm):
        ax.markers(lm[:, ax0], lm[:, ax1], red, "s", 9)
    if frame is not None:
        (x0, y0), (x1, y1) = frame
        ax.line(np.array([x0, x1, x1, x0, x0]), np.array([y0, y0, y1, y1, y0]), (150, 150, 150), 1.2)
    ax.box()
    R.legend_below(c, ax, rows)
    return c
