"""The stitching-seam ghosting of ``synth omni`` (hand-computed blends at known columns; the
bands at azimuth heading +-90 deg; a generated video equals the plain one ghosted) and the
dictionary experiment's seam marks (per-PIRF counts on planted duplicates; PIRFs found
again equal to the extract stage's tracker)."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from placeloc.evaluation.poses import read_poses
from placeloc.experiments.pirf_dictionary import dictionary_counts, in_seam_bands, seam_marks
from placeloc.pirf.chain import PirfTracker
from placeloc.pirf.features import extract_frame
from placeloc.synth.omni import generate, ghost_seams, seam_weight


def test_ghost_blend_at_hand_computed_columns() -> None:
    """64 px frame, 90 deg bands = 16 px around x = 16 (columns 8-23) and x = 48 (40-55); the
    ghost weight w = sin^2(pi s) / 2 with s = (c + 0.5 - 8) / 16 in the left band. A line at
    column 18 (200) shifted 4 px shows at column 14 with w(14) = 0.4579: 91.57 -> 92, and
    keeps (1 - w(18)) = 0.6111 of itself: 122.2 -> 122; in the right band column 50 (100)
    gives 45.8 -> 46 at column 46 and keeps 61.1 -> 61. Column 30 lies between the bands:
    untouched, and no ghost of it appears."""
    img = np.zeros((4, 64), np.uint8)
    img[:, 18], img[:, 50], img[:, 30] = 200, 100, 250
    out = ghost_seams(img, 4, 90.0)
    want = np.zeros((4, 64), np.uint8)
    want[:, 14], want[:, 18], want[:, 46], want[:, 50], want[:, 30] = 92, 122, 46, 61, 250
    assert np.array_equal(out, want)
    w = seam_weight(64, 90.0)
    assert np.flatnonzero(w).tolist() == list(range(8, 24)) + list(range(40, 56))
    assert w[15] == pytest.approx(0.5 * math.sin(math.pi * 7.5 / 16) ** 2)


def test_ghost_exposure_and_fractional_shift() -> None:
    flat = np.full((2, 64), 100, np.uint8)
    out = ghost_seams(flat, 0, 90.0, gain=1.2)  # the second lens 20 % brighter: 100 (1 + 0.2 w)
    assert out[0, 15] == 110 and out[0, 8] == 100  # w(15) = 0.495: 109.9; w(8) = 0.005: 100.1
    assert np.array_equal(out[:, 24:40], flat[:, 24:40])
    line = np.zeros((2, 64), np.uint8)
    line[:, 18] = 200
    half = ghost_seams(line, 0.5, 90.0)  # the copy at column c: (img[c] + img[c + 1]) / 2
    w = seam_weight(64, 90.0)
    assert half[0, 17] == round(w[17] * 100)
    assert half[0, 18] == round((1 - w[18]) * 200 + w[18] * 100)
    assert np.count_nonzero(half[0]) == 2


def test_seams_lie_at_plus_minus_90_degrees_of_the_heading() -> None:
    """The renderer's column c looks at azimuth heading + pi - (c + 0.5) / width * 2 pi."""
    width = 480
    w = seam_weight(width, 20.0)
    x = np.arange(width) + 0.5
    for half, want in ((x < width / 2, math.pi / 2), (x >= width / 2, -math.pi / 2)):
        centre = (w * x)[half].sum() / w[half].sum()
        assert math.pi - centre / width * 2 * math.pi == pytest.approx(want, abs=1e-9)
    assert np.count_nonzero(w) == 2 * 26  # 20 deg of 360 at 480 px: 26.7 px, column centres 107.5-132.5 inside
    assert in_seam_bands(np.array([106.6, 106.4, 120.0, 132.4, 132.6, 240.0]), width, 20.0).tolist() == \
        [True, False, True, True, False, False]


