"""Co-embedding mapper (seed 002) on the staged pipeline, with Isomap and PCAMD baselines.

extract   observation matrix (CSV in long form, ArUco markers or SIFT tracks from images) and landmarks
localize  the map (and the path, for co-embedding with known poses) by ``coembed.solver``
evaluate  map error after the method's alignment, path error, fig. 4-style figure, metrics.json

``build-dictionary`` and ``index`` have no work here and pass through.
"""

from __future__ import annotations

import time
from pathlib import Path

import h5py
import numpy as np
from placeloc.coembed.observations import (
    ObservationError,
    from_triplets,
    read_observations,
    read_observations_csv,
    read_points_csv,
    read_poses_csv,
    write_observations,
)
from placeloc.coembed.params import CoembedParams
from placeloc.config import ConfigError
from placeloc.methods import Method, Stage


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
    if p["pose_label_every"] < 0:
        raise ConfigError("coembed.pose_label_every must be >= 0")
    if p["pose_label_every"] > 0 and p["poses"] is None:
        raise ConfigError("coembed.pose_label_every > 0 needs coembed.poses (CSV t,x,y[,heading])")
    if p["alpha"] <= 0 or p["beta"] < 0:
        raise ConfigError("coembed.alpha must be > 0 and coembed.beta >= 0")
    if p["isomap_neighbors"] < 1 or p["pcamd_rank"] < 1:
        raise ConfigError("coembed.isomap_neighbors and coembed.pcamd_rank must be >= 1")


def extract(ctx) -> None:  # noqa: ANN001 - StageContext
    p = ctx.params
    if p["source"] == "csv":
        obs = read_observations_csv(p["observations"])
    else:
        from placeloc.coembed.extract import observations_from_images
        from placeloc.images import list_images

        paths = list_images(p["images"]).paths
        s, f, v = observations_from_images(paths, p, lambda fn, items: ctx.progress(ctx.executor.map(fn, items), total=len(items)))
        obs = from_triplets(s, f, v)
        ctx.out.create_dataset("frames", data=np.array([q.name for q in paths], dtype=object), dtype=h5py.string_dtype())
    ids, coords = read_points_csv(p["landmarks"], "landmarks")
    if p["landmark_ids"]:
        want = np.asarray(p["landmark_ids"], dtype=np.int64)
        missing = want[~np.isin(want, ids)]
        if missing.size:
            raise ObservationError(f"coembed.landmark_ids {missing.tolist()} are not in {p['landmarks']}")
        sel = np.searchsorted(ids, want) if np.all(np.diff(ids) > 0) else np.array([np.flatnonzero(ids == w)[0] for w in want])
        ids, coords = ids[sel], coords[sel]
    d = p["dim"]
    if coords.shape[1] < d:
        raise ObservationError(f"landmarks file {p['landmarks']} has {coords.shape[1]} coordinates per row; coembed.dim is {d}")
    obs.columns_of(ids, "landmark")  # clear error for a landmark id that is unknown or never observed
    if len(ids) < d + 1:
        raise ObservationError(f"a {d}-D map needs at least {d + 1} landmarks; got {len(ids)}")
    write_observations(ctx.out.require_group("observations"), obs)
    g = ctx.out.require_group("landmarks")
    g.create_dataset("ids", data=ids)
    g.create_dataset("coords", data=coords[:, :d])


def _pose_labels(p: dict, obs) -> dict | None:  # noqa: ANN001
    if not p["pose_label_every"]:
        return None
    steps, xy, heading = read_poses_csv(p["poses"])
    keep = (steps % p["pose_label_every"] == 0) & np.isin(steps, obs.step_ids)
    rows = np.searchsorted(obs.step_ids, steps[keep])
    return {"rows": rows, "xy": xy[keep], "heading": None if heading is None else heading[keep]}


