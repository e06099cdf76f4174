"""UMap stages: render the line-image database from a wireframe, pack it, extract query
line images (LSD) and AKAZE features, localize (UMap / UMap+CA) and evaluate.

Spec: ../shared/METHODS.md section 3 and seed 001_5b098ba37914637b.txt. Choices where the
paper is silent or ambiguous:

- Eq. (1) is read as intersection over union, M_i = A(LC) / (A(DB_i) + A(SEN) - A(LC))
  (see :func:`placeloc.umap.bits.iou_scores`).
- The database is drawn one pixel wide and dilated by ``tolerance_px`` at index time, so a
  query line a pixel or two off still overlaps.
- Query images may be larger than the database images (same aspect ratio): LSD runs at full
  resolution and the segments are scaled into the database's size.
- CA: the anchor is the frame with the best UMap score (the paper starts from "the one
  that matched best"); CA then chains forward and backward from it. ``ca.formula: paper``
  uses eqs. (2)-(3) as printed (with phi = :func:`placeloc.umap.ca.effective_phi` unless
  ``ca.phi_deg`` is set); ``exact`` uses both centroid positions (the paper assumes the
  first centroid sits at the image centre). These belong to ``ca.tracker: paper``.
- ``ca.tracker: robust`` (default, :func:`ca_track`): each match gives a signed step along
  the wall, the majority vote runs on those steps in metres, a vote whose winner is small or
  barely ahead of the runner-up is unreliable, the search is centred on the CA prediction,
  ties on a featureless wall follow the prediction, a much better score nearby re-localizes,
  and candidate poses must agree with the laser distance.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from placeloc.artifacts import atomic_open, read_strings, write_tree
from placeloc.config import ConfigError
from placeloc.geometry import Camera, equirect_to_pinhole, pose_grid
from placeloc.images import ImageError, read_gray
from placeloc.methods import Method, Stage
from placeloc.umap import ca as ca_mod
from placeloc.umap.bits import iou_scores, pack, popcount_rows, unpack
from placeloc.umap.model import ModelError, load_model
from placeloc.umap.params import UMapParams
from placeloc.umap.render import render_block


def _camera(p: dict[str, Any]) -> Camera:
    c = p["camera"]
    return Camera(int(c["width"]), int(c["height"]), float(c["hfov_deg"]))


def _check(config: dict[str, Any]) -> None:
    p = config["umap"]
    if p["model"] is None:
        raise ConfigError("umap.model is missing: give the wireframe (.yaml/.json/.obj) or floor plan (.yaml) file")
    if not Path(p["model"]).is_file():
        raise ConfigError(f"umap.model: {p['model']} does not exist; fix the path (relative paths start at the config's folder)")
    if p["mode"] == "umap+ca":
        if p["sensor_csv"] is None or not Path(p["sensor_csv"]).is_file():
            raise ConfigError("umap.sensor_csv is missing or does not exist: mode umap+ca needs the per-frame CSV "
                              "(frame, d, theta_deg); or set umap.mode: umap")
    try:
        _camera(p)
    except ValueError as exc:
        raise ConfigError(f"umap.camera: {exc}") from exc
    if p["tolerance_px"] < 0 or p["block"] < 1:
        raise ConfigError("umap.tolerance_px must be >= 0 and umap.block >= 1")


# ------------------------------------------------------------------ build-dictionary

def _wall_distance(xy: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Plan distance from each point to the nearest wall face."""
    if len(faces) == 0:
        return np.full(len(xy), np.inf)
    a, b = faces[:, 0:2], faces[:, 2:4]
    e = b - a
    ee = np.maximum((e * e).sum(1), 1e-12)
    out = np.full(len(xy), np.inf)
    for s in range(0, len(xy), 8192):  # chunks keep the (points x walls) temporaries small
        p = xy[s:s + 8192, None, :]
        t = np.clip(((p - a) * e).sum(2) / ee, 0, 1)
        d = np.hypot(*(p - (a + t[..., None] * e)).transpose(2, 0, 1))
        out[s:s + 8192] = d.min(1)
    return out


