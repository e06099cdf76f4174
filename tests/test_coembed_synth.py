"""The ABCD world generator: layout, field of view, range, noise and determinism."""

from __future__ import annotations

import numpy as np
import pytest

from placeloc.coembed.observations import poses_by_step, read_observations_csv, read_points_csv
from placeloc.synth import generate


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    out = tmp_path_factory.mktemp("abcd")
    summary = generate("coembed", out, seed=0, steps=800, bearing_noise=0.0, range_noise=0.0)
    return out, summary


def test_layout_matches_the_paper(world):
    out, summary = world
    ids, feat = read_points_csv(out / "features.csv", "truth")
    xy, letter, landmark = feat[:, :2], feat[:, 2].astype(bool), feat[:, 3].astype(bool)
    assert len(ids) == 200 and letter.sum() == 100 and landmark.sum() == 11
    assert not (letter & landmark).any()
    assert (xy >= 0).all() and (xy <= 20).all()
    lid, lxy = read_points_csv(out / "landmarks.csv")
    assert np.array_equal(lid, ids[landmark]) and np.allclose(lxy, xy[landmark])
    # Landmarks are spread out (farthest-point sampling): no two closer than 3 m.
    dd = np.linalg.norm(lxy[:, None] - lxy[None], axis=2) + np.eye(11) * 99
    assert dd.min() > 3.0
    assert summary["unobserved_features"] == 0


def test_sensors_see_exactly_the_features_in_range_and_field_of_view(world):
    out, _ = world
    _, feat = read_points_csv(out / "features.csv", "truth")
    steps, pxy, heading = poses_by_step(out / "poses.csv")
    xy = feat[:, :2]
    dx = xy[None, :, 0] - pxy[:, None, 0]
    dy = xy[None, :, 1] - pxy[:, None, 1]
    dist = np.hypot(dx, dy)
    bear = (np.arctan2(dy, dx) - heading[:, None] + np.pi) % (2 * np.pi) - np.pi
    visible = (dist <= 8.0) & (np.abs(bear) <= np.pi / 2)
    rng_obs = read_observations_csv(out / "obs_range.csv")
    brg_obs = read_observations_csv(out / "obs_bearing.csv")
    seen = np.zeros_like(visible)
    seen[rng_obs.step_ids[rng_obs.rows], rng_obs.feature_ids[rng_obs.indices]] = True
    assert np.array_equal(seen, visible)
    assert rng_obs.values.max() <= 8.0
    assert np.abs(brg_obs.values).max() <= np.pi / 2
    t, i = rng_obs.step_ids[rng_obs.rows], rng_obs.feature_ids[rng_obs.indices]
    assert np.allclose(rng_obs.values[:, 0], dist[t, i], atol=1e-6)   # noise 0: exact
    assert np.allclose(brg_obs.values[:, 0], bear[t, i], atol=1e-5)  # poses are written to 1e-6
    # The robot stays in the square and moves by straight runs or turns on the spot, never both.
    assert (pxy >= 0).all() and (pxy <= 20).all()
    moved = np.linalg.norm(np.diff(pxy, axis=0), axis=1) > 1e-9
    turned = np.abs(np.diff(np.unwrap(heading))) > 1e-9
    assert not (moved & turned).any() and moved.any() and turned.any()


def test_noise_levels_and_seeds(tmp_path):
    a = generate("coembed", tmp_path / "a", seed=1, steps=300, bearing_noise=0.05, range_noise=0.2)
    generate("coembed", tmp_path / "b", seed=1, steps=300, bearing_noise=0.0, range_noise=0.0)
    ra, rb = read_observations_csv(tmp_path / "a" / "obs_range.csv"), read_observations_csv(tmp_path / "b" / "obs_range.csv")
    assert np.array_equal(ra.indices, rb.indices)   # same world and path for the same seed
    assert np.std(ra.values - rb.values) == pytest.approx(0.2, rel=0.1)
    ba, bb = read_observations_csv(tmp_path / "a" / "obs_bearing.csv"), read_observations_csv(tmp_path / "b" / "obs_bearing.csv")
    assert np.std(ba.values - bb.values) == pytest.approx(0.05, rel=0.1)
    c = generate("coembed", tmp_path / "c", seed=2, steps=300)
    assert c["observations"] != a["observations"]
    with pytest.raises(TypeError, match="unknown parameter"):
        generate("coembed", tmp_path / "d", nonsense=1)