def test_generated_video_is_the_plain_one_ghosted(tmp_path: Path) -> None:
    generate(tmp_path / "plain", seed=2, frames=3, test_frames=2, width=64, layout="small")
    generate(tmp_path / "seam", seed=2, frames=3, test_frames=2, width=64, layout="small", seam_ghost=3, seam_band=40,
             seam_gain=0.9)
    for run in ("mapping", "test"):
        a, b = (read_poses(tmp_path / v / run / "poses.csv") for v in ("plain", "seam"))
        assert np.array_equal(a.xy, b.xy)
        for p in sorted((tmp_path / "plain" / run).glob("*.png")):
            plain = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            seam = cv2.imread(str(tmp_path / "seam" / run / p.name), cv2.IMREAD_UNCHANGED)
            assert np.array_equal(seam, ghost_seams(plain, 3, 40, 0.9))
            outside = seam_weight(64, 40) == 0
            assert np.array_equal(seam[:, outside], plain[:, outside]) and not np.array_equal(seam, plain)


def test_bad_seam_values_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="seam_ghost"):
        generate(tmp_path, frames=2, width=64, seam_ghost=20)
    with pytest.raises(ValueError, match="seam_gain"):
        generate(tmp_path, frames=2, width=64, seam_gain=3.0)
    with pytest.raises(ValueError, match="seam_band"):
        generate(tmp_path, frames=2, width=64, seam_ghost=2, seam_band=0)


def test_counts_on_marked_pirfs() -> None:
    """The planted video of the frame-mask test (frame 1: 5 pairs of near-duplicates): marking
    the rows of the first two pairs, the plain update inserts 4 marked words, the improved
    one 2 (one of each pair), and both rejected ones are marked."""
    rng = np.random.default_rng(0)
    base = rng.normal(0, 1, (15, 64)).astype(np.float32)
    f1 = np.repeat(base[10:], 2, axis=0) + rng.normal(0, 0.01, (10, 64)).astype(np.float32)
    pirfs = np.concatenate([base[:10], f1])
    rows = np.zeros(20, bool)
    rows[10:14] = True
    c = dictionary_counts(pirfs, np.array([0, 10, 20]), ratio=0.7, n_pmax=200, eps=30, sigma=2.0, marked_rows=rows)
    assert (c["plain"], c["improved"], c["marked_pirfs"]) == (20, 15, 4)
    assert (c["plain_marked"], c["improved_marked"]) == (4, 2)
    assert c["reduction_marked_pct"] == pytest.approx(50.0)
    assert c["within_frame_marked_pct"] == pytest.approx(50.0)
    with pytest.raises(ValueError, match="marked_rows has 3"):
        dictionary_counts(pirfs, np.array([0, 10, 20]), ratio=0.7, n_pmax=200, eps=30, sigma=2.0, marked_rows=rows[:3])


def test_seam_marks_find_the_extract_stages_pirfs(tmp_path: Path) -> None:
    """Against the extract stage's tracker on the same frames: the same PIRFs in the same
    order, one band mark each, and every feature counted once, in a band or outside."""
    generate(tmp_path, seed=0, frames=4, test_frames=2, width=240, layout="small", seam_ghost=4)
    paths = sorted((tmp_path / "mapping").glob("frame_*.png"))
    kw = dict(ratio=0.7, w_size_default=2, w_size_max=3, n_pmin=1, n_pmax=200)
    tracker = PirfTracker(**kw)
    want, n_features = [], 0
    for q in paths:
        _xy, resp, d, _shape = extract_frame((str(q), "sift", 1000))
        want.append(tracker.push(d, resp)[0])
        n_features += len(d)
    pirfs, band, c = seam_marks(paths, features="sift", n_features=1000, band_deg=20.0, shift_px=4, **kw)
    assert np.array_equal(pirfs, np.concatenate(want)) and len(pirfs) > 50
    assert len(band) == len(pirfs) and c["pirfs_band"] == int(band.sum()) > 0
    assert c["features_band"] + c["features_out"] == n_features
    assert c["twins_band"] <= c["features_band"] and c["ghost_pairs"] <= c["twins_band"]


def test_summary_laps_count_the_distance_walked(tmp_path: Path) -> None:
    """70 frames of 0.2 m on the 16 m loop: 60 walked + 10 at half speed = 65 steps = 13 m,
    0.81 laps (not 70 x 0.2 / 16 = 0.88)."""
    s = generate(tmp_path, seed=0, frames=70, test_frames=2, width=64, layout="small", slow=0.5, slow_frames=10)
    assert s["laps"] == 0.81