def build_dictionary(ctx: Any) -> None:
    p = ctx.params
    try:
        model = load_model(p["model"])
    except ModelError as exc:
        raise ctx_error(exc) from exc
    g = p["grid"]
    try:
        poses = pose_grid(g["x"], g["y"], g["z"], g["headings"])
    except ValueError as exc:
        raise ConfigError(f"umap.grid: {exc}") from exc
    if g["inside_only"] and model.polygons:
        keep = model.inside(poses[:, :2]) & (_wall_distance(poses[:, :2], model.faces) >= g["wall_margin_m"])
        poses = poses[keep]
    if len(poses) == 0:
        raise ConfigError(f"umap.grid: the pose grid is empty (x {g['x']}, y {g['y']}, headings {g['headings']}"
                          f"{', inside the floor plan' if g['inside_only'] else ''}); widen the ranges or check the model's coordinates")
    cam = _camera(p)
    block = int(p["block"])
    items = [(model.segments, model.faces, poses[s:s + block], (cam.width, cam.height, cam.hfov_deg), p["near_m"], p["hidden_lines"])
             for s in range(0, len(poses), block)]
    nw = (cam.width * cam.height + 63) // 64
    db = ctx.out.create_dataset("db", shape=(len(poses), nw), dtype=np.uint64, chunks=(min(block, len(poses)), nw))
    s = 0
    for bits in ctx.progress(ctx.executor.map(render_block, items), total=len(items), desc="render database"):
        db[s:s + len(bits)] = bits
        s += len(bits)
    write_tree(ctx.out, {"poses": poses, "segments": model.segments, "faces": model.faces,
                         "plan": {f"polygon_{i}": poly for i, poly in enumerate(model.polygons)}})
    ctx.out.attrs.update(width=cam.width, height=cam.height, hfov_deg=cam.hfov_deg, n_views=len(poses), model=model.source)


def ctx_error(exc: Exception) -> Exception:
    from placeloc.runner import StageError

    return StageError(str(exc))


# ------------------------------------------------------------------ index

def index(ctx: Any) -> None:
    src = ctx.artifact("build-dictionary")
    h, w = int(src.attrs["height"]), int(src.attrs["width"])
    db = src["db"]
    tol = int(ctx.params["tolerance_px"])
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * tol + 1, 2 * tol + 1)) if tol > 0 else None
    block = int(ctx.params["block"])
    bits = ctx.out.create_dataset("bits", shape=db.shape, dtype=np.uint64, chunks=(min(block, db.shape[0]), db.shape[1]))
    counts = np.zeros(db.shape[0], dtype=np.int64)
    for s in ctx.progress(range(0, db.shape[0], block), total=-(-db.shape[0] // block), desc="pack database"):
        words = db[s:s + block]
        if kernel is not None:
            imgs = unpack(words, h, w)
            imgs = np.stack([cv2.dilate(im, kernel) for im in imgs])
            words = pack(imgs)
        bits[s:s + len(words)] = words
        counts[s:s + len(words)] = popcount_rows(np.ascontiguousarray(words))
    write_tree(ctx.out, {"counts": counts, "poses": src["poses"][()]})
    ctx.out.attrs.update(width=w, height=h, hfov_deg=float(src.attrs["hfov_deg"]), tolerance_px=tol,
                         bytes=int(db.shape[0] * db.shape[1] * 8))


# ------------------------------------------------------------------ extract

def line_image(gray: np.ndarray, cam: Camera, min_length: float, thickness: int) -> np.ndarray:
    """LSD segments of ``gray`` drawn into a binary image of the database camera's size.

    ``gray`` must have the camera's aspect ratio; segments are scaled by cam.width / width."""
    lsd = cv2.createLineSegmentDetector()
    found = lsd.detect(gray)[0]
    segs = np.zeros((0, 4)) if found is None else found.reshape(-1, 4).astype(np.float64)  # (N,1,4) in 4.x
    segs = segs * (cam.width / gray.shape[1])
    keep = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]) >= min_length
    img = np.zeros((cam.height, cam.width), np.uint8)
    for x0, y0, x1, y1 in segs[keep]:
        cv2.line(img, (int(round(x0)), int(round(y0))), (int(round(x1)), int(round(y1))), 1, int(thickness))
    return img