def localize(ctx) -> None:  # noqa: ANN001
    from placeloc.coembed.align import align_to_landmarks

    p = ctx.params
    art = ctx.artifact("extract")
    obs = read_observations(art["observations"])
    lid, lxyz = art["landmarks/ids"][()], art["landmarks/coords"][()]
    lcols = obs.columns_of(lid, "landmark")
    t0 = time.perf_counter()
    info: dict = {"solver": p["solver"]}
    out = ctx.out.require_group("map")
    if p["solver"] == "coembed":
        from placeloc.coembed.solver import coembed_map, estimate_poses

        res = coembed_map(obs, lcols, lxyz, p["alpha"])
        coords = res.X
        ctx.out.create_dataset("transforms", data=res.T)
        labels = _pose_labels(p, obs)
        if labels is not None:
            xy, heading = estimate_poses(res.T, labels["rows"], labels["xy"], labels["heading"], p["beta"])
            g = ctx.out.require_group("path")
            g.create_dataset("step_ids", data=obs.step_ids)
            g.create_dataset("xy", data=xy)
            g.create_dataset("label_steps", data=obs.step_ids[labels["rows"]])
            if heading is not None:
                g.create_dataset("heading", data=heading)
    elif p["solver"] == "isomap":
        from placeloc.coembed.isomap import isomap_features

        emb = isomap_features(obs, p["isomap_neighbors"], p["dim"], p["isomap_min_common"])
        out.create_dataset("embedding", data=emb)
        coords = align_to_landmarks(emb, lcols, lxyz)
    else:
        from placeloc.coembed.wiberg import wiberg

        k = obs.value_dim
        # Features are rows; each (step, value component) is a column of the factorised matrix.
        cols = (obs.rows[:, None] * k + np.arange(k)).ravel()
        res = wiberg(np.repeat(obs.indices, k), cols, obs.values.ravel(), (obs.n_features, obs.n_steps * k),
                     p["pcamd_rank"], max_iter=p["pcamd_max_iter"], tol=p["pcamd_tol"], seed=ctx.config["seed"])
        out.create_dataset("embedding", data=res.U)
        coords = align_to_landmarks(res.U, lcols, lxyz)
        info.update(pcamd_cost=res.cost, pcamd_iterations=res.iterations, pcamd_converged=res.converged)
    info["solve_seconds"] = time.perf_counter() - t0
    out.create_dataset("feature_ids", data=obs.feature_ids)
    out.create_dataset("coords", data=coords)
    out.create_dataset("is_landmark", data=np.isin(obs.feature_ids, lid))
    for k, v in info.items():
        out.attrs[k] = v


