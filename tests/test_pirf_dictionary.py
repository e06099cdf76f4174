"""The dictionary-size experiment: the generator's slow motion and sideways revisits (known
speeds and offsets), default generation unchanged, and the plain/improved counting on
descriptors with planted within-frame duplicates."""

from __future__ import annotations

import hashlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from placeloc.evaluation.poses import read_poses
from placeloc.experiments.pirf_dictionary import dictionary_counts, merged_chains, property_frames, ratio_twins
from placeloc.synth.omni import OmniWorld, generate, loop_length, loop_path

SQUARE = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)]  # 40 m, counter-clockwise: left = inside


def _steps(poses: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1)


def test_slow_motion_walks_at_the_given_fraction_of_the_step() -> None:
    walk = loop_path(SQUARE, 80, 0.2)
    slow = loop_path(SQUARE, 80, 0.2, slow=0.25, slow_frames=10, dwell_every=30)
    steps = _steps(slow)  # steps[t - 1]: from frame t - 1 to frame t (all on the first side, 0..10 m)
    assert np.allclose(slow[:30], walk[:30])
    assert np.allclose(steps[29:39], 0.05)  # frames 30-39: a quarter of the 0.2 m step
    assert np.allclose(steps[39:55], 0.2)   # then walking again (to the first corner at 10 m)
    assert np.allclose(steps[69:79], 0.05)  # and the next slow stretch


def test_generated_slow_motion_poses_have_the_slow_speed(tmp_path: Path) -> None:
    generate(tmp_path, seed=0, frames=70, test_frames=2, width=64, layout="small", step=0.2, slow=0.5, slow_frames=10)
    xy = read_poses(tmp_path / "mapping" / "poses.csv").xy
    steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)  # the written poses carry 2 cm jitter
    assert abs(np.median(steps[:49]) - 0.2) < 0.02
    assert abs(np.median(steps[49:59]) - 0.1) < 0.02  # frames 50-59 at half speed
    assert abs(np.median(steps[59:]) - 0.2) < 0.02
    # the experiment's stretches are 50 frames long (after every 50 walked)
    assert property_frames("slow", 0.5, 120).nonzero()[0].tolist() == list(range(50, 100))


def test_later_laps_are_offset_sideways_alternately() -> None:
    poses = loop_path(SQUARE, 600, 0.2, lap_offset=0.3, lap_ramp=2.0)  # 200 frames a lap, 3 laps
    bottom = (poses[:, 0] > 3) & (poses[:, 0] < 7) & (poses[:, 1] < 1)  # the first side, y = 0 on lap 0, past each ramp
    lap = np.arange(600) // 200
    assert np.allclose(poses[bottom & (lap == 0), 1], 0.0)
    assert np.allclose(poses[bottom & (lap == 1), 1], 0.3)   # left of the path (inside the square)
    assert np.allclose(poses[bottom & (lap == 2), 1], -0.3)  # then the other side
    # the shift ramps in over lap_ramp metres: 0.3 m, then 0.6 m, spread over 10 frames of 0.2 m
    for k, total in ((1, 0.3), (2, -0.6)):
        y = poses[k * 200:k * 200 + 15, 1]
        assert np.allclose(np.diff(y)[:10], total / 10) and np.allclose(np.diff(y)[10:], 0.0)


def test_generated_revisit_laps_lie_at_the_offset(tmp_path: Path) -> None:
    generate(tmp_path, seed=0, frames=200, test_frames=2, width=64, layout="small", revisit_offset=0.4)
    xy = read_poses(tmp_path / "mapping" / "poses.csv").xy
    lap_frames = int(round(loop_length("small") / 0.2))  # 16 m loop: 80 frames a lap
    # the small room's loop walks x = 6.5 from y = 1.5 to 4.5 second (5-8 m into a lap, past the
    # 5 m ramp); lap 1 walks it 0.4 m to the left (x = 6.1), lap 2 0.4 m to the right (x = 6.9)
    second = (xy[:, 0] > 5.5) & (xy[:, 1] > 2.3) & (xy[:, 1] < 4.0)
    lap = np.arange(200) // lap_frames
    for k, x in ((0, 6.5), (1, 6.1), (2, 6.9)):
        assert (second & (lap == k)).sum() >= 5
        assert abs(np.median(xy[second & (lap == k), 0]) - x) < 0.05  # 2 cm jitter on a few frames
    assert property_frames("revisit", 0.4, 200, "small").nonzero()[0][0] == lap_frames