def _check_size(path: Path, shape: tuple[int, ...], first: tuple[int, ...] | None, cam: Camera, kind: str) -> None:
    h, w = shape[:2]
    if first is not None and (h, w) != first:
        raise ImageError(f"{path}: query image is {w}x{h} but the first query image is {first[1]}x{first[0]}; "
                         "all query images of one run must have the same size")
    want = 2.0 if kind == "equirect" else cam.width / cam.height
    if abs(w / h - want) > 0.01 * want:
        what = "an equirectangular panorama needs width = 2 x height" if kind == "equirect" else (
            f"the database camera is {cam.width}x{cam.height}: set umap.camera.width/height to the images' aspect ratio or resize them")
        raise ImageError(f"{path}: query image is {w}x{h} (aspect {w / h:.3f}); {what}")


def extract(ctx: Any) -> None:
    p = ctx.params
    cam = _camera(p)
    images = ctx.images["query"]
    kind = p["query_kind"]
    headings = [float(hd) for hd in p["grid"]["headings"]] if kind == "equirect" else [math.nan]
    lines, pts_all, desc_all, offsets = [], [], [], [0]
    first = None
    qcam = None
    for path in ctx.progress(images.paths, total=len(images), desc="LSD + AKAZE"):
        gray = read_gray(path)
        _check_size(path, gray.shape, first, cam, kind)
        first = gray.shape[:2]
        if kind == "equirect":
            # Cut views at twice the database resolution, so LSD sees enough detail.
            qcam = Camera(cam.width * 2, cam.height * 2, cam.hfov_deg)
            views = [equirect_to_pinhole(gray, hd, qcam) for hd in headings]
        else:
            qcam = Camera(gray.shape[1], gray.shape[0], cam.hfov_deg)
            views = [gray]
        lines.append(pack(np.stack([line_image(v, cam, p["lsd_min_length_px"], p["query_thickness_px"]) for v in views])))
        pts, desc = ca_mod.akaze(views[0], p["ca"]["akaze_threshold"])
        pts_all.append(pts)
        desc_all.append(desc)
        offsets.append(offsets[-1] + len(pts))
    write_tree(ctx.out, {"lines": np.stack(lines), "view_heading": np.asarray(headings), "names": images.names,
                         "kp_pts": np.concatenate(pts_all), "kp_desc": np.concatenate(desc_all),
                         "kp_offsets": np.asarray(offsets, dtype=np.int64)})
    ctx.out.attrs.update(width=cam.width, height=cam.height, query_width=qcam.width, query_height=qcam.height,
                         query_focal=qcam.focal, query_kind=kind)


# ------------------------------------------------------------------ localize

def read_frame_csv(path: str | Path, columns: tuple[str, str], what: str) -> dict[str, tuple[float, float]]:
    """frame -> (two numeric columns) from a CSV with a ``frame`` column; errors name the
    file, the line and the columns it needs."""
    out: dict[str, tuple[float, float]] = {}
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        need = {"frame", *columns}
        if reader.fieldnames is None or not need <= set(reader.fieldnames):
            raise ImageError(f"{path}: {what} CSV needs the columns frame, {', '.join(columns)} (has {reader.fieldnames})")
        for i, row in enumerate(reader, 2):
            try:
                out[row["frame"]] = (float(row[columns[0]]), float(row[columns[1]]))
            except (TypeError, ValueError) as exc:
                raise ImageError(f"{path}:{i}: {' and '.join(columns)} must be numbers ({exc})") from exc
    return out


