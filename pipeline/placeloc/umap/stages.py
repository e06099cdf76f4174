"""UMap stages: render the line-image database from a wireframe, pack it, extract query
line images (LSD) and AKAZE features, localize (UMap / UMap+CA) and evaluate.

The numerics live in modules named for what they do: :mod:`placeloc.umap.render` (database
line images), :mod:`placeloc.umap.bits` (packing and the eq. (1) score),
:mod:`placeloc.umap.lines` (query line images), :mod:`placeloc.umap.scoring`,
:mod:`placeloc.umap.ca` (CA geometry) and :mod:`placeloc.umap.tracker` (the CA trackers);
floor plans and plan ray casting in :mod:`placeloc.geometry`. docs/umap.md says where this
project reads the paper one way or another.
"""

from __future__ import annotations

import csv
import json
import logging
import math
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np

from placeloc.core.artifacts import atomic_open, read_mapped, read_strings, write_tree
from placeloc.core.config import ConfigError
from placeloc.core.imagework import ImageStream, ImageWork, write_images
from placeloc.core.methods import Method, Stage
from placeloc.evaluation.contracts import PoseEvaluation
from placeloc.evaluation.pose_estimates import right_answers, yaw_errors
from placeloc.geometry import Camera
from placeloc.geometry.floorplan import (
    ModelError,
    floor_plan_model,
    label_points,
    load_model,
    load_plan,
    plan_grid,
    with_ceiling,
)
from placeloc.umap import resources as umap_resources
from placeloc.umap.artifacts import drawn_ceiling, model_at_ceiling, plan_rooms, query_seen_rows, rooms_of_points
from placeloc.umap.bits import pack, popcount_rows, unpack
from placeloc.umap.panorama import (
    CeilingChoice,
    PanoramaAnswers,
    chamfer_spectra,
    choose_ceiling,
    map_side,
    region_masks,
    render_oriented_block,
    render_panorama_block,
    search_layers,
)
from placeloc.umap.params import UMapParams
from placeloc.umap.pictures import ceiling_picture, panorama_pictures, report_pictures, show_extra
from placeloc.umap.query_features import panorama_arrays, query_arrays, query_camera
from placeloc.umap.render import render_grid_block
from placeloc.umap.room_hints import RoomRegion, matching_rooms, read_room_hints
from placeloc.umap.scoring import Scorer
from placeloc.umap.sensor import read_sensor_csv
from placeloc.umap.tracker import ca_chain, ca_steps, ca_track

log = logging.getLogger("placeloc")


def _camera(p: Any) -> Camera:
    c = p.camera
    return Camera(int(c.width), int(c.height), float(c.hfov_deg))


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
    if p["query_kind"] == "panorama" and p["mode"] == "umap+ca":
        raise ConfigError("umap.mode umap+ca needs pinhole views along a wall (the laser CA); panoramas are localized "
                          "one by one: set umap.mode: umap for umap.query_kind: panorama")
    if p["room_hints"] is not None:
        if p["query_kind"] != "panorama":
            raise ConfigError("umap.room_hints keeps whole panoramas' search to a room (umap.query_kind: panorama); "
                              "leave it out for pinhole images")
        if not Path(p["room_hints"]).is_file():
            raise ConfigError(f"umap.room_hints: {p['room_hints']} does not exist; fix the path (relative paths start at "
                              "the config's folder) or leave it out")
        try:   # each hint names a room of the plan: told now, not after the index is built
            plan = load_plan(p["model"], p["floor"])
            names = floor_plan_model(plan, str(p["model"])).room_names if plan is not None else []
        except ModelError:
            names = None   # build-dictionary says what is wrong with the model
        if names is not None:
            read_room_hints(p["room_hints"], [], names)
    heights = list(p["grid"]["heights"] or [])
    if heights and p["query_kind"] != "panorama":
        raise ConfigError("umap.grid.heights searches the camera height of whole panoramas (umap.query_kind: panorama); "
                          "for pinhole images give the one height as umap.grid.z")
    _listed_once("umap.grid.heights", heights)   # two layers at one height: every position searched twice
    ceilings = list(p["grid"]["ceilings"] or [])
    if ceilings and p["query_kind"] != "panorama":
        raise ConfigError("umap.grid.ceilings searches a floor plan's ceiling height for whole panoramas "
                          "(umap.query_kind: panorama); for pinhole images give the plan's ceiling_z")
    _listed_once("umap.grid.ceilings", ceilings)
    bad = [h for h in ceilings if not (math.isfinite(h) and h > 0)]
    if bad:
        raise ConfigError(f"umap.grid.ceilings: {', '.join(f'{h:g}' for h in bad)} is not a height in metres above the floor")
    if len(ceilings) > 1 and p["panorama"]["score"] != "chamfer":
        raise ConfigError("umap.grid.ceilings chooses the home's ceiling by the chamfer score's grid table: set "
                          "umap.panorama.score chamfer, or give the one ceiling as the plan's ceiling_z")
    pp = p["panorama"]
    if p["query_kind"] == "panorama" and pp["orientation_bins"] > 1 and (pp["score"] != "chamfer"
                                                                         or pp["chamfer_chance"] != "none"):
        raise ConfigError("umap.panorama.orientation_bins > 1 (the oriented chamfer score) needs umap.panorama.score "
                          "chamfer and chamfer_chance none; set orientation_bins: 1 for the others")
    try:
        c = p["camera"]
        Camera(int(c["width"]), int(c["height"]), float(c["hfov_deg"]))
    except ValueError as exc:
        raise ConfigError(f"umap.camera: {exc}") from exc


def _listed_once(key: str, heights: list[float]) -> None:
    """Refuse a list of heights (``key``) that gives one more than once, naming it."""
    twice = sorted({h for h in heights if heights.count(h) > 1})
    if twice:
        raise ConfigError(f"{key} lists {', '.join(f'{h:g}' for h in twice)} more than once; give each height once")


def _stage_error(exc: Exception) -> Exception:
    from placeloc.core.errors import StageError

    return StageError(str(exc))


# ------------------------------------------------------------------ build-dictionary

