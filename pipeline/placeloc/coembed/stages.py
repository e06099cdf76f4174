"""Co-embedding mapper on the staged pipeline, with Isomap and PCAMD baselines.

extract   observation matrix (CSV in long form, ArUco markers or SIFT tracks from images) and landmarks
localize  the map (and the path, for co-embedding with known poses) by ``coembed.solver``; map.csv, path.csv
evaluate  map error after the method's alignment, path error, fig. 4-style figure, metrics.json

``build-dictionary`` and ``index`` have no work here and pass through. The numerics live in
``solver`` (co-embedding), ``isomap``, ``wiberg`` (PCAMD), ``align``, ``landmarks``, ``metrics``
and ``plots``; this file only reads inputs, calls them and writes outputs.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from placeloc.coembed import resources as coembed_resources
from placeloc.coembed.observations import (
    ObservationError,
    from_triplets,
    poses_by_step,
    read_observations,
    read_observations_csv,
    read_points_csv,
    write_observations,
)
from placeloc.coembed.params import CoembedParams
from placeloc.core.config import ConfigError
from placeloc.core.methods import Method, Stage
from placeloc.evaluation.contracts import MapEvaluation

log = logging.getLogger("placeloc")


def _check(config: dict) -> None:
    p = config["coembed"]
    if p["source"] == "csv" and p["observations"] is None:
        raise ConfigError("coembed.observations is missing: give the long-form CSV (t,feature,value) or set coembed.source to an image source")
    if p["source"] != "csv" and p["images"] is None:
        raise ConfigError(f"coembed.images is missing: source {p['source']!r} reads a folder of frames")
    for key in METHOD.path_keys:
        if p[key] is not None and not Path(p[key]).exists():
            raise ConfigError(f"coembed.{key}: {p[key]} does not exist (relative paths start at the config's folder)")
    if p["landmarks"] is None:
        raise ConfigError("coembed.landmarks is missing: co-embedding and the baselines' alignment need known feature positions")
    if p["pose_label_every"] > 0 and p["poses"] is None:
        raise ConfigError("coembed.pose_label_every > 0 needs coembed.poses (CSV t,x,y[,heading])")
    if p["camera_model"] == "pinhole" and p["dim"] != 3:
        raise ConfigError("coembed.camera_model pinhole maps image points to a 3-D map: set coembed.dim: 3 (or camera_model linear)")
    if p["camera_model"] in ("perspective", "pinhole") and p["intrinsics"] is None:
        raise ConfigError(f"coembed.camera_model {p['camera_model']} needs coembed.intrinsics (CSV f,cx,cy[,k1,k2,k3,p1,p2]) "
                          "to turn pixels into directions; or set camera_model: linear")
    if p["landmark_count"] and p["landmark_count"] < p["dim"] + 1:
        raise ConfigError(f"coembed.landmark_count must be 0 or at least dim + 1 = {p['dim'] + 1}")


def extract(ctx) -> None:  # noqa: ANN001 - StageContext
    from placeloc.coembed.landmarks import farthest_point_landmarks, landmark_warnings_by_cause, take_landmarks

    p: CoembedParams = ctx.params
    if p.source == "csv":
        obs = read_observations_csv(p.observations)
    else:
        from placeloc.coembed.extract import observations_from_images
        from placeloc.core.images import list_images
        from placeloc.core.imagework import ImageStream

        images = list_images(p.images)
        paths = images.paths
        s, f, v = observations_from_images(
            len(paths), source=p.source, image_values=p.image_values, aruco_dictionary=p.aruco_dictionary,
            sift_features=p.sift_features, sift_ratio=p.sift_ratio, sift_min_track=p.sift_min_track,
            sift_id_offset=p.sift_id_offset,
            describe=lambda work: (frame.arrays for frame in ImageStream(ctx, images, work, desc=f"extract {work.fn.__name__}")))
        obs = from_triplets(s, f, v)
        ctx.out.create_dataset("frames", data=np.array([q.name for q in paths], dtype=object), dtype=h5py.string_dtype())
    if p.intrinsics is not None:
        from placeloc.coembed.camera import normalised_coordinates, read_intrinsics

        obs.values = normalised_coordinates(obs.values, read_intrinsics(p.intrinsics))
    ids, coords = read_points_csv(p.landmarks, "landmarks")
    if p.landmark_ids:
        ids, coords = take_landmarks(ids, coords, p.landmark_ids, p.landmarks)
    d = p.dim
    if coords.shape[1] < d:
        raise ObservationError(f"landmarks file {p.landmarks} has {coords.shape[1]} coordinates per row; coembed.dim is {d}")
    if p.landmark_count:
        seen = np.isin(ids, obs.feature_ids)
        counts = np.bincount(obs.indices, minlength=obs.n_features)[obs.columns_of(ids[seen], "landmark")]
        chosen = farthest_point_landmarks(ids[seen], coords[seen, :d], counts, p.landmark_count)
        ids, coords = take_landmarks(ids, coords, chosen, p.landmarks)
    obs.columns_of(ids, "landmark")  # clear error for a landmark id that is unknown or never observed
    if len(ids) < d + 1:
        raise ObservationError(f"a {d}-D map needs at least {d + 1} landmarks; got {len(ids)}")
    by_cause = landmark_warnings_by_cause(coords[:, :d], d)
    for cause, w in by_cause.items():
        # The cause lets an experiment that runs many landmark sets show each kind of warning once.
        log.warning("coembed landmarks: %s", w, extra={"coembed_warning_cause": cause})
    warnings = list(by_cause.values())
    write_observations(ctx.out.require_group("observations"), obs)
    ctx.out["observations"].attrs["units"] = "normalised image coordinates" if p.intrinsics else "as given"
    g = ctx.out.require_group("landmarks")
    g.create_dataset("ids", data=ids)
    g.create_dataset("coords", data=coords[:, :d])
    g.attrs["warnings"] = json.dumps(warnings)


def localize(ctx) -> None:  # noqa: ANN001
    from placeloc.coembed.align import align_to_landmarks
    from placeloc.coembed.export import write_map_csv, write_path_csv

    p: CoembedParams = ctx.params
    art = ctx.artifact("extract")
    obs = read_observations(art["observations"])
    lid, lxyz = art["landmarks/ids"][()], art["landmarks/coords"][()]
    lcols = obs.columns_of(lid, "landmark")
    t0 = time.perf_counter()
    info: dict = {"solver": p.solver}
    out = ctx.out.require_group("map")
    if p.solver == "coembed":
        from placeloc.coembed.solver import coembed_map, estimate_poses
        from placeloc.coembed.tuning import loo_alpha

        def alpha_for(o):  # noqa: ANN001, ANN202
            if p.alpha_select == "fixed":
                return p.alpha
            choice = loo_alpha(o, lcols, lxyz, candidates=p.alpha_grid)
            info["alpha_loo_rmse"] = json.dumps(choice.scores)
            return choice.value

        if p.camera_model == "perspective":
            from placeloc.coembed.perspective import perspective_coembed

            directions = np.hstack([obs.values, np.ones((obs.nnz, 1))])
            res, depth, alphas = perspective_coembed(obs, directions, lcols, lxyz, alpha_for=alpha_for,
                                                     iterations=p.perspective_iterations)
            ctx.out.create_dataset("depth", data=depth)
            info["alpha"] = alphas[-1]
            info["alpha_per_round"] = alphas
        else:
            info["alpha"] = alpha_for(obs)
            res = coembed_map(obs, lcols, lxyz, alpha=info["alpha"])
        coords = res.X
        if p.camera_model == "pinhole":
            from placeloc.coembed.pinhole import calibrated_map

            # The linear map (above) is the fallback for points whose rays are nearly parallel; the path
            # read-out below keeps using its transforms.
            cam = calibrated_map(obs, obs.values, lcols, lxyz, res.X, prior=p.pinhole_prior, max_iter=p.pinhole_max_iter,
                                 tol=p.pinhole_tol)
            coords = cam.X
            g = ctx.out.require_group("cameras")
            g.create_dataset("rotation", data=np.transpose(cam.Q, (0, 2, 1)))   # world-to-camera R_t, x_cam = R_t (x - C_t)
            g.create_dataset("centre", data=cam.C)
            g.create_dataset("depth", data=cam.depth)
            info["pinhole_iterations"] = cam.iterations
            info["pinhole_cost"] = cam.costs[-1]
        ctx.out.create_dataset("transforms", data=res.T)
        if p.pose_label_every:
            steps, xy, heading = poses_by_step(p.poses)
            keep = (steps % p.pose_label_every == 0) & np.isin(steps, obs.step_ids)
            rows = np.searchsorted(obs.step_ids, steps[keep])
            pxy, phead = estimate_poses(res.T, rows, xy[keep], None if heading is None else heading[keep], beta=p.beta)
            g = ctx.out.require_group("path")
            g.create_dataset("step_ids", data=obs.step_ids)
            g.create_dataset("xy", data=pxy)
            g.create_dataset("label_steps", data=obs.step_ids[rows])
            if phead is not None:
                g.create_dataset("heading", data=phead)
            write_path_csv(ctx.output("path.csv"), obs.step_ids, pxy, phead, obs.step_ids[rows])
    elif p.solver == "isomap":
        from placeloc.coembed.isomap import isomap_features

        k = p.isomap_neighbors
        if p.isomap_neighbors_select == "loo":
            from placeloc.coembed.tuning import loo_isomap_neighbors

            choice = loo_isomap_neighbors(obs, lcols, lxyz, dim=p.dim, min_common=p.isomap_min_common,
                                          candidates=p.isomap_neighbors_grid)
            k = int(choice.value)
            info["isomap_neighbors_loo_rmse"] = json.dumps(choice.scores)
        info["isomap_neighbors"] = k
        emb = isomap_features(obs, n_neighbors=k, dim=p.dim, min_common=p.isomap_min_common)
        out.create_dataset("embedding", data=emb)
        coords = align_to_landmarks(emb, lcols, lxyz)
    else:
        from placeloc.coembed.wiberg import factorise_observations

        res = factorise_observations(obs, rank=p.pcamd_rank, max_iter=p.pcamd_max_iter, tol=p.pcamd_tol, seed=ctx.config["seed"])
        out.create_dataset("embedding", data=res.U)
        coords = align_to_landmarks(res.U, lcols, lxyz)
        info.update(pcamd_cost=res.cost, pcamd_iterations=res.iterations, pcamd_converged=res.converged)
    info["solve_seconds"] = time.perf_counter() - t0
    out.create_dataset("feature_ids", data=obs.feature_ids)
    out.create_dataset("coords", data=coords)
    out.create_dataset("is_landmark", data=np.isin(obs.feature_ids, lid))
    for k, v in info.items():
        out.attrs[k] = v
    from placeloc.evaluation import maps

    path = ctx.out.get("path")
    maps.write(ctx, feature_ids=obs.feature_ids, coords=coords, is_landmark=np.isin(obs.feature_ids, lid),
               path=None if path is None else {"step_ids": path["step_ids"][()], "xy": path["xy"][()],
                                               "heading": path["heading"][()] if "heading" in path else None,
                                               "label_steps": path["label_steps"][()]})
    write_map_csv(ctx.output("map.csv"), obs.feature_ids, coords, np.isin(obs.feature_ids, lid))


def evaluate_extra(ctx: Any, ev: MapEvaluation) -> None:
    """Co-embedding's own figures beside the map contract's: the solver's settings and cost,
    the landmark warnings, and the path read out from the map against the true poses."""
    from placeloc.coembed.metrics import path_errors

    p: CoembedParams = ctx.params
    loc = ctx.artifact("localize")
    art = ctx.artifact("extract")
    m = ev.metrics
    m.update({"method": "coembed", "solver": p.solver, "n_steps": int(art["observations/step_ids"].shape[0]),
              "fill": float(art["observations"].attrs["fill"]), "path_rmse": None,
              "solve_seconds": float(loc["map"].attrs["solve_seconds"])})
    for k in ("pcamd_iterations", "pcamd_converged", "alpha", "isomap_neighbors", "pinhole_iterations"):
        if k in loc["map"].attrs:
            v = loc["map"].attrs[k]
            m[k] = v.item() if hasattr(v, "item") else v
    m["landmark_warnings"] = json.loads(art["landmarks"].attrs.get("warnings", "[]"))
    ev.landmarks = art["landmarks/coords"][()]
    if "path" in loc and p.poses is not None:
        steps, xy, heading = poses_by_step(p.poses)
        path_est = loc["path/xy"][()]
        found, path_truth = path_errors(loc["path/step_ids"][()], path_est, loc["path/heading"][()] if "path/heading" in loc else None,
                                        loc["path/label_steps"][()], steps, xy, heading)
        m.update(found)
        if path_truth is not None:
            ev.path_est, ev.path_truth = path_est, path_truth
            # kept in evaluate.h5 so that `placeloc show` draws the true path too
            ev.arrays.update(path_est_xy=path_est, path_truth_xy=path_truth)
            m["headline"] = [k for k in m["headline"] if k != "seconds_per_frame"] + ["path_rmse", "seconds_per_frame"]
    name = {"coembed": "co-embedding", "isomap": "Isomap", "pcamd": "PCAMD (Wiberg)"}[p.solver]
    if p.solver == "coembed" and p.camera_model != "linear":
        name += f" ({p.camera_model} camera)"
    ev.label = name


EXTRACT_KEYS = ("source", "observations", "images", "image_values", "aruco_dictionary", "sift_features", "sift_ratio",
                "sift_min_track", "sift_id_offset", "landmarks", "landmark_ids", "landmark_count", "intrinsics", "dim")
METHOD = Method(
    resources=coembed_resources,
    name="coembed",
    params=CoembedParams,
    stages={
        "extract": Stage(extract, keys=EXTRACT_KEYS),
        # The parent stamp carries extract's keys; localize adds only what its solvers read.
        "localize": Stage(localize, keys=("solver", "alpha", "alpha_select", "alpha_grid", "camera_model", "perspective_iterations",
                                          "pinhole_prior", "pinhole_max_iter", "pinhole_tol",
                                          "beta", "poses", "pose_label_every", "isomap_neighbors", "isomap_neighbors_select",
                                          "isomap_neighbors_grid", "isomap_min_common", "pcamd_rank", "pcamd_max_iter", "pcamd_tol")),
    },
    result="map",
    evaluate_extra=evaluate_extra,
    evaluate_keys=("solver", "camera_model", "truth", "poses"),
    truth_keys={"points": "truth", "poses": "poses"},
    required_images=(),
    checker=_check,
    citation="S. Nakamura and T. Yairi, \"Experimental Study on Mapping by Dimensionality Reduction\" (co-embedding; "
             "baselines Isomap (Tenenbaum, de Silva and Langford, \"A Global Geometric Framework for Nonlinear "
             "Dimensionality Reduction\", Science 2000) and the Wiberg algorithm of Okatani and Deguchi, \"On the Wiberg "
             "Algorithm for Matrix Factorization in the Presence of Missing Components\", IJCV 2007)",
)