def read_sensor_csv(path: str | Path, names: list[str]) -> dict[str, tuple[float, float]]:
    """frame -> (d, theta_deg); every query frame must be present."""
    out = read_frame_csv(path, ("d", "theta_deg"), "sensor")
    missing = [n for n in names if n not in out]
    if missing:
        raise ImageError(f"{path}: no sensor row for {len(missing)} query frame(s), e.g. {missing[0]}; add them")
    return out


class Scorer:
    """Eq. (1) for one query frame against all (or some) database views."""

    def __init__(self, bits: np.ndarray, counts: np.ndarray, poses: np.ndarray, view_heading: np.ndarray) -> None:
        self.bits, self.counts, self.poses = bits, counts, poses
        self.view_heading = view_heading
        # rows of each cut-view heading (panoramas), or all rows (pinhole: heading unknown)
        self.groups = [np.flatnonzero(np.isclose(poses[:, 3] % 360, hd % 360)) if not math.isnan(hd) else np.arange(len(poses))
                       for hd in view_heading]

    def best(self, lines: np.ndarray, rows: np.ndarray | None = None) -> tuple[int, float]:
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
            sc = iou_scores(self.bits, self.counts, lines[v], cand)
            k = int(np.argmax(sc))
            if sc[k] > best_s:
                best_i, best_s = int(cand[k]), float(sc[k])
        return best_i, best_s


