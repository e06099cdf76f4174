"""UMap benchmark, two cases in one run.

1. The paper's size: a 36,032-view database of the synthetic corridor building, rendered
   with the per-pixel hidden-line renderer, packed and dilated; one query scored against
   every view with the bit-packed AND + popcount kernel versus the naive per-view NumPy loop.
2. A real-scale floor (``--floor``): three generated homes side by side (about 480
   segments and 156 wall faces, the size of a real floor of ten rooms), a 0.3 m x 5 degree
   grid (about 253,000 views of 160 x 120): the per-position renderer
   (:func:`placeloc.umap.render.render_grid`: visibility once per position, lines drawn
   already dilated, one stored copy) against the per-pixel renderer plus the separate
   dilation pass (timed on an evenly spread subset and extrapolated per view), their
   agreement on a few hundred views, the stored size and the time to score one query.

3. Whole panoramas (``--panorama-only``): about 2,000 grid positions of a generated home x
   144 yaws, 32 query line images (map renders at off-grid poses and random headings, a
   third of their lines dropped, clutter added): the localize stage's search
   (:func:`placeloc.umap.panorama.search_panoramas` with the default parameters but the plain score: chamfer
   spectra, batched, the cell stage and the coarse-to-fine beam) against the search before the spectra (the chamfer
   score pixel by pixel for every shift, then 8 candidates each re-scored on a 7 x 7 local
   grid), both timed in the same run, per panorama, wall and CPU; also the beam climbing by
   8 neighbours only (``refine_square`` 1) and every candidate climbing once first
   (``refine_climb`` 1), each against the defaults in the same run; and the oriented score
   (``orientation_bins`` B for each B of ``--orientation-bins``, spread 1 (0 for B = 2); 6
   bins, spread 1 are the defaults: the same queries with their directions, the clutter's
   at random), its index and search against the plain score's in the same run, and with the
   final pattern search of the beam's best pose (``refine_final_m``, ``--final-m``) against
   it in the same run, and that search from the best lattice point within
   ``refine_final_radius_m`` (the defaults) against it from the lattice point nearest the
   beam's pose, and that search from every pose of the beam within ``refine_final_ties`` of
   its best (the defaults) against from its best pose only; and the beam cut to the poses
   within ``refine_beam_within`` of the cell stage's best (the defaults) against the whole
   beam of ``refine_beam``.

    python bench/bench_umap.py [--views 36032] [--floor-only] [--panorama-only] [--old-views 3000]

The panorama case ends with the search over numba thread counts 1, 2, 4, ... (`--workers`).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import cv2
import numba
import numpy as np

from placeloc.geometry import Camera, pose_grid
from placeloc.geometry.floorplan import floor_plan_model
from placeloc.synth.corridor import building
from placeloc.umap.bits import best_iou, iou_naive, iou_scores, pack, popcount_rows, unpack
from placeloc.umap.render import render_grid, render_packed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--views", type=int, default=36032)
    ap.add_argument("--tolerance", type=int, default=2)
    ap.add_argument("--floor-only", action="store_true", help="only the real-scale floor case")
    ap.add_argument("--old-views", type=int, default=3000, help="views the per-pixel renderer is timed on (floor case)")
    ap.add_argument("--grid-step", type=float, default=0.3, help="grid spacing of the floor case in metres")
    ap.add_argument("--queries", type=int, default=30, help="queries timed in the floor case")
    ap.add_argument("--panorama-only", action="store_true", help="only the whole-panorama search")
    ap.add_argument("--panorama-positions", type=int, default=2000, help="grid positions of the panorama case (about)")
    ap.add_argument("--old-panoramas", type=int, default=6, help="panoramas the search before is timed on")
    ap.add_argument("--orientation-bins", default="2,4,6,8",
                    help="direction bin counts of the oriented score timed against the defaults (empty: none)")
    ap.add_argument("--final-m", type=float, default=0.01,
                    help="the oriented cases also timed with the final pattern search down to this many metres "
                         "(umap.panorama.refine_final_m; 0: not)")
    ap.add_argument("--final-start-m", default="0,0.08",
                    help="comma-separated first steps of that search in metres (umap.panorama.refine_final_start_m; 0: "
                         "the beam's finest step)")
    ap.add_argument("--workers", default=None,
                    help="numba thread counts of the panorama search's scaling table (default 1, 2, 4, ..., the threads; 0: none)")
    args = ap.parse_args()
    if not args.panorama_only:
        if not args.floor_only:
            corridor(args)
        floor(args)
    panorama(args)


def _today_search(lines: np.ndarray, poses: np.ndarray, model, db: np.ndarray, close: np.ndarray, w: int, h: int) -> list:  # noqa: ANN001
    """The panorama search before the spectra: the chamfer score pixel by pixel for every
    shift, then the 8 best distinct positions re-scored on a 7 x 7 local grid (0.05 m)."""
    from placeloc.geometry.floorplan import wall_distance
    from placeloc.umap.panorama import best_pose, chamfer_yaw_scores, closeness, distinct_candidates, local_grid, render_panoramas

    out = []
    for q in lines:
        table = chamfer_yaw_scores(db, close, q, tau_px=3.0, chance="none")
        i, k, s = best_pose(table)
        best = (poses[i, :2], k, s)
        for c in distinct_candidates(table, poses[:, :2], count=8, min_separation_m=0.5):
            pts = local_grid(poses[c, 0], poses[c, 1], radius_m=0.15, step_m=0.05)
            pts = pts[wall_distance(pts, model.faces) >= min(0.1, float(wall_distance(poses[c:c + 1, :2], model.faces)[0]))]
            local = np.column_stack([pts, np.full(len(pts), poses[c, 2]), np.zeros(len(pts))])
            raw = render_panoramas(model.segments, model.faces, local, width=w, height=h, hidden=True)
            sub = chamfer_yaw_scores(raw, closeness(unpack(raw, h, w), 3.0), q, tau_px=3.0, chance="none")
            j, ks, sc = best_pose(sub)
            if sc > best[2]:
                best = (pts[j], ks, sc)
        out.append(best)
    return out


def panorama(args: argparse.Namespace) -> None:
    from placeloc.geometry.floorplan import plan_grid
    from placeloc.synth.home import plan as home_plan
    from placeloc.umap.panorama import chamfer_spectra, closeness, render_panoramas, row_weights, search_panoramas
    from placeloc.umap.params import PanoramaParams

    fp, _ = home_plan(np.random.default_rng(0), 3)
    model = floor_plan_model({**fp, "camera_z": 1.5}, "a generated home")
    # the grid step that gives about the asked number of positions
    area = len(plan_grid(model, step_m=0.1)[0]) * 0.01
    step = round(float(np.sqrt(area / args.panorama_positions)), 3)
    poses = plan_grid(model, step_m=step)[0]
    pp = PanoramaParams(orientation_bins=1)   # the plain score: the baseline of the oriented cases
    w, h = pp.width, pp.height
    rng = np.random.default_rng(1)
    truth = poses[rng.choice(len(poses), 32, replace=False)].copy()
    truth[:, :2] += rng.uniform(-step / 2, step / 2, size=(32, 2))
    truth[:, 3] = rng.choice(w, 32) * 360.0 / w
    q = unpack(render_panoramas(model.segments, model.faces, truth, width=w, height=h, hidden=True), h, w)
    q = (q & (rng.random(q.shape) < 0.66)) | (rng.random(q.shape) < 0.01)
    print(f"\nwhole panoramas: {len(poses):,} grid positions ({step} m) x {w} yaws, {len(q)} queries; score {pp.score} "
          f"(chance: {pp.chamfer_chance}, solid-angle rows: {pp.solid_angle}), {pp.refine_candidates} candidate cells, beam {pp.refine_beam}, "
          f"beam square {pp.refine_square}; cores "
          f"{os.cpu_count()}, load average {os.getloadavg()[0]:.1f}")
    db = render_panoramas(model.segments, model.faces, poses, width=w, height=h, hidden=True)
    weights = row_weights(h, polar_deg=pp.polar_deg, polar_weight=pp.polar_weight, solid_angle=pp.solid_angle)
    spectra, t_idx, c_idx = _timed(chamfer_spectra, unpack(db, h, w), tau_px=pp.chamfer_tau_px, weights=weights)
    print(f"index (map spectra, once per database): {t_idx:.2f} s wall, {c_idx:.2f} s CPU, {spectra.nbytes / 2**20:.0f} MiB")
    search_panoramas(q[:2], poses, model.segments, model.faces, {"spectra": spectra}, pp, tolerance_px=2,
                     wall_margin_m=0.1, hidden=True)  # JIT and caches
    res, t_new, c_new = _timed(search_panoramas, q, poses, model.segments, model.faces, {"spectra": spectra}, pp,
                               tolerance_px=2, wall_margin_m=0.1, hidden=True)
    # the same search with the beam climbing by its 8 neighbours only (the search before the
    # beam's square), timed in the same run
    res1, t_climb, c_climb = _timed(search_panoramas, q, poses, model.segments, model.faces, {"spectra": spectra},
                                    PanoramaParams(refine_square=1, orientation_bins=1), tolerance_px=2, wall_margin_m=0.1, hidden=True)
    # every candidate climbing once before the beam (refine_climb 1), timed in the same run
    resc, t_all, c_all = _timed(search_panoramas, q, poses, model.segments, model.faces, {"spectra": spectra},
                                PanoramaParams(refine_climb=1, orientation_bins=1), tolerance_px=2, wall_margin_m=0.1, hidden=True)
    pp0 = PanoramaParams(refine_candidates=0, orientation_bins=1)
    _, t_glob, c_glob = _timed(search_panoramas, q, poses, model.segments, model.faces, {"spectra": spectra}, pp0,
                               tolerance_px=2, wall_margin_m=0.1, hidden=True)
    err = np.hypot(*(res[1] - truth[:, :2]).T)
    n = len(q)
    print(f"localize search, the plain score (orientation_bins 1), otherwise the defaults: {t_new / n * 1e3:.0f} ms wall, "
          f"{c_new / n * 1e3:.0f} ms CPU per panorama (target "
          f"<= 100 ms wall); of it every position x yaw: {t_glob / n * 1e3:.1f} ms wall, {c_glob / n * 1e3:.1f} ms CPU; within "
          f"0.05 m of the truth {np.mean(err <= 0.05):.0%}, within 0.1 m {np.mean(err <= 0.1):.0%}; load average now "
          f"{os.getloadavg()[0]:.1f}")
    # the queries one after another, each kernel on every core (panorama.PANORAMA_THREADS = 1),
    # against side by side, one a thread (the default), timed in the same run
    from placeloc.umap import panorama as panorama_module

    panorama_module.PANORAMA_THREADS = 1
    try:
        res_seq, t_seq, c_seq = _timed(search_panoramas, q, poses, model.segments, model.faces, {"spectra": spectra}, pp,
                                       tolerance_px=2, wall_margin_m=0.1, hidden=True)
    finally:
        panorama_module.PANORAMA_THREADS = None
    same = all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(res, res_seq))
    print(f"the queries one after another (PANORAMA_THREADS 1): {t_seq / n * 1e3:.0f} ms wall, {c_seq / n * 1e3:.0f} ms CPU "
          f"per panorama; side by side on {panorama_module.panorama_threads(n)} threads (the default) {t_new / n * 1e3:.0f} ms "
          f"wall; ratio one after another / side by side {t_seq / t_new:.2f}x wall; the same answers: {same}")
    err1 = np.hypot(*(res1[1] - truth[:, :2]).T)
    print(f"the beam by 8 neighbours only (refine_square 1): {t_climb / n * 1e3:.0f} ms wall, {c_climb / n * 1e3:.0f} ms CPU per "
          f"panorama; within 0.05 m {np.mean(err1 <= 0.05):.0%}; ratio plain search / that {t_new / t_climb:.2f}x wall, "
          f"{c_new / c_climb:.2f}x CPU")
    errc = np.hypot(*(resc[1] - truth[:, :2]).T)
    print(f"every candidate climbing once first (refine_climb 1): {t_all / n * 1e3:.0f} ms wall, {c_all / n * 1e3:.0f} ms "
          f"CPU per panorama; within 0.05 m {np.mean(errc <= 0.05):.0%}; ratio that / plain search {t_all / t_new:.2f}x wall, "
          f"{c_all / c_new:.2f}x CPU")
    for bins in [int(b) for b in args.orientation_bins.split(",") if b.strip()]:
        _oriented_case(bins, model, poses, truth, q, rng, (t_idx, c_idx, t_new, c_new), args.final_m,
                       tuple(float(x) for x in args.final_start_m.split(",")))
    close = closeness(unpack(db, h, w), 3.0)
    m = min(args.old_panoramas, n)
    _today_search(q[:1], poses, model, db, close, w, h)  # JIT
    old, t_old, c_old = _timed(_today_search, q[:m], poses, model, db, close, w, h)
    from placeloc.umap.panorama import chamfer_yaw_scores

    _, t_oglob, _ = _timed(lambda: [chamfer_yaw_scores(db, close, x, tau_px=3.0, chance="none") for x in q[:m]])
    print(f"the search before (timed on {m} panoramas): {t_old / m * 1e3:.0f} ms wall, {c_old / m * 1e3:.0f} ms CPU per panorama; "
          f"of it every position x yaw: {t_oglob / m * 1e3:.0f} ms wall")
    print(f"ratio, before / now, per panorama: whole search {t_old / m / (t_new / n):.1f}x wall, {c_old / m / (c_new / n):.1f}x "
          f"CPU; every position x yaw {t_oglob / m / (t_glob / n):.1f}x wall")
    if args.workers != "0":
        # the search's parallel kernels over numba thread counts (numba.set_num_threads)
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from scaling import counts_from, markdown, scaling_table

        top = numba.get_num_threads()
        counts = counts_from(args.workers, top)

        def measure(k: int) -> dict[str, float]:
            # k threads: the queries side by side on k (panorama.PANORAMA_THREADS), and the
            # tables' kernels on k numba threads
            numba.set_num_threads(min(k, top))
            panorama_module.PANORAMA_THREADS = k
            try:
                _, wall, _ = _timed(search_panoramas, q, poses, model.segments, model.faces, {"spectra": spectra}, pp,
                                    tolerance_px=2, wall_margin_m=0.1, hidden=True)
                return {f"localize search, {len(poses):,} positions, per panorama": wall / n}
            finally:
                numba.set_num_threads(top)
                panorama_module.PANORAMA_THREADS = None

        print(markdown(scaling_table(measure, counts, warm_up=False), "UMap whole-panorama search", unit="thread",
                       note="k threads: the queries side by side on k (panorama.PANORAMA_THREADS) and numba's "
                            "kernels on k (numba.set_num_threads); BLAS and SciPy's transforms on every core; one "
                            "run each."))


def _oriented_case(bins: int, model, poses: np.ndarray, truth: np.ndarray, q: np.ndarray, rng: np.random.Generator,  # noqa: ANN001
                   default_times: tuple[float, float, float, float], final_m: float = 0.0,
                   final_starts: tuple[float, ...] = (0.0,)) -> None:
    """The oriented score with ``bins`` direction bins: index and search timed, against the
    plain score's (``default_times``: index wall, CPU, search wall, CPU) measured in the same run;
    with ``final_m`` > 0, the search with ``refine_final_m`` at it (from each first step of
    ``final_starts``) against it off."""
    from dataclasses import replace

    from placeloc.geometry.panorama import render_panoramas
    from placeloc.umap.panorama import chamfer_spectra, orientation_channels, row_weights, search_panoramas
    from placeloc.umap.params import PanoramaParams

    pp = PanoramaParams(orientation_bins=bins, orientation_spread=0 if bins == 2 else 1)
    w, h = pp.width, pp.height
    # the same query pixels, each with its map direction; the clutter pixels a random direction
    masks = render_panoramas(model.segments, model.faces, truth, width=w, height=h, hidden=True, orientation_bins=bins)
    clutter = (q != 0) & (masks == 0)
    masks = np.where(q != 0, masks, 0).astype(np.uint8)
    masks[clutter] = (1 << rng.integers(0, bins, int(clutter.sum()))).astype(np.uint8)
    qo = orientation_channels(masks, bins)
    weights = row_weights(h, polar_deg=pp.polar_deg, polar_weight=pp.polar_weight, solid_angle=pp.solid_angle)
    chans = orientation_channels(render_panoramas(model.segments, model.faces, poses, width=w, height=h, hidden=True,
                                                  orientation_bins=bins), bins)
    spectra, t_idx, c_idx = _timed(chamfer_spectra, chans, tau_px=pp.chamfer_tau_px, weights=weights,
                                   spread=pp.orientation_spread)
    del chans
    db = {"spectra": spectra}
    search_panoramas(qo[:2], poses, model.segments, model.faces, db, pp, tolerance_px=2, wall_margin_m=0.1, hidden=True)
    res, t, c = _timed(search_panoramas, qo, poses, model.segments, model.faces, db, pp, tolerance_px=2,
                       wall_margin_m=0.1, hidden=True)
    pp0 = PanoramaParams(orientation_bins=bins, orientation_spread=pp.orientation_spread, refine_candidates=0)
    _, t_glob, c_glob = _timed(search_panoramas, qo, poses, model.segments, model.faces, db, pp0, tolerance_px=2,
                               wall_margin_m=0.1, hidden=True)
    n = len(qo)
    err = np.hypot(*(res[1] - truth[:, :2]).T)

    def searched(p: PanoramaParams) -> tuple:
        """The search with parameters p, timed: the defaults' run above where p is the defaults."""
        return (res, t, c) if p == pp else _timed(search_panoramas, qo, poses, model.segments, model.faces, db, p,
                                                  tolerance_px=2, wall_margin_m=0.1, hidden=True)

    for start_m in final_starts if final_m > 0 else []:
        # the final pattern search of the beam's best pose (refine_final_m, first step
        # refine_final_start_m, from the lattice point nearest the beam's pose) on and off, timed in the same run
        on = replace(pp, refine_final_m=final_m, refine_final_start_m=start_m, refine_final_radius_m=0.0)
        off = replace(pp, refine_final_m=0.0)
        timed = {}
        for name, p in (("on", on), ("off", off)):
            timed[name] = searched(p)
        (ron, ton, con), (roff, toff, coff) = timed["on"], timed["off"]
        eon, eoff = (np.hypot(*(r[1] - truth[:, :2]).T) for r in (ron, roff))
        print(f"oriented score, {bins} bins, with the final pattern search from {start_m or 'the beam finest step'} "
              f"down to {final_m} m (refine_final_start_m, refine_final_m): {ton / n * 1e3:.0f} ms wall, "
              f"{con / n * 1e3:.0f} ms CPU per panorama against {toff / n * 1e3:.0f} ms wall, {coff / n * 1e3:.0f} ms CPU "
              f"without: {ton / toff:.2f}x wall, {con / coff:.2f}x CPU; median error {np.median(eon):.3f} m against "
              f"{np.median(eoff):.3f} m, within 0.05 m {np.mean(eon <= 0.05):.0%} against {np.mean(eoff <= 0.05):.0%}")
    if final_m > 0 and pp.refine_final_radius_m > 0:
        # the final search from the best point of the plan's lattice within refine_final_radius_m
        # (the defaults) against it from the lattice point nearest the beam's pose, in the same run
        near = replace(pp, refine_final_m=final_m, refine_final_radius_m=0.0)
        disk = replace(pp, refine_final_m=final_m)
        (rn, tn_, cn_), (rd, td, cd) = (searched(p) for p in (near, disk))
        en, ed = (np.hypot(*(r[1] - truth[:, :2]).T) for r in (rn, rd))
        print(f"oriented score, {bins} bins, the final search from the best lattice point within "
              f"{pp.refine_final_radius_m} m (refine_final_radius_m): {td / n * 1e3:.0f} ms wall, {cd / n * 1e3:.0f} ms "
              f"CPU per panorama against {tn_ / n * 1e3:.0f} ms wall, {cn_ / n * 1e3:.0f} ms CPU from the lattice point "
              f"nearest the beam's pose: {td / tn_:.2f}x wall, {cd / cn_:.2f}x CPU; median error {np.median(ed):.3f} m "
              f"against {np.median(en):.3f} m")

    def compared(what: str, new: PanoramaParams, old: PanoramaParams, old_what: str) -> None:
        """The search with ``new`` (the defaults) against ``old``, timed in the same run."""
        (r_old, t_old, c_old), (r_new, t_new, c_new) = (searched(p) for p in (old, new))
        moved = int(np.sum(np.hypot(*(r_old[1] - r_new[1]).T) > 0.05))
        print(f"oriented score, {bins} bins, {what}: {t_new / n * 1e3:.0f} ms wall, {c_new / n * 1e3:.0f} ms CPU per "
              f"panorama against {t_old / n * 1e3:.0f} ms wall, {c_old / n * 1e3:.0f} ms CPU {old_what}: "
              f"{t_new / t_old:.2f}x wall, {c_new / c_old:.2f}x CPU; {moved} of {n} answers elsewhere (more than 0.05 m)")

    if final_m > 0 and pp.refine_final_ties > 0:
        # the final search from every pose of the beam within refine_final_ties of its best
        # (the defaults) against from its best pose only, in the same run
        compared(f"the final search from every pose of the beam within {pp.refine_final_ties} of its best "
                 "(refine_final_ties)", replace(pp, refine_final_m=final_m),
                 replace(pp, refine_final_m=final_m, refine_final_ties=0.0), "from its best pose only")
    if pp.refine_beam_within > 0:
        # the beam cut to the poses within refine_beam_within of the cell stage's best (the
        # defaults) against the whole beam of refine_beam, in the same run
        compared(f"the beam cut to the poses within {pp.refine_beam_within} of the cell stage's best "
                 "(refine_beam_within)", pp, replace(pp, refine_beam_within=0.0),
                 f"with the whole beam of {pp.refine_beam}")
    ti, ci, tn, cn = default_times
    print(f"oriented score, {bins} bins (spread {pp.orientation_spread}): index {t_idx:.2f} s wall, {c_idx:.2f} s CPU, "
          f"{spectra.nbytes / 2**20:.0f} MiB ({t_idx / ti:.1f}x the plain score's wall); search {t / n * 1e3:.0f} ms wall, "
          f"{c / n * 1e3:.0f} ms CPU per panorama, of it every position x yaw {t_glob / n * 1e3:.1f} ms wall, "
          f"{c_glob / n * 1e3:.1f} ms CPU; ratio that / the plain score {t / tn:.2f}x wall, {c / cn:.2f}x CPU; within 0.05 m "
          f"{np.mean(err <= 0.05):.0%}; load average now {os.getloadavg()[0]:.1f}")


