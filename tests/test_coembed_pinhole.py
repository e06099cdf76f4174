"""Co-embedding with a calibrated pinhole camera, the synthetic camera track, and the experiment's warning filter."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from placeloc.coembed.camera import normalised_coordinates, read_intrinsics
from placeloc.coembed.landmarks import farthest_point_landmarks
from placeloc.coembed.observations import read_observations_csv, read_points_csv
from placeloc.coembed.pinhole import calibrated_map
from placeloc.coembed.solver import coembed_map
from placeloc.core.config import ConfigError, load_config
from placeloc.core.runner import run_all
from placeloc.experiments.coembed import _OncePerCause
from placeloc.synth import generate


def _track(path, **kw):
    generate("coembed", path, seed=4, world="camera", frames=120, n_near=16, n_far=4, min_track=20, **kw)
    obs = read_observations_csv(path / "markers.csv")
    obs.values = normalised_coordinates(obs.values, read_intrinsics(path / "intrinsics.csv"))
    ids, xyz = read_points_csv(path / "points.csv", "points")
    truth = xyz[np.searchsorted(ids, obs.feature_ids)]
    return obs, truth


def test_camera_track_projects_the_truth_through_the_distorted_lens(tmp_path):
    """Noise-free: undistorting the markers gives exactly the pinhole projection of the true points by the true cameras."""
    obs, truth = _track(tmp_path, noise_px=0.0)
    cams = np.loadtxt(tmp_path / "cameras.csv", delimiter=",", skiprows=1)
    k = read_intrinsics(tmp_path / "intrinsics.csv")
    assert k.dist[0] == pytest.approx(-0.12) and k.dist[1] == pytest.approx(0.03)     # the lens is distorted
    rot = cams[obs.step_ids - 1, 1:10].reshape(-1, 3, 3)[obs.rows]
    xc = np.einsum("nab,nb->na", rot, truth[obs.indices]) + cams[obs.step_ids - 1, 10:][obs.rows]
    assert np.abs(xc[:, :2] / xc[:, 2:] - obs.values).max() < 1e-6
    raw = np.loadtxt(tmp_path / "markers.csv", delimiter=",", skiprows=1)[:, 2:]
    assert np.abs((raw - [k.cx, k.cy]) / k.f - obs.values).max() > 1e-3           # ... so pixels alone would be off


def test_calibrated_map_is_exact_without_noise_and_beats_the_linear_form_with_it(tmp_path):
    # Noise-free: the answer up to the prior's pull toward the linear map (1e-9: 1e-5 m; the default 1e-6: millimetres).
    # Without any prior the start put one point behind a camera and Levenberg-Marquardt could not recover.
    for noise, bound, prior in ((0.0, 1e-4, 1e-9), (0.0, 0.01, 1e-6), (0.7, None, 1e-6)):
        obs, truth = _track(tmp_path / f"n{noise}-{prior}", noise_px=noise)
        counts = np.bincount(obs.indices, minlength=obs.n_features)
        lm = farthest_point_landmarks(obs.feature_ids, truth, counts, 8)
        cols = obs.columns_of(lm, "landmark")
        rest = ~np.isin(obs.feature_ids, lm)
        linear = coembed_map(obs, cols, truth[cols], alpha=1000.0).X
        res = calibrated_map(obs, obs.values, cols, truth[cols], linear, prior=prior, max_iter=100, tol=1e-12)
        err = np.sqrt(np.mean(np.sum((res.X - truth)[rest] ** 2, axis=1)))
        if bound is not None:
            assert err < bound
            assert np.all(res.depth > 0)
        else:
            lin_err = np.sqrt(np.mean(np.sum((linear - truth)[rest] ** 2, axis=1)))
            assert err < 0.5 and err < 0.1 * lin_err
        assert np.abs(res.X[cols] - truth[cols]).max() == 0.0                     # landmarks are held


def test_pinhole_config_checks(tmp_path):
    generate("coembed", tmp_path, seed=4, world="camera", frames=60, n_near=10, n_far=2, min_track=20)
    cfg = json.loads(json.dumps(load_config(tmp_path / "camera.yaml").get("coembed")))
    with pytest.raises(ConfigError, match="dim: 3"):
        load_config(data={"method": "coembed", "coembed": {**cfg, "dim": 2}})
    with pytest.raises(ConfigError, match="intrinsics"):
        load_config(data={"method": "coembed", "coembed": {**cfg, "intrinsics": None}})
    with pytest.raises(ValueError, match="world"):
        generate("coembed", tmp_path / "x", world="moon")


def test_landmark_warnings_are_shown_once_per_cause():
    once = _OncePerCause()
    log = logging.getLogger("placeloc.test-once")
    log.addFilter(once)
    seen = []
    handler = logging.Handler()
    handler.emit = lambda record: seen.append(record.getMessage())     # type: ignore[method-assign]
    log.addHandler(handler)
    try:
        for cause in ("clustered", "too-few", "clustered", "clustered"):
            log.warning("landmarks %s", cause, extra={"coembed_warning_cause": cause})
        log.warning("something else")
    finally:
        log.removeHandler(handler)
        log.removeFilter(once)
    assert once.counts == {"clustered": 3, "too-few": 1}
    assert len(seen) == 3 and seen[-1] == "something else" and "shown once" in seen[0]


@pytest.mark.shared_data
def test_pinhole_on_tears_of_steel_fixed_rule(tmp_path, tears_of_steel):
    d = tears_of_steel
    section = {"observations": str(d / "markers.csv"), "landmarks": str(d / "points.csv"), "truth": str(d / "points.csv"),
               "intrinsics": str(d / "intrinsics.csv"), "dim": 3, "landmark_count": 10, "camera_model": "pinhole"}
    run_all(load_config(data={"method": "coembed", "plots": False, "coembed": section}), tmp_path, quiet=True)
    m = json.loads((tmp_path / "metrics.json").read_text())
    # The reference points are libmv's own solve of these tracks with this camera model: agreement to millimetres,
    # against 1.13 for the evaluated points' own centroid and 6.55 for PCAMD (docs/coembed.md).
    assert m["n_evaluated"] == 16 and m["map_rmse"] < 0.01


def test_calibrated_map_does_not_depend_on_the_map_units(tmp_path):
    obs, truth = _track(tmp_path)
    counts = np.bincount(obs.indices, minlength=obs.n_features)
    cols = obs.columns_of(farthest_point_landmarks(obs.feature_ids, truth, counts, 8), "landmark")
    linear = coembed_map(obs, cols, truth[cols], alpha=1000.0).X
    ref = calibrated_map(obs, obs.values, cols, truth[cols], linear, prior=1e-6, max_iter=100, tol=1e-12).X
    for scale, shift in ((1e-4, 0.0), (1e3, 5e3)):
        got = calibrated_map(obs, obs.values, cols, truth[cols] * scale + shift, linear * scale + shift, prior=1e-6,
                             max_iter=100, tol=1e-12).X
        assert np.abs((got - shift) / scale - ref).max() < 1e-6 * np.ptp(truth)