def build_dictionary(ctx: Any) -> None:
    p = ctx.params
    g = p.grid
    ceilings = list(g.ceilings) or [None]   # a model per ceiling height searched (umap.grid.ceilings)
    models, plan = [], None
    try:
        if g.ceilings:
            plan = load_plan(p.model, p.floor)
            if plan is None:
                load_model(p.model, p.floor, g.ceilings[0])   # refuses a wireframe, naming the file
        for ceiling in ceilings:
            try:
                models.append(load_model(p.model, p.floor) if ceiling is None
                              else floor_plan_model(with_ceiling(plan, ceiling), str(p.model)))
            except ModelError as exc:
                raise ModelError(f"{exc}" + (f" (umap.grid.ceilings: {ceiling:g} m)" if ceiling else "")) from exc
    except ModelError as exc:
        raise _stage_error(exc) from exc
    model = models[0]
    layers, layer_models, layer_ceilings, warned = [], [], [], set()
    for ceiling, layer_model in zip(ceilings, models):
        for z in (g.heights or [g.z]):   # one layer of the grid per camera height (and ceiling) searched
            try:
                poses, notes = plan_grid(layer_model, x=g.x, y=g.y, step_m=g.step_m, z=z, headings=g.headings,
                                         inside_only=g.inside_only, wall_margin_m=g.wall_margin_m)
            except ValueError as exc:
                where = "".join(k for k, on in ((".heights", g.heights), (".ceilings", g.ceilings)) if on)
                raise ConfigError(f"umap.grid{where}: {exc}" + (f" (ceiling {ceiling:g} m)" if ceiling else "")) from exc
            for note in notes:
                if note not in warned:   # once, not once a layer
                    warned.add(note)
                    log.warning("umap.%s", note)
            layers.append(poses)
            layer_models.append(layer_model)
            layer_ceilings.append(ceiling)
    block = int(p.block)
    poses = layers[0]
    pose_ceiling = None
    if p.query_kind == "panorama":
        # one panoramic line image per grid position, rendered at heading 0: the yaw is searched;
        # the layers of several heights and ceilings one after another (localize searches each alone)
        unique = [q[np.unique(q[:, :2], axis=0, return_index=True)[1]] for q in layers]
        unique = [q[np.lexsort((q[:, 1], q[:, 0]))] for q in unique]
        poses = np.concatenate(unique)
        poses[:, 3] = 0.0
        if g.ceilings:
            pose_ceiling = np.repeat(np.asarray(layer_ceilings, np.float64), [len(q) for q in unique])
        pw, ph = int(p.panorama.width), int(p.panorama.height)
        bins = int(p.panorama.orientation_bins)
        starts = np.cumsum([0] + [len(q) for q in unique])
        # blocks never span two layers: each is drawn with its layer's model
        spans = [(s, min(s + block, hi), m) for lo, hi, m in zip(starts[:-1], starts[1:], layer_models)
                 for s in range(int(lo), int(hi), block)]
        if bins > 1:   # each view's oriented channels, packed one after another
            items = [(m.segments, m.faces, poses[s:e], pw, ph, p.hidden_lines, bins) for s, e, m in spans]
            render = render_oriented_block
        else:
            items = [(m.segments, m.faces, poses[s:e], pw, ph, p.hidden_lines, "all") for s, e, m in spans]
            render = render_panorama_block
        cam = Camera(pw, ph, 90.0)
    else:
        # Views drawn already dilated by the matching tolerance (the only stored copy), hidden
        # lines found once per position: a block holds whole positions (all their headings are
        # consecutive, and the free-space mask keeps or drops them together).
        cam = _camera(p)
        block = max(1, block // len(g.headings)) * len(g.headings)
        items = [(model.segments, model.faces, poses[s:s + block], (cam.width, cam.height, cam.hfov_deg), p.near_m,
                  p.hidden_lines, int(p.tolerance_px)) for s in range(0, len(poses), block)]
        render = render_grid_block
    nw = (cam.width * cam.height + 63) // 64
    bins = int(p.panorama.orientation_bins) if p.query_kind == "panorama" else 1
    nw *= bins
    db = ctx.out.create_dataset("db", shape=(len(poses), nw), dtype=np.uint64, chunks=(min(block, len(poses)), nw))
    cells = None
    s = 0
    for res in ctx.progress(ctx.executor.map(render, items), total=len(items), desc="render database"):
        bits, pooled = res if isinstance(res, tuple) else (res, None)
        if pooled is not None:
            if cells is None:  # the views' 8 x 8 cell images, which bound eq. (1) before a view is read
                cells = ctx.out.create_dataset("pooled", shape=(len(poses), pooled.shape[1]), dtype=np.uint64)
            cells[s:s + len(bits)] = pooled
        db[s:s + len(bits)] = bits
        s += len(bits)
    write_tree(ctx.out, {"poses": poses, "segments": model.segments, "faces": model.faces,
                         "plan": {f"polygon_{i}": poly for i, poly in enumerate(model.polygons)}})
    if pose_ceiling is not None:
        # the ceiling each position's layer was drawn at, and the plan (localize draws it at the ceiling it finds)
        write_tree(ctx.out, {"ceiling_m": pose_ceiling})
        ctx.out.attrs["plan_json"] = json.dumps(plan, default=str)   # a YAML date or the like: as text
    if model.room_names:  # polygon_i's room (a multi-room plan): answers are read off the plan by room
        write_tree(ctx.out, {"room_names": list(model.room_names)})
    if len(model.gaps):   # doors and openings, drawn as gaps on the plan picture
        write_tree(ctx.out, {"plan_gaps": np.asarray(model.gaps, np.float64).reshape(-1, 4)})
    ctx.out.attrs.update(width=cam.width, height=cam.height, hfov_deg=cam.hfov_deg, n_views=len(poses), model=model.source,
                         kind="panorama" if p.query_kind == "panorama" else "pinhole",
                         dilated_px=-1 if p.query_kind == "panorama" else int(p.tolerance_px), orientation_bins=bins)


# ------------------------------------------------------------------ index

def index(ctx: Any) -> None:
    """Per-view line pixel counts. Pinhole databases were drawn already dilated, so the
    build-dictionary artifact's ``db`` is the one stored copy; a panorama database is kept
    undilated there (the chamfer score needs it) and only its small dilated copy is written
    here, as ``bits``, for the IoU score."""
    src = ctx.artifact("build-dictionary")
    h, w = int(src.attrs["height"]), int(src.attrs["width"])
    db = src["db"]
    tol = int(ctx.params.tolerance_px)
    block = int(ctx.params.block)
    counts = np.zeros(db.shape[0], dtype=np.int64)
    if int(src.attrs.get("dilated_px", -1)) >= 0:
        if int(src.attrs["dilated_px"]) != tol:
            raise _stage_error(ValueError(f"the database was drawn {int(src.attrs['dilated_px'])} px thick but "
                                          f"umap.tolerance_px is {tol}: re-run build-dictionary (--force-all)"))
        for s in ctx.progress(range(0, db.shape[0], block), total=-(-db.shape[0] // block), desc="count line pixels"):
            counts[s:s + block] = popcount_rows(np.ascontiguousarray(db[s:s + block]))
        write_tree(ctx.out, {"counts": counts, "poses": src["poses"][()]})
        ctx.out.attrs.update(width=w, height=h, hfov_deg=float(src.attrs["hfov_deg"]), tolerance_px=tol,
                             kind=str(src.attrs.get("kind", "pinhole")), bits_in="build-dictionary/db",
                             bytes=int(db.shape[0] * db.shape[1] * 8))
        return
    if str(src.attrs.get("kind", "pinhole")) == "panorama" and ctx.params.panorama.score == "chamfer":
        _index_spectra(ctx, src, db, h, w)
        return
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * tol + 1, 2 * tol + 1)) if tol > 0 else None
    bits = ctx.out.create_dataset("bits", shape=db.shape, dtype=np.uint64, chunks=(min(block, db.shape[0]), db.shape[1]))
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
                         kind=str(src.attrs.get("kind", "pinhole")), bits_in="index/bits",
                         bytes=int(db.shape[0] * db.shape[1] * 8))