def _dilate(db: np.ndarray, cam: Camera, tolerance: int) -> np.ndarray:
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * tolerance + 1,) * 2)
    out = np.empty_like(db)
    for s in range(0, len(db), 2048):
        out[s:s + 2048] = pack(np.stack([cv2.dilate(im, kernel) for im in unpack(db[s:s + 2048], cam.height, cam.width)]))
    return out


def _timed(fn, *a, **k):  # noqa: ANN001, ANN002, ANN003, ANN202
    w, c = time.perf_counter(), time.process_time()
    out = fn(*a, **k)
    return out, time.perf_counter() - w, time.process_time() - c


def floor(args: argparse.Namespace) -> None:
    from placeloc.geometry.floorplan import free_space_mask
    from placeloc.synth.home import floor_of_homes

    model = floor_plan_model(floor_of_homes(np.random.default_rng(0), 3, 4), "three generated homes")
    cam = Camera(160, 120, 60.0)
    xy = np.concatenate(model.polygons)
    lo, hi = xy.min(0), xy.max(0)
    grid = pose_grid([lo[0], hi[0], args.grid_step], [lo[1], hi[1], args.grid_step], 1.14, list(np.arange(0.0, 360.0, 5.0)))
    keep, _ = free_space_mask(grid[:, :2], model, inside_only=True, wall_margin_m=0.1)
    poses = grid[keep]
    n_pos = len(np.unique(poses[:, :2], axis=0))
    print(f"\nreal-scale floor: {len(model.segments)} segments, {len(model.faces)} wall faces, {len(model.polygons)} rooms; "
          f"grid {args.grid_step} m x 5 deg: {n_pos} positions, {len(poses):,} views of {cam.width}x{cam.height}; "
          f"cores {os.cpu_count()}, numba threads {numba.get_num_threads()}; load average {os.getloadavg()[0]:.1f}")
    tol = args.tolerance
    render_grid(model.segments, model.faces, poses[:144], cam, near=0.05, hidden=True, tolerance_px=tol, pooled=True)  # JIT
    (db, cells), wall, cpu = _timed(render_grid, model.segments, model.faces, poses, cam, near=0.05, hidden=True,
                                    tolerance_px=tol, pooled=True)
    print(f"per-position renderer, lines drawn {tol} px thick: {wall:.2f} s wall, {cpu:.2f} s CPU "
          f"({len(poses) / wall:,.0f} views/s; target < 10 s on 2 cores)")

    # the per-pixel renderer + the separate dilation pass, on an evenly spread subset
    sub = np.linspace(0, len(poses) - 1, min(args.old_views, len(poses))).round().astype(int)
    render_packed(model.segments, model.faces, poses[sub[:16]], cam)
    raw_old, w_old, c_old = _timed(render_packed, model.segments, model.faces, poses[sub], cam)
    _, w_dil, c_dil = _timed(_dilate, raw_old, cam, tol)
    per_view = (w_old + w_dil) / len(sub)
    print(f"per-pixel renderer + dilation pass on {len(sub)} of the views: {w_old + w_dil:.2f} s wall "
          f"({c_old + c_dil:.2f} s CPU) -> extrapolated to all {len(poses):,} views: {per_view * len(poses):.0f} s; "
          f"speed-up {per_view * len(poses) / wall:.0f}x (extrapolated)")

    # agreement with the per-pixel renderer (undilated lines), a few hundred views
    few = sub[np.linspace(0, len(sub) - 1, min(300, len(sub))).round().astype(int)]
    old = unpack(render_packed(model.segments, model.faces, poses[few], cam), cam.height, cam.width).astype(bool)
    new = unpack(render_grid(model.segments, model.faces, poses[few], cam, near=0.05, hidden=True, tolerance_px=0),
                 cam.height, cam.width).astype(bool)
    both = np.count_nonzero(old & new)
    print(f"agreement on {len(few)} views, undilated: {both / max(np.count_nonzero(old), 1):.2%} of the per-pixel renderer's "
          f"line pixels drawn, {both / max(np.count_nonzero(new), 1):.2%} of the drawn ones in it; "
          f"dilated views equal to it: {np.mean(np.all(_dilate(pack(old), cam, tol) == db[few], axis=1)):.1%}")
    counts = popcount_rows(db)
    size = db.nbytes + cells.nbytes + counts.nbytes + poses.nbytes
    print(f"stored database: {size / 2**20:,.0f} MiB, the line images once (dilated, {db.nbytes / 2**20:,.0f} MiB) + their "
          f"8x8 cell images ({cells.nbytes / 2**20:,.0f} MiB) + counts + poses; before: undilated 'db' and dilated 'bits' "
          f"each {db.nbytes / 2**20:,.0f} MiB, {2 * db.nbytes / 2**20:,.0f} MiB in all")
    # queries: database views (evenly spread) with a third of their lines lost and 1 % clutter
    rng = np.random.default_rng(0)
    picks = np.linspace(0, len(db) - 1, args.queries).round().astype(int)
    thin = unpack(render_grid(model.segments, model.faces, poses[picks], cam, near=0.05, hidden=True, tolerance_px=0),
                  cam.height, cam.width)
    best_iou(db, counts, cells, pack(thin[0]), cam.height, cam.width)  # JIT warm-up
    t_pruned, t_full, same = [], [], 0
    for q in thin:
        qw = pack((q & (rng.random(q.shape) < 0.66)) | (rng.random(q.shape) < 0.01))
        t0 = time.perf_counter()
        row, score = best_iou(db, counts, cells, qw, cam.height, cam.width)
        t_pruned.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        full = iou_scores(db, counts, qw)
        t_full.append(time.perf_counter() - t0)
        same += int(row == int(np.argmax(full)) and score == float(full.max()))
    print(f"best view for one query among {len(db):,} views, {len(thin)} queries: {statistics.median(t_pruned) * 1e3:.1f} ms "
          f"median, {max(t_pruned) * 1e3:.1f} ms slowest (target < 20 ms); the same view and score as scoring every view "
          f"for {same}/{len(thin)}; scoring every view: {statistics.median(t_full) * 1e3:.1f} ms median -> "
          f"{statistics.median(t_full) / statistics.median(t_pruned):.1f}x")