def _figure(path, est, truth, lm_xyz, path_est, path_truth, title) -> None:  # noqa: ANN001
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ax0, ax1 = 0, truth.shape[1] - 1   # a 3-D map is drawn from above (x, last axis)
    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    if path_truth is not None:
        ax.plot(path_truth[:, 0], path_truth[:, 1], color="0.75", lw=0.8, label="true path")
    if path_est is not None:
        ax.plot(path_est[:, 0], path_est[:, 1], color="tab:orange", lw=0.8, alpha=0.8, label="estimated path")
    segs = np.stack([est[:, [ax0, ax1]], truth[:, [ax0, ax1]]], axis=1)
    from matplotlib.collections import LineCollection

    ax.add_collection(LineCollection(segs, colors="tab:green", lw=0.8, label="error"))
    ax.scatter(truth[:, ax0], truth[:, ax1], s=14, facecolors="none", edgecolors="0.4", lw=0.7, label="truth")
    ax.scatter(est[:, ax0], est[:, ax1], s=10, color="tab:blue", label="estimate")
    ax.scatter(lm_xyz[:, ax0], lm_xyz[:, ax1], s=40, marker="s", color="tab:red", label="landmarks")
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def evaluate(ctx) -> None:  # noqa: ANN001
    from placeloc.evaluation import write_metrics

    p = ctx.params
    loc = ctx.artifact("localize")
    art = ctx.artifact("extract")
    ids = loc["map/feature_ids"][()]
    coords = loc["map/coords"][()]
    is_lm = loc["map/is_landmark"][()]
    lxyz = art["landmarks/coords"][()]
    d = coords.shape[1]
    metrics: dict = {"method": "coembed", "solver": p["solver"], "n_features": int(len(ids)), "n_landmarks": int(is_lm.sum()),
                     "n_steps": int(art["observations/step_ids"].shape[0]), "fill": float(art["observations"].attrs["fill"]),
                     "map_rmse": None, "map_max_error": None, "path_rmse": None,
                     "solve_seconds": float(loc["map"].attrs["solve_seconds"])}
    for k in ("pcamd_iterations", "pcamd_converged"):
        if k in loc["map"].attrs:
            metrics[k] = loc["map"].attrs[k]
    est_eval = truth_eval = None
    if p["truth"] is not None:
        tid, txyz = read_points_csv(p["truth"], "truth")
        if txyz.shape[1] < d:
            raise ObservationError(f"truth file {p['truth']} has {txyz.shape[1]} coordinates per row; the map is {d}-D")
        have = np.isin(ids, tid) & ~is_lm
        order = {int(f): j for j, f in enumerate(tid)}
        rows = np.array([order[int(f)] for f in ids[have]], dtype=np.int64)
        est_eval, truth_eval = coords[have], txyz[rows, :d]
        err = np.linalg.norm(est_eval - truth_eval, axis=1)
        metrics.update(map_rmse=float(np.sqrt(np.mean(err ** 2))) if len(err) else None,
                       map_max_error=float(err.max()) if len(err) else None,
                       map_median_error=float(np.median(err)) if len(err) else None, n_evaluated=int(len(err)),
                       # Features with a true position that were never observed cannot be mapped: counted, not hidden.
                       n_truth_unobserved=int((~np.isin(tid, ids)).sum()))
        lm_rows = np.array([order[int(f)] for f in ids[is_lm] if int(f) in order], dtype=np.int64)
        if len(lm_rows) == int(is_lm.sum()):
            metrics["landmark_rmse"] = float(np.sqrt(np.mean(np.sum((coords[is_lm] - txyz[lm_rows, :d]) ** 2, axis=1))))
    path_est = path_truth = None
    if "path" in loc and p["poses"] is not None:
        steps, xy, heading = read_poses_csv(p["poses"])
        pst = loc["path/step_ids"][()]
        pxy = loc["path/xy"][()]
        labelled = np.isin(pst, loc["path/label_steps"][()])
        common = np.isin(pst, steps) & ~labelled
        idx = np.searchsorted(steps, pst[common])   # read_poses_csv returns steps sorted and unique
        if common.any():
            perr = np.linalg.norm(pxy[common] - xy[idx], axis=1)
            metrics.update(path_rmse=float(np.sqrt(np.mean(perr ** 2))), path_max_error=float(perr.max()),
                           n_path_evaluated=int(common.sum()), n_pose_labels=int(labelled.sum()))
            if heading is not None and "path/heading" in loc:
                dh = (loc["path/heading"][()][common] - heading[idx] + np.pi) % (2 * np.pi) - np.pi
                metrics["heading_rmse_deg"] = float(np.degrees(np.sqrt(np.mean(dh ** 2))))
            path_est, path_truth = pxy, xy[np.searchsorted(steps, pst[np.isin(pst, steps)])]
    write_metrics(ctx.run_dir, metrics, ctx.out)
    if ctx.config.get("plots", True) and est_eval is not None:
        title = f"{p['solver']}: map RMSE {metrics['map_rmse']:.3g}, max {metrics['map_max_error']:.3g} ({metrics['n_evaluated']} features)"
        _figure(ctx.run_dir / "map.png", est_eval, truth_eval, lxyz, path_est, path_truth, title)


EXTRACT_KEYS = ("source", "observations", "images", "image_values", "aruco_dictionary", "sift_features", "sift_ratio",
                "sift_min_track", "sift_id_offset", "landmarks", "landmark_ids", "dim")
METHOD = Method(
    name="coembed",
    params=CoembedParams,
    stages={
        "extract": Stage(extract, keys=EXTRACT_KEYS),
        "localize": Stage(localize, keys=EXTRACT_KEYS + ("solver", "alpha", "beta", "poses", "pose_label_every",
                                                         "isomap_neighbors", "isomap_min_common", "pcamd_rank",
                                                         "pcamd_max_iter", "pcamd_tol")),
        "evaluate": Stage(evaluate, keys=tuple(CoembedParams.__dataclass_fields__), sections=("ground_truth", "plots")),
    },
    required_images=(),
    checker=_check,
    citation="S. Nakamura and T. Yairi, \"Experimental Study on Mapping by Dimensionality Reduction\" (co-embedding; "
             "baselines Isomap and the Okatani-Deguchi Wiberg algorithm)",
)