def _ca_chain(anchor: int, umap_best: np.ndarray, umap_score: np.ndarray, ca_dist: np.ndarray, poses: np.ndarray,
              lines: np.ndarray, scorer: Scorer, c: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """UMap+CA from one anchor frame: chain forward and backward, each search limited to
    (CA moved distance + mean + std of the CA error) around the previous estimate."""
    n = len(umap_best)
    best, score = umap_best.copy(), umap_score.copy()
    radius = np.full(n, np.nan)
    order = [(k, k - 1, k) for k in range(anchor + 1, n)] + [(k, k + 1, k + 1) for k in range(anchor - 1, -1, -1)]
    for k, prev, step in order:
        m = ca_dist[step]
        r = (m + c["error_mean_m"] + c["error_std_m"]) if np.isfinite(m) else c["fallback_radius_m"]
        dist = np.hypot(poses[:, 0] - poses[best[prev], 0], poses[:, 1] - poses[best[prev], 1])
        near = dist <= r
        if c["keep_heading"]:
            # CA matched features between the frames, so the views overlap: on a database
            # whose headings are 90 deg apart only the previous heading is consistent.
            near &= np.isclose(poses[:, 3], poses[best[prev], 3])
        rows = np.flatnonzero(near)
        if rows.size == 0:  # radius below the grid step: take the nearest grid positions
            rows = np.flatnonzero(dist <= dist.min() + 1e-9)
        radius[k] = r
        best[k], score[k] = scorer.best(lines[k], rows)
    return best, score, radius


def laser_ranges(xy: np.ndarray, angle_deg: float, faces: np.ndarray) -> np.ndarray:
    """Plan ray cast: distance from each point along ``angle_deg`` to the first wall face
    (``faces`` (F, >=4) x0 y0 x1 y1 ...); inf where no face is hit."""
    h = math.radians(angle_deg)
    dx, dy = math.cos(h), math.sin(h)
    out = np.full(len(xy), np.inf)
    for ax, ay, bx, by in faces[:, :4]:
        ex, ey = bx - ax, by - ay
        den = dx * ey - dy * ex
        if abs(den) < 1e-12:
            continue
        wx, wy = ax - xy[:, 0], ay - xy[:, 1]
        t = (wx * ey - wy * ex) / den
        u = (wx * dy - wy * dx) / den
        hit = (t > 1e-9) & (u >= 0) & (u <= 1)
        out[hit] = np.minimum(out[hit], t[hit])
    return out


def _pick(scorer: Scorer, lines: np.ndarray, rows: np.ndarray, xy: np.ndarray, pred: np.ndarray,
          tie_tol: float) -> tuple[int, float]:
    """Best-scoring row; rows scoring within ``tie_tol`` of the best are ties (a wall without
    doors looks the same from everywhere along it) and go to the one nearest ``pred``."""
    if len(scorer.view_heading) == 1 and math.isnan(scorer.view_heading[0]):
        sc = iou_scores(scorer.bits, scorer.counts, lines[0], rows)
    else:  # panorama cut views: each row is compared with the view cut at its own heading
        sc = np.full(len(rows), -1.0)
        for v, hd in enumerate(scorer.view_heading):
            on = np.isclose(scorer.poses[rows, 3] % 360, hd % 360)
            if on.any():
                sc[on] = iou_scores(scorer.bits, scorer.counts, lines[v], rows[on])
    top = float(sc.max())
    tied = np.flatnonzero(sc >= top - tie_tol)
    j = tied[np.argmin(np.hypot(*(xy[rows[tied]] - pred).T))]
    return int(rows[j]), float(sc[j])


def ca_track(anchor: int, umap_best: np.ndarray, umap_score: np.ndarray, step: np.ndarray, reliable: np.ndarray,
             theta: np.ndarray, poses: np.ndarray, lines: np.ndarray, scorer: Scorer,
             c: dict[str, Any], alt: np.ndarray | None = None,
             laser: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust UMap+CA from one anchor frame, forward then backward.

    ``step[k]``: signed CA step along the wall from frame k-1 to k (nan if none), ``reliable[k]``
    whether its vote group had enough matches, ``theta[k]`` the camera angle to the wall at
    frame k-1. Each frame's search is centred on the position CA predicts (previous estimate +
    step along the wall), within ``|error_mean| + 2 error_std`` (+0.1 m grid quantisation).
    An unreliable or missing CA step falls back to the sequence's median reliable step with
    ``fallback_radius_m`` (or ``fallback_step_m`` in its direction when calibrated: CA fails
    mostly on large steps, so the median reliable step underestimates them). If the best score inside the gate is ``recover_ratio`` times below
    the best within ``fallback_radius_m`` of the previous estimate, the CA step is taken to be
    wrong and the wider search wins (re-localization). ``alt[k]`` (optional) is the vote's
    runner-up step, a second motion hypothesis tried before the wide search under the same
    ratio: a wrong winning group often has the true motion as runner-up. ``laser`` (optional)
    = (d per frame, theta per frame, wall faces): candidate poses whose plan ray cast towards the wall differs
    from the measured laser distance by more than ``laser_tol_m`` are dropped (the laser CA
    already relies on fixes the distance across the wall, which the line images of a corridor
    barely constrain). Returns (best rows, scores, radii)."""
    n = len(umap_best)
    best, score = umap_best.copy(), umap_score.copy()
    radius = np.full(n, np.nan)
    xy = poses[:, :2]
    gate = abs(c["error_mean_m"]) + 2.0 * c["error_std_m"] + 0.1
    ok = reliable & np.isfinite(step)
    typical = float(np.median(step[ok])) if ok.any() else 0.0
    if c["fallback_step_m"] is not None:  # calibrated size of the steps CA fails on (large ones), same direction
        typical = math.copysign(float(c["fallback_step_m"]), typical)
    order = [(k, k - 1, k, 1.0) for k in range(anchor + 1, n)] + [(k, k + 1, k + 1, -1.0) for k in range(anchor - 1, -1, -1)]
    for k, prev, st, sgn in order:
        pp = poses[best[prev]]
        t = ca_mod.wall_tangent(float(pp[3]), float(theta[st]), c["wall_side"] == "right")
        if ok[st]:
            pred, r = pp[:2] + sgn * step[st] * t, gate
        else:
            pred, r = pp[:2] + sgn * typical * t, c["fallback_radius_m"]
        heading_ok = np.isclose(poses[:, 3], pp[3]) if c["keep_heading"] else np.ones(len(poses), bool)
        if laser is not None:
            th_k = laser[1][k]  # frame k's laser points at heading -/+ theta
            near_prev = heading_ok & (np.hypot(*(xy - pp[:2]).T) <= c["fallback_radius_m"] + 2 * abs(typical) + gate)
            cand = np.flatnonzero(near_prev)
            ang = poses[cand, 3] - th_k if c["wall_side"] == "right" else poses[cand, 3] + th_k
            rng_ = np.full(len(cand), np.inf)
            for a_ in np.unique(ang):
                on = ang == a_
                rng_[on] = laser_ranges(xy[cand[on]], float(a_), laser[2])
            fits = np.abs(rng_ - laser[0][k]) <= c["laser_tol_m"]
            if fits.any():
                heading_ok = np.zeros(len(poses), bool)
                heading_ok[cand[fits]] = True
        dist = np.hypot(*(xy - pred).T)
        rows = np.flatnonzero((dist <= r) & heading_ok)
        if rows.size == 0:  # gate below the grid step: the nearest grid positions
            rows = np.flatnonzero(heading_ok & (dist <= dist[heading_ok].min() + 1e-9))
        i, s = _pick(scorer, lines[k], rows, xy, pred, c["tie_tol"])
        if alt is not None and np.isfinite(alt[st]):
            pred2 = pp[:2] + sgn * alt[st] * t
            rows2 = np.flatnonzero((np.hypot(*(xy - pred2).T) <= gate) & heading_ok)
            if rows2.size:
                j, s2 = _pick(scorer, lines[k], rows2, xy, pred2, c["tie_tol"])
                if s2 > s * c["recover_ratio"]:
                    i, s, r, pred = j, s2, gate, pred2
        if r < c["fallback_radius_m"]:
            wide = np.flatnonzero((np.hypot(*(xy - pp[:2]).T) <= c["fallback_radius_m"]) & heading_ok)
            if wide.size:
                j, sw = _pick(scorer, lines[k], wide, xy, pred, c["tie_tol"])
                if sw > s * c["recover_ratio"]:
                    i, s, r = j, sw, c["fallback_radius_m"]
        best[k], score[k], radius[k] = i, s, r
    return best, score, radius


def localize(ctx: Any) -> None:
    p = ctx.params
    idx = ctx.artifact("index")
    ex = ctx.artifact("extract")
    if (int(ex.attrs["width"]), int(ex.attrs["height"])) != (int(idx.attrs["width"]), int(idx.attrs["height"])):
        raise ctx_error(ValueError("extract and index line images differ in size: re-run extract (--force)"))
    bits = idx["bits"][()]
    poses = idx["poses"][()]
    scorer = Scorer(bits, idx["counts"][()], poses, ex["view_heading"][()])
    lines = ex["lines"][()]
    names = read_strings(ex["names"])
    n = len(names)
    umap_best = np.zeros(n, dtype=np.int64)
    umap_score = np.zeros(n)
    for k in ctx.progress(range(n), total=n, desc="UMap search"):
        umap_best[k], umap_score[k] = scorer.best(lines[k])
    best, score = umap_best.copy(), umap_score.copy()
    ca_dist = np.full(n, np.nan)
    radius = np.full(n, np.nan)
    n_kept = np.zeros(n, dtype=np.int64)
    anchor = int(np.argmax(umap_score))
    if p["mode"] == "umap+ca":
        c = p["ca"]
        sensor = read_sensor_csv(p["sensor_csv"], names)
        off = ex["kp_offsets"][()]
        pts, desc = ex["kp_pts"][()], ex["kp_desc"][()]
        qw, qf = int(ex.attrs["query_width"]), float(ex.attrs["query_focal"])
        phi = c["phi_deg"] if c["phi_deg"] > 0 else ca_mod.effective_phi(float(idx.attrs["hfov_deg"]))
        step = np.full(n, np.nan)
        reliable = np.zeros(n, dtype=bool)
        alt = np.full(n, np.nan)  # the vote's runner-up step: a second motion hypothesis
        laser_d = np.array([sensor[nm][0] for nm in names])
        laser_theta = np.array([sensor[nm][1] for nm in names])
        faces = ctx.artifact("build-dictionary")["faces"][()]
        theta = np.zeros(n)
        for k in range(1, n):  # ca_dist[k]: moved distance between frames k-1 and k
            a, b = slice(off[k - 1], off[k]), slice(off[k], off[k + 1])
            d, theta[k] = sensor[names[k - 1]]
            if c["tracker"] == "robust":
                step[k], n_kept[k], second, alt[k] = ca_mod.signed_step(pts[a], desc[a], pts[b], desc[b], d, theta[k], qf, (qw - 1) / 2.0,
                                                           c["wall_side"] == "right", c["vote_tol_m"], c["vote_rel_tol"])
                reliable[k] = ca_mod.is_reliable(int(n_kept[k]), second, c)
                ca_dist[k] = abs(step[k])
                continue
            shift = ca_mod.centroid_shift(pts[a], desc[a], pts[b], desc[b], c["bin_px"], c["min_matches"])
            if shift is None:
                continue
            n_kept[k] = shift[3]
            if c["formula"] == "paper":
                ca_dist[k] = ca_mod.moved_distance_paper(shift[0], d, theta[k], phi, qw)
            else:
                ca_dist[k] = ca_mod.moved_distance_exact(shift[1], shift[2], d, theta[k], qf, (qw - 1) / 2.0, c["wall_side"] == "right")
        # Anchor: the paper starts from the frame with the best UMap score ("best"); "chain"
        # starts a chain from every frame's UMap estimate and keeps the chain with the highest
        # summed score, so one confidently wrong frame cannot carry the whole sequence off.
        anchors = [anchor] if c["anchor"] == "best" else list(np.argsort(-umap_score, kind="stable"))
        best_total = -1.0
        for a in ctx.progress(anchors, total=len(anchors), desc="CA chains"):
            if c["tracker"] == "robust":
                b, s, r = ca_track(int(a), umap_best, umap_score, step, reliable, theta, poses, lines, scorer, c, alt,
                                   (laser_d, laser_theta, faces) if c["use_laser"] else None)
            else:
                b, s, r = _ca_chain(int(a), umap_best, umap_score, ca_dist, poses, lines, scorer, c)
            if s.sum() > best_total:
                best_total, anchor = float(s.sum()), int(a)
                best, score, radius = b, s, r
    est = poses[best]
    write_tree(ctx.out, {"names": names, "best_index": best, "x": est[:, 0], "y": est[:, 1], "heading_deg": est[:, 3],
                         "score": score, "ca_distance_m": ca_dist, "search_radius_m": radius, "ca_matches": n_kept,
                         "umap_x": poses[umap_best, 0], "umap_y": poses[umap_best, 1], "umap_score": umap_score})
    ctx.out.attrs.update(mode=p["mode"], anchor=anchor)
    with atomic_open(ctx.run_dir / "estimates.csv", newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "x", "y", "heading_deg", "score", "ca_distance_m", "search_radius_m"])
        for k in range(n):
            w.writerow([names[k], f"{est[k, 0]:.3f}", f"{est[k, 1]:.3f}", f"{est[k, 3]:.1f}", f"{score[k]:.5f}",
                        "" if math.isnan(ca_dist[k]) else f"{ca_dist[k]:.3f}", "" if math.isnan(radius[k]) else f"{radius[k]:.3f}"])


# ------------------------------------------------------------------ evaluate

def read_poses_csv(path: str | Path) -> dict[str, tuple[float, float]]:
    """Ground truth: CSV with columns frame, x, y (z, heading_deg optional)."""
    return read_frame_csv(path, ("x", "y"), "ground-truth poses")


def error_metrics(err: np.ndarray) -> dict[str, Any]:
    err = np.asarray(err, float)
    return {"max_error_m": float(err.max()), "mean_error_m": float(err.mean()), "median_error_m": float(np.median(err)),
            "within_0_5m": float(np.mean(err <= 0.5)), "within_1m": float(np.mean(err <= 1.0)), "n_frames": int(len(err))}


def evaluate(ctx: Any) -> None:
    from placeloc.evaluation import write_metrics

    gt_cfg = ctx.config["ground_truth"]
    if gt_cfg["kind"] != "poses":
        raise ConfigError(f"ground_truth.kind is {gt_cfg['kind']!r}; UMap is scored against poses: set ground_truth.kind: poses "
                          "and ground_truth.path to a CSV with frame, x, y")
    loc = ctx.artifact("localize")
    names = read_strings(loc["names"])
    gt = read_poses_csv(gt_cfg["path"])
    missing = [nm for nm in names if nm not in gt]
    if missing:
        raise ImageError(f"{gt_cfg['path']}: no ground truth for {len(missing)} frame(s), e.g. {missing[0]}")
    truth = np.array([gt[nm] for nm in names])
    est = np.stack([loc["x"][()], loc["y"][()]], axis=1)
    err = np.hypot(*(est - truth).T)
    metrics = error_metrics(err)
    metrics["mode"] = str(loc.attrs["mode"])
    write_tree(ctx.out, {"error_m": err, "truth_xy": truth})
    write_metrics(ctx.run_dir, metrics, ctx.out)
    if ctx.config.get("plots", True):
        plan = ctx.artifact("build-dictionary")
        polys = [plan["plan"][k][()] for k in sorted(plan["plan"].keys())] if "plan" in plan else []
        _plots(ctx.run_dir, err, truth, est, polys, plan["segments"][()], metrics["mode"])


def _plots(run_dir: Path, err: np.ndarray, truth: np.ndarray, est: np.ndarray, polys: list[np.ndarray],
           segments: np.ndarray, mode: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.5))
    e = np.sort(err)
    ax.step(e, np.arange(1, len(e) + 1) / len(e), where="post")
    ax.set_xscale("symlog", linthresh=1.0)
    ax.set_xlabel("error [m]")
    ax.set_ylabel("share of frames")
    ax.set_title(f"cumulative error ({mode})")
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(run_dir / "error_cdf.png", dpi=120)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(12, 3))
    if polys:
        for poly in polys:
            q = np.vstack([poly, poly[:1]])
            ax.plot(q[:, 0], q[:, 1], "k-", lw=0.8)
    else:
        for s in segments:
            ax.plot([s[0], s[3]], [s[1], s[4]], "k-", lw=0.4)
    ax.plot(truth[:, 0], truth[:, 1], "b.", ms=5, label="ground truth")
    ax.plot(est[:, 0], est[:, 1], "r.", ms=5, label=f"{mode} estimate")
    for t, s in zip(truth, est):
        ax.plot([t[0], s[0]], [t[1], s[1]], "r-", lw=0.3, alpha=0.5)
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=7)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    fig.tight_layout()
    fig.savefig(run_dir / "estimates_on_plan.png", dpi=120)
    plt.close(fig)


METHOD = Method(
    name="umap",
    params=UMapParams,
    stages={
        "extract": Stage(extract, keys=("camera", "query_kind", "lsd_min_length_px", "query_thickness_px", "ca", "grid")),
        "build-dictionary": Stage(build_dictionary, keys=("model", "camera", "grid", "near_m", "hidden_lines")),
        "index": Stage(index, keys=("tolerance_px",)),
        "localize": Stage(localize, keys=("mode", "sensor_csv", "ca")),
        "evaluate": Stage(evaluate, keys=(), sections=("ground_truth", "plots")),
    },
    required_images=("query",),
    checker=_check,
    citation="K. Takahashi, J. Takahashi, T. Kaneko and Y. Tobe, \"Improving pre-map indoor localization by comparing "
             "consecutive images\" (Universal Map with Consistency Adjustment)",
)