def corridor(args: argparse.Namespace) -> None:
    model = floor_plan_model(building())
    cam = Camera(160, 120, 60.0)
    grid = pose_grid([0.0, 90.0, 0.1], [-1.5, 4.0, 0.2], 1.14, [45.0, 135.0, 225.0, 315.0])
    grid = grid[model.inside(grid[:, :2])]
    # the paper's count: an evenly spread subset of the inside poses of the paper's grid
    poses = grid[np.linspace(0, len(grid) - 1, min(args.views, len(grid))).round().astype(int)]
    print(f"cores: {os.cpu_count()}, numba threads: {numba.get_num_threads()}, model: {len(model.segments)} segments, "
          f"{len(model.faces)} faces; grid inside the plan: {len(grid)} views, benchmarked: {len(poses)}")
    render_packed(model.segments, model.faces, poses[:64], cam)  # JIT warm-up (cached after the first run)
    t0 = time.perf_counter()
    db = render_packed(model.segments, model.faces, poses, cam)
    t_render = time.perf_counter() - t0
    t0 = time.perf_counter()
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * args.tolerance + 1,) * 2)
    for s in range(0, len(db), 2048):
        db[s:s + 2048] = pack(np.stack([cv2.dilate(im, kernel) for im in unpack(db[s:s + 2048], cam.height, cam.width)]))
    counts = popcount_rows(db)
    t_index = time.perf_counter() - t0
    mem = db.nbytes + counts.nbytes + poses.nbytes
    print(f"render database: {t_render:.2f} s ({len(poses) / t_render:,.0f} views/s; target < 60 s)")
    print(f"pack + dilate {args.tolerance} px + counts: {t_index:.2f} s")
    print(f"database memory: {mem / 2**20:.1f} MiB ({db.shape[1]} words/view; target < 200 MB)")

    # a query: a database view with a third of its lines lost and clutter added
    rng = np.random.default_rng(0)
    q = unpack(db[len(db) // 3], cam.height, cam.width)
    q = (q & (rng.random(q.shape) < 0.66)) | (rng.random(q.shape) < 0.01)
    qw = pack(q)
    iou_scores(db, counts, qw)
    times = []
    for _ in range(30):
        t0 = time.perf_counter()
        fast = iou_scores(db, counts, qw)
        times.append(time.perf_counter() - t0)
    t_fast = statistics.median(times)
    imgs = unpack(db, cam.height, cam.width)
    t0 = time.perf_counter()
    naive = iou_naive(imgs, q)
    t_naive = time.perf_counter() - t0
    t0 = time.perf_counter()
    packed_loop = np.array([np.bitwise_count(db[i] & qw).sum() for i in range(len(db))])
    t_packed_loop = time.perf_counter() - t0
    assert np.allclose(fast, naive), "fast and naive scores differ"
    assert int(np.argmax(fast)) == int(np.argmax(naive))
    assert packed_loop.sum() >= 0
    print(f"score one query vs {len(db)} views: {t_fast * 1e3:.2f} ms (median of 30; target < 20 ms)")
    print(f"naive per-view NumPy AND/count loop (unpacked images): {t_naive * 1e3:.0f} ms -> speed-up {t_naive / t_fast:.0f}x (target >= 20x)")
    print(f"per-view loop on packed words (np.bitwise_count): {t_packed_loop * 1e3:.0f} ms -> speed-up {t_packed_loop / t_fast:.0f}x")


if __name__ == "__main__":
    main()