def _index_spectra(ctx: Any, src: Any, db: Any, h: int, w: int) -> None:
    """A panorama database for the chamfer score: the map side of the score as row spectra
    (:func:`placeloc.umap.panorama.chamfer_spectra`), so localize scores every position and
    yaw of a batch of queries with one matrix product per frequency."""
    pp = ctx.params.panorama
    n = db.shape[0]
    bins = int(src.attrs.get("orientation_bins", 1))
    if bins != int(pp.orientation_bins):
        raise _stage_error(ValueError(f"the database was drawn with {bins} orientation bins but "
                                      f"umap.panorama.orientation_bins is {int(pp.orientation_bins)}: re-run "
                                      "build-dictionary (--force-all)"))
    side = map_side(pp, h)
    clutter, spread = side["clutter_share"], side["spread"]
    spectra = ctx.out.create_dataset("spectra", shape=(w // 2 + 1, n, 2 * bins * h), dtype=np.complex64)
    counts = np.zeros(n, dtype=np.int64)
    block = umap_resources.SPECTRA_BLOCK   # positions made and written at a time (its why: there)
    for s in ctx.progress(range(0, n, block), total=-(-n // block), desc="map spectra"):
        words = np.ascontiguousarray(db[s:s + block])
        imgs = unpack(words, h, w) if bins == 1 else unpack(words.reshape(len(words), bins, -1), h, w)
        spectra[:, s:s + len(words)] = chamfer_spectra(imgs, **side)
        counts[s:s + len(words)] = popcount_rows(words)
    write_tree(ctx.out, {"counts": counts, "poses": src["poses"][()]})
    ctx.out.attrs.update(width=w, height=h, hfov_deg=float(src.attrs["hfov_deg"]), tolerance_px=int(ctx.params.tolerance_px),
                         kind="panorama", bits_in="index/spectra", bytes=int(spectra.size * 8),
                         clutter_share=-1.0 if clutter is None else clutter, orientation_bins=bins,
                         orientation_spread=-1 if spread is None else spread)


def _dilated_bits(ctx: Any, idx: Any) -> np.ndarray:
    """The dilated database line images: the index's ``bits`` (panoramas) or the
    build-dictionary's ``db`` (pinhole views, drawn dilated)."""
    return idx["bits"][()] if "bits" in idx else ctx.artifact("build-dictionary")["db"][()]


def _pooled(ctx: Any) -> np.ndarray | None:
    src = ctx.artifact("build-dictionary")
    return src["pooled"][()] if "pooled" in src else None


# ------------------------------------------------------------------ extract

def extract(ctx: Any) -> None:
    """Query line images and AKAZE features (:mod:`placeloc.umap.query_features`) through
    the engine (:mod:`placeloc.core.imagework`), written at the artifact's root."""
    p = ctx.params
    cam = _camera(p)
    kind = p.query_kind
    images = ctx.images["query"]
    if kind == "panorama":
        _extract_panoramas(ctx)
        return
    headings = [float(hd) for hd in p.grid.headings] if kind == "equirect" else [math.nan]
    work = ImageWork(fn=query_arrays, settings={"camera": (cam.width, cam.height, cam.hfov_deg), "kind": kind,
                                                "headings": tuple(headings), "min_length": p.lsd_min_length_px,
                                                "thickness": p.query_thickness_px, "akaze_threshold": p.ca.akaze_threshold},
                     ragged=("kp_pts", "kp_desc"), offsets="kp_offsets", same_size=True, with_path=True)
    table = write_images(ctx.out, ImageStream(ctx, images, work, desc="LSD + AKAZE"))
    qcam = query_camera(table.first_shape, (cam.width, cam.height, cam.hfov_deg), kind)
    ctx.out.create_dataset("view_heading", data=np.asarray(headings))
    ctx.out.attrs.update(width=cam.width, height=cam.height, query_width=qcam.width, query_height=qcam.height,
                         query_focal=qcam.focal, query_kind=kind)


def _extract_panoramas(ctx: Any) -> None:
    """Whole panoramas: one equirectangular line image each (no AKAZE: no CA on panoramas)."""
    pp = ctx.params.panorama
    work = ImageWork(fn=panorama_arrays, settings={"width": pp.width, "height": pp.height, "face_px": pp.face_px,
                                                   "min_length": pp.lsd_min_length_px,
                                                   "orientation_bins": int(pp.orientation_bins),
                                                   "level_max_deg": float(pp.level_max_deg),
                                                   "equalize_clip": float(pp.equalize_clip)},
                     with_path=True)   # sizes may differ: each panorama's lines are drawn at one size
    table = write_images(ctx.out, ImageStream(ctx, ctx.images["query"], work, desc="LSD on cube faces"))
    write_tree(ctx.out, {"view_heading": np.asarray([math.nan]), "kp_pts": np.zeros((0, 2), np.float32),
                         "kp_desc": np.zeros((0, 61), np.uint8), "kp_offsets": np.zeros(len(table) + 1, dtype=np.int64)})
    ctx.out.attrs.update(width=pp.width, height=pp.height, query_width=int(table.first_shape[1]),
                         query_height=int(table.first_shape[0]), query_focal=0.0, query_kind="panorama",
                         orientation_bins=int(pp.orientation_bins))


# ------------------------------------------------------------------ localize

def query_line_images(ex: Any, bins: int, rows: Any = slice(None)) -> np.ndarray:
    """The panorama queries' line images of the extract artifact ``ex`` (its ``rows``):
    (N, H, W) with one orientation bin, else (N, B, H, W) oriented channels, as
    :func:`placeloc.umap.panorama.search_panoramas` takes them."""
    h, w = int(ex.attrs["height"]), int(ex.attrs["width"])
    words = ex["lines"][rows]
    return unpack(words[:, 0], h, w) if bins == 1 else unpack(words, h, w)


def _localize_panoramas(ctx: Any, idx: Any, ex: Any) -> tuple[PanoramaAnswers, CeilingChoice | None, RoomCheck | None]:
    """Best (grid row, plan position, heading, score) of each panorama and its rival's score:
    :func:`placeloc.umap.panorama.search_panoramas` over the index's database; and the
    home's ceiling where umap.grid.ceilings searched several (else None)."""
    pp = ctx.params.panorama
    bins = int(pp.orientation_bins)
    if int(ex.attrs.get("orientation_bins", 1)) != bins:
        raise _stage_error(ValueError("the query line images were extracted with another umap.panorama.orientation_bins "
                                      "than localize's: re-run extract (--force)"))
    lines = query_line_images(ex, bins)   # the size of the index's images: localize checked it
    src = ctx.artifact("build-dictionary")
    if pp.score == "chamfer":
        if "spectra" not in idx:
            raise _stage_error(ValueError("the index holds no chamfer spectra (it was built for umap.panorama.score iou): "
                                          "re-run index (--force)"))
        built = float(idx.attrs.get("clutter_share", -1.0))
        wanted = float(pp.clutter_share) if pp.chamfer_chance == "likelihood" else -1.0
        if abs(built - wanted) > 1e-9:
            raise _stage_error(ValueError("the index's chamfer spectra were built for another umap.panorama.chamfer_chance "
                                          "or clutter_share than localize's: re-run index (--force)"))
        if (int(idx.attrs.get("orientation_bins", 1)), int(idx.attrs.get("orientation_spread", -1))) != (
                bins, int(pp.orientation_spread) if bins > 1 else -1):
            raise _stage_error(ValueError("the index's chamfer spectra were built for another umap.panorama."
                                          "orientation_bins or orientation_spread than localize's: re-run index (--force)"))
        database = {"spectra": read_mapped(idx["spectra"])}  # about 1 GB: mapped, not copied
    else:
        database = {"bits": _dilated_bits(ctx, idx), "counts": idx["counts"][()]}
    # photo spheres stored cropped: the rows each one saw (the recall half counts the map's lines there only)
    seen = query_seen_rows(ex, lines.shape[-2])
    if seen is not None and not np.all(seen == 1.0):
        log.info("%d of %d panoramas cover part of the sphere (Photo Sphere metadata): each is scored over the rows "
                 "it covers", int(np.sum(np.any(seen == 0.0, axis=1))), len(seen))
    poses = idx["poses"][()]
    segments, faces = src["segments"][()], src["faces"][()]
    choice, lo = None, 0
    pose_ceiling = src["ceiling_m"][()] if "ceiling_m" in src else None
    # each panorama's room where umap.room_hints names it: the ceiling, the layers and the search look there only
    names = read_strings(ex["names"])
    inside, hints = _room_regions(ctx, src, poses, names) if ctx.params.room_hints is not None else (None, [])
    if pose_ceiling is not None and len(np.unique(pose_ceiling)) > 1:
        # the home's ceiling by the grid table of every ceiling's layers, then the search
        # off the grid at that ceiling, refined between the layers, alone
        choice = choose_ceiling(lines, pose_ceiling, database["spectra"], pp, seen, region_masks(inside, poses))
        lo, hi = choice.rows
        poses = poses[lo:hi]
        database = {k: v[:, lo:hi] if k == "spectra" else v[lo:hi] for k, v in database.items()}
        segments, faces = model_at_ceiling(src, choice.height)
    outside = None if inside is None else np.tile([-np.inf, -1.0], (len(lines), 1))
    found = search_layers(lines, poses, segments, faces, database, pp,
                          tolerance_px=int(ctx.params.tolerance_px), wall_margin_m=float(ctx.params.grid.wall_margin_m),
                          hidden=bool(ctx.params.hidden_lines),
                          progress=lambda it, desc, total: ctx.progress(it, total=total, desc=desc), seen=seen,
                          inside=inside, outside=outside)
    checked = None if inside is None else RoomCheck(hints, _check_room_hints(ctx, src, poses, names, inside, hints,
                                                                           outside, found.score))
    return found._replace(best=found.best + lo), choice, checked


class RoomCheck(NamedTuple):
    """Each panorama's room as ``umap.room_hints`` names it (None: not named) and the gap of
    :func:`_check_room_hints` (NaN: not named, or nothing outside its room)."""

    named: list[str | None]
    gap: np.ndarray


def _check_room_hints(ctx: Any, src: Any, poses: np.ndarray, names: list[str], inside: list[RoomRegion | None],
                      hints: list[str | None], outside: np.ndarray, score: np.ndarray) -> np.ndarray:
    """Warn about each named photo whose best grid place outside its named room (``outside``:
    its score and grid row, as the search found them) scores more than
    ``umap.room_hint_check`` above its answer (``score``, found inside; a wrong name, most
    likely), naming the room that place lies in; returns that gap of each photo (NaN where
    none was named, or nothing lies outside its room). Why the answer and not the
    room's best grid place: the answer is refined off the grid, so a right name is not flagged
    for where the grid happens to fall in its room."""
    ks = np.flatnonzero([r is not None for r in inside])
    gap = np.full(len(inside), np.nan)
    best_out, row = outside[ks, 0], outside[ks, 1].astype(np.int64)
    gap[ks] = np.where(np.isfinite(best_out), best_out - score[ks], np.nan)   # NaN: the room holds the whole grid
    limit = float(ctx.params.room_hint_check)
    flagged = [(k, j) for j, k in enumerate(ks) if gap[k] > limit]
    if flagged:
        where = rooms_of_points(src, poses[[row[j] for _, j in flagged], :2])[0]
        log.warning("%d of %d photos named for a room score far better elsewhere (by more than umap.room_hint_check "
                    "%g): check the room named in %s: %s", len(flagged), len(ks), limit, ctx.params.room_hints,
                    "; ".join(f"{names[k]} named {hints[k]!r} scores {score[k]:.3f} there and {best_out[j]:.3f} in "
                              f"{where[i] or 'no room'!r}" for i, (k, j) in enumerate(flagged[:10]))
                    + ("; ..." if len(flagged) > 10 else ""))
    return gap


def _room_regions(ctx: Any, src: Any, poses: np.ndarray, names: list[str]
                  ) -> tuple[list[RoomRegion | None], list[str | None]]:
    """Each query panorama's (frame ``names``) region where ``umap.room_hints`` names its room
    (None where it names none): the rooms of that name and ``room_hint_margin_m`` around them;
    and each one's name as given. A room the grid ``poses`` lay no position in is an error
    naming it and the fix."""
    room_names, polygons = plan_rooms(src)
    hints, stray = read_room_hints(ctx.params.room_hints, names, room_names)
    if stray:
        log.warning("umap.room_hints %s names %d frame%s that are not query images (e.g. %s); they are left out",
                    ctx.params.room_hints, len(stray), "" if len(stray) == 1 else "s", stray[0])
    regions: dict[str, RoomRegion] = {}
    for hint in dict.fromkeys(h for h in hints if h is not None):
        regions[hint] = RoomRegion([polygons[i] for i in matching_rooms(hint, room_names)],
                                   float(ctx.params.room_hint_margin_m))
        if not regions[hint](poses[:, :2]).any():
            raise _stage_error(ValueError(f"umap.room_hints: no grid position lies in {hint!r}; give umap.grid a finer "
                                          "step_m or a smaller wall_margin_m"))
    log.info("umap.room_hints: %d of %d panoramas searched in the room named for them",
             sum(h is not None for h in hints), len(names))
    return [None if h is None else regions[h] for h in hints], hints


def localize(ctx: Any) -> None:
    p = ctx.params
    c = p.ca
    idx = ctx.artifact("index")
    ex = ctx.artifact("extract")
    if (int(ex.attrs["width"]), int(ex.attrs["height"])) != (int(idx.attrs["width"]), int(idx.attrs["height"])):
        raise _stage_error(ValueError("extract and index line images differ in size: re-run extract (--force)"))
    poses = idx["poses"][()]
    if str(ex.attrs["query_kind"]) == "panorama" or str(idx.attrs.get("kind", "pinhole")) == "panorama":
        if str(ex.attrs["query_kind"]) != str(idx.attrs.get("kind", "pinhole")):
            raise _stage_error(ValueError("extract and the database disagree on umap.query_kind: re-run both (--force-all)"))
        tilt = ex["tilt_deg"][()] if "tilt_deg" in ex else None
        found, ceiling, checked = _localize_panoramas(ctx, idx, ex)
        _write_panorama_estimates(ctx, poses, read_strings(ex["names"]), found, tilt, ceiling, checked)
        return
    scorer = Scorer(_dilated_bits(ctx, idx), idx["counts"][()], poses, ex["view_heading"][()], pooled=_pooled(ctx),
                    shape=(int(idx.attrs["height"]), int(idx.attrs["width"])))
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
    if p.mode == "umap+ca":
        sensor = read_sensor_csv(p.sensor_csv, names)
        laser_d = np.array([sensor[nm][0] for nm in names])
        laser_theta = np.array([sensor[nm][1] for nm in names])
        wall_right = c.wall_side == "right"
        steps = ca_steps(ex["kp_pts"][()], ex["kp_desc"][()], ex["kp_offsets"][()], laser_d, laser_theta,
                         focal=float(ex.attrs["query_focal"]), width=int(ex.attrs["query_width"]),
                         hfov_deg=float(idx.attrs["hfov_deg"]), tracker=c.tracker, formula=c.formula, phi_deg=c.phi_deg,
                         wall_right=wall_right, vote_tol_m=c.vote_tol_m, vote_rel_tol=c.vote_rel_tol,
                         reliable_matches=c.reliable_matches, reliable_ratio=c.reliable_ratio, bin_px=c.bin_px,
                         min_matches=c.min_matches)
        ca_dist, n_kept = steps.distance, steps.matches
        faces = ctx.artifact("build-dictionary")["faces"][()]
        # Anchor: the paper starts from the frame with the best UMap score ("best"); "chain"
        # starts a chain from every frame's UMap estimate and keeps the chain with the highest
        # summed score, so one confidently wrong frame cannot carry the whole sequence off.
        anchors = [anchor] if c.anchor == "best" else list(np.argsort(-umap_score, kind="stable"))
        best_total = -1.0
        for a in ctx.progress(anchors, total=len(anchors), desc="CA chains"):
            if c.tracker == "robust":
                b, s, r = ca_track(int(a), umap_best, umap_score, steps.step, steps.reliable, steps.theta, poses, lines, scorer,
                                   error_mean_m=c.error_mean_m, error_std_m=c.error_std_m,
                                   fallback_radius_m=c.fallback_radius_m, fallback_step_m=c.fallback_step_m,
                                   wall_right=wall_right, keep_heading=c.keep_heading, tie_tol=c.tie_tol,
                                   recover_ratio=c.recover_ratio, laser_tol_m=c.laser_tol_m, alt=steps.alt,
                                   laser=(laser_d, laser_theta, faces) if c.use_laser else None)
            else:
                b, s, r = ca_chain(int(a), umap_best, umap_score, ca_dist, poses, lines, scorer,
                                   error_mean_m=c.error_mean_m, error_std_m=c.error_std_m,
                                   fallback_radius_m=c.fallback_radius_m, keep_heading=c.keep_heading)
            if s.sum() > best_total:
                best_total, anchor = float(s.sum()), int(a)
                best, score, radius = b, s, r
    est = poses[best]
    _write_result(ctx, names, est[:, 0], est[:, 1], est[:, 3], score)
    write_tree(ctx.out, {"names": names, "best_index": best, "x": est[:, 0], "y": est[:, 1], "heading_deg": est[:, 3],
                         "score": score, "ca_distance_m": ca_dist, "search_radius_m": radius, "ca_matches": n_kept,
                         "umap_x": poses[umap_best, 0], "umap_y": poses[umap_best, 1], "umap_score": umap_score})
    ctx.out.attrs.update(mode=p.mode, anchor=anchor)
    with atomic_open(ctx.output("estimates.csv"), newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "x", "y", "heading_deg", "score", "ca_distance_m", "search_radius_m"])
        for k in range(n):
            w.writerow([names[k], f"{est[k, 0]:.3f}", f"{est[k, 1]:.3f}", f"{est[k, 3]:.1f}", f"{score[k]:.5f}",
                        "" if math.isnan(ca_dist[k]) else f"{ca_dist[k]:.3f}", "" if math.isnan(radius[k]) else f"{radius[k]:.3f}"])


# fewer panoramas than this choose the home's ceiling (umap.grid.ceilings) with a warning: on
# test homes 20-22 (8 ft and 9 ft ceilings), 10 random panoramas put it within 0.05 m in 83-96 %
# of draws, a single one in 31-49 % (docs/umap.md, "How many photos the ceiling needs")
CEILING_PANORAMAS = 10


_ADVISED: list[bool] = []   # the room_hints advice given in this process (said once)

# the ceiling search's own error: within 0.02 m of the ceiling on generated homes, so a
# scale told from it within about 2 % where the ceiling stands 1 m above the camera
# (docs/umap.md, "A floor plan drawn at the wrong scale"); a smaller difference is not said
SCALE_HINT = 0.04


def _scale_hint(ctx: Any, found: float, camera_z: np.ndarray) -> None:
    """Where the ceiling found differs from the one the plan draws, say the other reading:
    a plan drawn ``s`` times the home's size puts the ceiling's lines where a ceiling of
    ``z + s (c - z)`` would, seen from a camera at ``z``."""
    drawn = drawn_ceiling(ctx.artifact("build-dictionary"))
    heights = np.unique(camera_z)
    if drawn is None or len(heights) != 1 or drawn - float(heights[0]) < 0.3:
        # the rooms' ceilings differ, or the camera's height was searched too: no one reading;
        # a ceiling within 0.3 m of the camera: the ratio says nothing (its error dominates)
        return
    z = float(heights[0])
    s = (float(found) - z) / (drawn - z)
    if abs(s - 1.0) < SCALE_HINT:
        return
    log.info("the plan draws its ceiling at %.2f m: either the home's is %.2f m, or the plan is drawn about %.0f %% too "
             "%s (with a camera at %.2f m, a plan s times the home's size shows the ceiling's lines where a ceiling of "
             "z + s (c - z) would); where you measured the ceiling, check the plan's scale on one long wall "
             "(docs/umap.md, \"A floor plan drawn at the wrong scale\")", drawn, found, abs(s - 1.0) * 100.0,
             "large" if s > 1.0 else "small", z)


def _write_panorama_estimates(ctx: Any, poses: np.ndarray, names: list[str], found: PanoramaAnswers,
                              tilt: np.ndarray | None = None, ceiling: CeilingChoice | None = None,
                              checked: RoomCheck | None = None) -> None:
    n = len(names)
    est = np.column_stack([found.xy, poses[found.best, 2:]])
    heading, score, rival, margin = found.heading, found.score, found.rival, found.margin
    nan = np.full(n, np.nan)
    rival_xy, rival_heading = found.rival_xy, found.rival_heading
    # NaN (no rival scored) is not doubtful: nothing else was a candidate
    doubtful = margin < ctx.params.panorama.doubtful_margin
    room, rival_room = rooms_of_points(ctx.artifact("build-dictionary"), est[:, :2], rival_xy)
    _write_result(ctx, names, est[:, 0], est[:, 1], heading, score, margin,
                  np.where(doubtful[:, None], rival_xy, np.nan))
    write_tree(ctx.out, {"names": names, "best_index": found.best, "x": est[:, 0], "y": est[:, 1], "heading_deg": heading,
                         "score": score, "rival_score": rival, "margin": margin, "doubtful": doubtful,
                         "rival_x": rival_xy[:, 0], "rival_y": rival_xy[:, 1], "rival_heading_deg": rival_heading,
                         "ca_distance_m": nan, "search_radius_m": nan, "ca_matches": np.zeros(n, np.int64),
                         "umap_x": est[:, 0], "umap_y": est[:, 1], "umap_score": score})
    ctx.out.attrs.update(mode=ctx.params.mode, anchor=-1)
    if doubtful.any():
        def either(k: int) -> str:   # "pano_013.png (bedroom1, or bedroom2)" where the plan names its rooms
            places = [r for r in (room[k], rival_room[k]) if r]
            if len(places) == 2 and places[0] == places[1]:
                return f"{names[k]} (both in {places[0]})"
            return names[k] + (f" ({places[0]}, or {places[1]})" if len(places) == 2 else "")

        log.warning("%d of %d answers are doubtful (margin below umap.panorama.doubtful_margin %g: another place or "
                    "heading scores nearly as well; estimates.csv gives each one's rival as rival_x, rival_y, "
                    "rival_heading_deg and rival_room): %s", int(doubtful.sum()), n, ctx.params.panorama.doubtful_margin,
                    ", ".join(either(k) for k in np.flatnonzero(doubtful)[:10]) + (", ..." if doubtful.sum() > 10 else ""))
        if ctx.params.room_hints is None and not _ADVISED and any(room[k] and rival_room[k] and room[k] != rival_room[k]
                                                                  for k in np.flatnonzero(doubtful)):
            # the one thing the photos' taker knows that lines cannot tell: which room (said once
            # a process: an experiment's hundred runs need it once)
            _ADVISED.append(True)
            log.warning("where a doubtful photo's two places lie in different rooms and you know the room it was taken "
                        "in, name it in umap.room_hints (a CSV frame, room): it is then searched in that room only "
                        "(docs/umap.md, \"The room each photo was taken in\")")
    # the camera height each answer was found at, where several were searched (umap.grid.heights)
    heights = len(np.unique(poses[:, 2])) > 1
    if heights:
        ctx.out.create_dataset("height_m", data=est[:, 2])
        found_at = np.unique(est[:, 2], return_counts=True)
        log.info("camera heights found (umap.grid.heights): %s",
                 ", ".join(f"{z:.2f} m for {c} of {n}" for z, c in zip(*found_at)))
    # the home's ceiling height, where several were searched (umap.grid.ceilings)
    ceilings = ceiling is not None
    if ceilings:
        found_ceiling = np.full(n, round(ceiling.height, 2))
        ctx.out.create_dataset("ceiling_m", data=found_ceiling)
        ctx.out.create_dataset("ceiling_grid_means", data=np.array(sorted(ceiling.means.items()), np.float64))
        log.info("ceiling height found (umap.grid.ceilings): %.2f m; the grid's mean best score at each ceiling "
                 "searched: %s", found_ceiling[0], ", ".join(f"{c:.2f} m {v:.4f}" for c, v in sorted(ceiling.means.items())))
        if n < CEILING_PANORAMAS:
            log.warning("the ceiling height was found from %d panorama%s: with fewer than %d it is often 0.05 m or "
                        "more off (docs/umap.md, \"How many photos the ceiling needs\"); give the ceiling if you can "
                        "measure it, or localize more photos of the home together", n, "" if n == 1 else "s",
                        CEILING_PANORAMAS)
        _scale_hint(ctx, found_ceiling[0], poses[:, 2])
        if ceiling.at_edge:
            lowest = ceiling.layer == min(ceiling.means)
            log.warning("the ceiling found, %.2f m, is the %s of umap.grid.ceilings: the home's may lie beyond them; "
                        "search %s ceilings too", ceiling.layer, "lowest" if lowest else "highest",
                        "lower" if lowest else "higher")
    # how far each panorama was turned upright (umap.panorama.level_max_deg), where any was
    levelled = tilt is not None and bool(np.any(tilt > 0))
    if levelled:
        ctx.out.create_dataset("tilt_deg", data=np.asarray(tilt, np.float64))
        log.info("panoramas levelled (umap.panorama.level_max_deg): %d of %d turned upright, by %.1f deg at the median "
                 "and %.1f at most", int(np.sum(tilt > 0)), n, float(np.median(tilt[tilt > 0])), float(np.max(tilt)))
    # each photo's room as named (umap.room_hints) and how far a place outside it scored above
    # the answer (room_hint_gap; above umap.room_hint_check the name was warned about)
    gap = None if checked is None else checked.gap
    named = [""] * n if checked is None else [h or "" for h in checked.named]
    if checked is not None:
        write_tree(ctx.out, {"room_hint_gap": gap, "room_named": named})
    with atomic_open(ctx.output("estimates.csv"), newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "x", "y", "heading_deg", *(["height_m"] if heights else []),
                    *(["ceiling_m"] if ceilings else []), *(["tilt_deg"] if levelled else []),
                    "score", "rival_score", "margin", "doubtful", "rival_x", "rival_y", "rival_heading_deg", "room",
                    "rival_room", *(["room_named", "room_hint_gap"] if gap is not None else [])])
        for k in range(n):
            w.writerow([names[k], f"{est[k, 0]:.3f}", f"{est[k, 1]:.3f}", f"{heading[k]:.1f}",
                        *([f"{est[k, 2]:.2f}"] if heights else []), *([f"{found_ceiling[k]:.2f}"] if ceilings else []),
                        *([f"{tilt[k]:.1f}"] if levelled else []),
                        f"{score[k]:.5f}",
                        _csv_number(rival[k]), _csv_number(margin[k]), "true" if doubtful[k] else "false",
                        _csv_number(rival_xy[k, 0], 3), _csv_number(rival_xy[k, 1], 3), _csv_number(rival_heading[k], 1),
                        room[k], rival_room[k], *([named[k], _csv_number(gap[k], 4)] if gap is not None else [])])


def _csv_number(x: float, decimals: int = 5) -> str:
    """A number in estimates.csv (empty for NaN: no rival was scored)."""
    return "" if math.isnan(x) else f"{x:.{decimals}f}"


def _write_result(ctx: Any, names: list[str], x: np.ndarray, y: np.ndarray, heading: np.ndarray, score: np.ndarray,
                  margin: np.ndarray | None = None, alternative: np.ndarray | None = None) -> None:
    """The ``poses`` contract, with the plan's walls (room outlines, else the wireframe seen from above), and
    for panoramas each answer's margin over its rival as the confidence and the doubtful answers' rivals as
    their alternatives."""
    from placeloc.evaluation import pose_estimates

    plan = ctx.artifact("build-dictionary")
    labels = label_xy = None
    if "plan" in plan:
        # polygon_0, polygon_1, ..., polygon_10 in the order written (room_names follows it)
        keys = sorted(plan["plan"].keys(), key=lambda k: int(k.rsplit("_", 1)[1]))
        polygons = [plan["plan"][k][()] for k in keys]
        walls = [np.column_stack([q, np.roll(q, -1, axis=0)]) for q in polygons]
        segments = np.concatenate(walls) if walls else np.zeros((0, 4))
        if "room_names" in plan and polygons:  # each room's name written inside it on the plan picture
            labels = read_strings(plan["room_names"])[:len(polygons)]
            label_xy = label_points(polygons[:len(labels)])
    else:
        segments = plan["segments"][()][:, [0, 1, 3, 4]]
    pose_estimates.write(ctx, names=names, x=x, y=y, heading_deg=heading, score=score, plan_segments=segments,
                         label=str(ctx.params.mode), confidence=margin,
                         confidence_label="score margin over the best rival pose", alternative=alternative,
                         plan_openings=plan["plan_gaps"][()] if "plan_gaps" in plan else None, plan_labels=labels,
                         plan_label_xy=label_xy)


# ------------------------------------------------------------------ evaluate: the poses contract scores; UMap adds

def evaluate_extra(ctx: Any, ev: PoseEvaluation) -> None:
    """UMap's own figures: the mode in metrics.json, for panoramas with true headings how
    often a doubtful answer's rival is where the camera stood (:func:`rival_metrics`), on a
    plan of rooms the share of answers in the camera's room (``room_right``, over the
    ``room_frames`` whose true position lies in a named room), and each panorama's lines
    against the map rendered at the estimate and at the truth."""
    loc = ctx.artifact("localize")
    ev.metrics["mode"] = str(loc.attrs["mode"])
    ev.label = ev.metrics["mode"]
    if "rival_x" in loc and ev.yaw_err is not None:
        ev.metrics.update(rival_metrics(ev, loc["doubtful"][()], loc["rival_x"][()], loc["rival_y"][()],
                                        loc["rival_heading_deg"][()]))
        # in the headline beside the share it qualifies: what checking both places of the doubtful answers finds
        head = ev.metrics["headline"]
        head.insert(head.index("within_1m_30deg") + 1 if "within_1m_30deg" in head else 0, "within_1m_30deg_or_rival")
    # a plan of rooms: how often the answer's room is the camera's (what a person asks first)
    room_est, room_truth = rooms_of_points(ctx.artifact("build-dictionary"), ev.est, ev.truth)
    named = np.array([bool(r) for r in room_truth])
    if named.any():
        ev.metrics["room_right"] = float(np.mean([e == t for e, t, k in zip(room_est, room_truth, named) if k]))
        ev.metrics["room_frames"] = int(named.sum())
    ex = ctx.artifact("extract")
    if ctx.config.get("plots", True) and str(ex.attrs["query_kind"]) == "panorama":
        ev.method_pictures = panorama_pictures(ctx, ex, ctx.artifact("build-dictionary"), loc, ev.poses, ev.rows, ev.err,
                                                ev.yaw_err)
        ceiling_picture(ctx.output("ceiling_scores.png"), loc)


def rival_metrics(ev: PoseEvaluation, doubtful: np.ndarray, rival_x: np.ndarray, rival_y: np.ndarray,
                  rival_heading_deg: np.ndarray) -> dict[str, Any]:
    """What the doubtful answers' rivals are worth, against the truth: ``doubtful_answers``
    (margin below ``doubtful_margin``), ``doubtful_wrong`` (of those, not within 1 m and 30
    deg), ``doubtful_wrong_rival_right`` (of those, the rival within 1 m and 30 deg: a twin
    room's spot where the camera stood) and ``within_1m_30deg_or_rival`` (the share of
    frames whose answer is right, or doubtful with its rival right: the share a user who
    checks both places of every doubtful answer finds). A rival of NaN is never right."""
    right = right_answers(ev.err, ev.yaw_err)
    with np.errstate(invalid="ignore"):
        rival_err = np.hypot(rival_x - ev.truth[:, 0], rival_y - ev.truth[:, 1])
        rival_right = right_answers(rival_err, yaw_errors(rival_heading_deg, ev.truth_heading)) & np.isfinite(rival_err)
    doubtful = np.asarray(doubtful, bool)
    return {"doubtful_answers": int(doubtful.sum()), "doubtful_wrong": int((doubtful & ~right).sum()),
            "doubtful_wrong_rival_right": int((doubtful & ~right & rival_right).sum()),
            "within_1m_30deg_or_rival": float(np.mean(right | (doubtful & rival_right))) if len(right) else math.nan}


# Exactly the CA parameters the localize stage reads (akaze_threshold belongs to extract).
LOCALIZE_CA_KEYS = tuple(f"ca.{k}" for k in (
    "formula", "wall_side", "phi_deg", "error_mean_m", "error_std_m", "bin_px", "min_matches", "fallback_radius_m", "anchor",
    "keep_heading", "tracker", "vote_tol_m", "vote_rel_tol", "reliable_matches", "reliable_ratio", "tie_tol", "recover_ratio",
    "fallback_step_m", "laser_tol_m", "use_laser"))

METHOD = Method(
    resources=umap_resources,
    name="umap",
    params=UMapParams,
    stages={
        "extract": Stage(extract, keys=("camera", "query_kind", "lsd_min_length_px", "query_thickness_px", "ca.akaze_threshold",
                                        "grid.headings", "panorama.width", "panorama.height", "panorama.face_px",
                                        "panorama.lsd_min_length_px", "panorama.orientation_bins",
                                        "panorama.level_max_deg", "panorama.equalize_clip")),
        # the map database and its index are drawn from the plan alone: a photo added or changed
        # re-runs extract and localize, not these (0.7-1 GB and seconds of renders at a home's size)
        "build-dictionary": Stage(build_dictionary, parents=(), keys=("model", "floor", "camera", "grid", "near_m", "hidden_lines", "query_kind",
                                                          "panorama.width", "panorama.height", "tolerance_px",
                                                          "panorama.orientation_bins")),
        "index": Stage(index, parents=("build-dictionary",), keys=("tolerance_px", "panorama.score", "panorama.chamfer_tau_px", "panorama.polar_deg",
                                    "panorama.polar_weight", "panorama.solid_angle", "panorama.chamfer_chance",
                                    "panorama.clutter_share", "panorama.orientation_bins", "panorama.orientation_spread")),
        "localize": Stage(localize, parents=("extract", "index"), keys=("mode", "sensor_csv", "room_hints", "room_hint_margin_m", "room_hint_check",
                                          "panorama.score",
                                          "panorama.chamfer_tau_px", "panorama.chamfer_chance", "panorama.recall_weight",
                                          "panorama.clutter_share", "panorama.texture_radius_px", "panorama.precision_polar_deg",
                                          "panorama.polar_deg", "panorama.polar_weight", "panorama.solid_angle", "tolerance_px",
                                          "panorama.refine_candidates", "panorama.refine_separation_m", "panorama.refine_top",
                                          "panorama.coarse_candidates", "panorama.coarse_tau_px", "panorama.coarse_blur_px",
                                          "panorama.refine_climb", "panorama.orientation_bins", "panorama.orientation_spread",
                                          "panorama.refine_beam", "panorama.refine_beam_within", "panorama.refine_square", "panorama.refine_step_m",
                                          "panorama.refine_final_m", "panorama.refine_final_start_m", "panorama.refine_final_radius_m",
                                          "panorama.refine_final_ties",
                                          "panorama.refine_yaw_cols",
                                          "panorama.margin_distance_m", "panorama.margin_yaw_deg",
                                          "panorama.doubtful_margin", "panorama.height_layers", "hidden_lines",
                                          "grid.wall_margin_m")
                          + LOCALIZE_CA_KEYS),
    },
    result="poses",
    # read by localize alone: editing the per-frame sensor or room file re-runs localize, not the map
    file_stages={"model": "build-dictionary", "sensor_csv": "localize", "room_hints": "localize"},
    evaluate_extra=evaluate_extra,
    show_extra=show_extra,
    report_pictures=report_pictures,
    required_images=("query",),
    checker=_check,
    citation="K. Takahashi, J. Takahashi, T. Kaneko and Y. Tobe, \"Improving pre-map indoor localization by comparing "
             "consecutive images\" (Universal Map with Consistency Adjustment)",
)