def _digest(out: Path) -> str:
    h = hashlib.sha256()
    for run in ("mapping", "test"):
        h.update((out / run / "poses.csv").read_bytes())
        for p in sorted((out / run).glob("*.png")):
            h.update(cv2.imread(str(p), cv2.IMREAD_UNCHANGED).tobytes())
    return h.hexdigest()


def test_default_generation_is_unchanged(tmp_path: Path) -> None:
    """Digests recorded with the generator before slow motion and revisits existed."""
    generate(tmp_path / "a", seed=3, frames=4, test_frames=2, width=64, layout="building")
    assert _digest(tmp_path / "a") == "6eb05bda985241d5f382a136281e4184fd39c9af689d828efb016e5213e8ac6c"
    generate(tmp_path / "b", seed=1, frames=3, test_frames=2, width=64, layout="building", dwell=2)
    assert _digest(tmp_path / "b") == "080c144d6e7df81a7875ba0e8529bb7caa8f564e2c279c90da8d5e8f8996bb6e"
    loop = OmniWorld("building", 0).loop
    for kw, want in (({}, "dc33477c0a4f652770c83ce9a319d1ce72463463d8463309b3560417298ea94b"),
                     ({"dwell": 10}, "6541b8c5795d07b7c22a857c72c2357f91603f232036b2c72e3ba249ed7dda2f")):
        p = loop_path(loop, 1500, 0.2, jitter=0.02, rng=np.random.default_rng(0), **kw)
        assert hashlib.sha256(np.ascontiguousarray(p).tobytes()).hexdigest() == want


def test_bad_generator_values_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="slow must lie in"):
        generate(tmp_path, frames=4, width=64, slow=0.0)
    with pytest.raises(ValueError, match="revisit_offset"):
        generate(tmp_path, frames=4, width=64, revisit_offset=2.0)


def test_counts_on_planted_within_frame_duplicates() -> None:
    """Frame 0: 10 unrelated descriptors; frame 1: 5 pairs of near-duplicates, unrelated to
    frame 0. The plain update inserts all 20; the improved one rejects the second of each
    pair (its nearest word, the first, passes the ratio test), so 15 words."""
    rng = np.random.default_rng(0)
    base = rng.normal(0, 1, (15, 64)).astype(np.float32)
    f1 = np.repeat(base[10:], 2, axis=0) + rng.normal(0, 0.01, (10, 64)).astype(np.float32)
    pirfs = np.concatenate([base[:10], f1])
    offsets = np.array([0, 10, 20])
    c = dictionary_counts(pirfs, offsets, ratio=0.7, n_pmax=200, eps=30, sigma=2.0, marked=np.array([False, True]))
    assert (c["plain"], c["improved"], c["within_frame"]) == (20, 15, 5)
    assert c["reduction_pct"] == pytest.approx(25.0)
    assert (c["plain_marked"], c["improved_marked"]) == (10, 5)
    assert c["twins_plain_pct"] == pytest.approx(50.0)  # the 10 words of the pairs
    assert c["twins_improved_pct"] == 0.0
    assert c["twins_plain_near_pct"] == 100.0  # each pair entered in one frame


def test_ratio_twins_finds_the_planted_pair() -> None:
    rng = np.random.default_rng(1)
    words = rng.normal(0, 1, (50, 32)).astype(np.float32)
    words[7] = words[31] + 0.01
    has, twin = ratio_twins(words, 0.7)
    assert has.nonzero()[0].tolist() == [7, 31]
    assert (twin[7], twin[31]) == (31, 7)


def test_merged_chains_are_counted_as_within_frame_twins() -> None:
    """30 features tracked over 4 frames; in the last frame feature 5 appears twice (a second
    detection 0.5 % away), so both ratio-match feature 5 of the frame before: their chains
    merge and their PIRFs (means along the chain) are twins."""
    rng = np.random.default_rng(2)
    base = rng.normal(0, 1, (30, 64)).astype(np.float32)
    frames = [(base + rng.normal(0, 0.01, base.shape).astype(np.float32), np.ones(30, np.float32)) for _ in range(4)]
    last = np.concatenate([frames[-1][0], frames[-1][0][5:6] + 0.005])
    frames[-1] = (last, np.ones(31, np.float32))
    c = merged_chains(frames, ratio=0.7, w_size_default=2, w_size_max=3, n_pmin=1, n_pmax=200)
    # frames 1-3 give PIRFs (frame 0 has no history): 30 + 30 + 31
    assert c["pirfs"] == 91
    assert (c["merged_chain"], c["twins_in_frame"], c["twins_in_merged_chain"]) == (2, 2, 2)
