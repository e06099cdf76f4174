"""Known answers for the eight image comparisons studied for SeqSLAM under changing illumination."""

from __future__ import annotations

import numpy as np
import pytest

from placeloc.seqslam.comparisons import (
    COMPARISONS,
    difference_block,
    half_resolution,
    increment_signs,
    mean_abs_difference,
    orientation_codes,
    patch_normalise,
    prepare,
)

PARAMS = {"patch": 8, "normalisation": "minmax", "gaussian_sigma": 1.0, "ocm_epsilon": 5.0}


def _img(seed: int = 0, shape=(32, 64)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(20, 200, shape).astype(np.uint8)


def test_sad_matches_numpy_reference_uint8_and_float():
    rng = np.random.default_rng(1)
    a = rng.integers(0, 256, (7, 50), dtype=np.uint8)
    b = rng.integers(0, 256, (5, 50), dtype=np.uint8)
    ref = np.abs(a.astype(int)[:, None] - b.astype(int)[None]).mean(-1)
    np.testing.assert_allclose(mean_abs_difference(a, b), ref, rtol=1e-6)
    af, bf = a.astype(np.float32) / 7, b.astype(np.float32) / 7
    np.testing.assert_allclose(mean_abs_difference(af, bf), ref / 7, rtol=1e-5)


def test_patch_normalise_minmax_stretches_each_patch_and_zscore_standardises():
    img = _img(2)
    out = patch_normalise(img, 8, "minmax")
    for y in range(0, 32, 8):
        for x in range(0, 64, 8):
            blk = out[y:y + 8, x:x + 8]
            assert blk.min() == 0 and blk.max() == 255
    z = patch_normalise(img, 8, "zscore")
    blk = z[8:16, 16:24]
    assert abs(blk.mean()) < 1e-5 and abs(blk.std() - 1) < 1e-4
    flat = np.full((8, 8), 77, np.uint8)
    assert (patch_normalise(flat, 8, "minmax") == 0).all()


def test_zscore_blocks_equal_a_per_block_loop_and_the_nan_mean_to_the_bit():
    # whole blocks take the plain mean, edge blocks the NaN-padded one: both agree with a loop
    # over blocks, and whole blocks give the NaN-aware mean's bits (what was computed before)
    rng = np.random.default_rng(7)
    for shape in ((4, 32, 64), (3, 30, 50)):
        img = rng.integers(0, 256, shape, dtype=np.uint8)
        img[0, :8, :8] = 9  # a flat block: zero
        z = patch_normalise(img, 8, "zscore")
        for i in range(shape[0]):
            for y in range(0, shape[1], 8):
                for x in range(0, shape[2], 8):
                    blk = img[i, y:y + 8, x:x + 8].astype(np.float64)
                    sd = blk.std()
                    want = np.zeros_like(blk) if sd <= 1e-6 else (blk - blk.mean()) / sd
                    np.testing.assert_allclose(z[i, y:y + 8, x:x + 8], want, rtol=0, atol=2e-6)
        assert (z[0, :8, :8] == 0).all()
    img_whole = rng.integers(0, 256, (5, 32, 64), dtype=np.uint8)
    blocks = img_whole.astype(np.float32).reshape(5, 4, 8, 8, 8)
    mean = np.nanmean(blocks, axis=(2, 4), keepdims=True)
    sd = np.sqrt(np.nanmean((blocks - mean) ** 2, axis=(2, 4), keepdims=True))
    with np.errstate(divide="ignore", invalid="ignore"):
        before = np.where(sd > 1e-6, (blocks - mean) / sd, np.float32(0.0)).astype(np.float32).reshape(5, 32, 64)
    assert np.array_equal(patch_normalise(img_whole, 8, "zscore"), before)


def test_minmax_blocks_equal_a_per_block_loop_and_the_general_route_to_the_bit():
    # the uint8 whole-block route (in place, a scale per block) against a loop over blocks
    # in float32, and against the general route (a float image: the padded path with
    # np.where), including a flat block and ranges of 1 and 2 (halves: rint to even)
    rng = np.random.default_rng(11)
    img = rng.integers(0, 256, (6, 32, 64), dtype=np.uint8)
    img[0, :8, :8] = 9
    img[1, :8, :8] = rng.integers(40, 42, (8, 8))
    img[2, 8:16, :8] = rng.integers(40, 43, (8, 8))
    out = patch_normalise(img, 8, "minmax")
    for i in range(6):
        for y in range(0, 32, 8):
            for x in range(0, 64, 8):
                blk = img[i, y:y + 8, x:x + 8]
                lo, r = blk.min(), np.float32(blk.max() - blk.min())
                want = (np.zeros_like(blk) if r == 0 else
                        np.rint((blk.astype(np.float32) - np.float32(lo)) * (np.float32(255.0) / r)).astype(np.uint8))
                assert np.array_equal(out[i, y:y + 8, x:x + 8], want), (i, y, x)
    assert (out[0, :8, :8] == 0).all() and set(np.unique(out[2, 8:16, :8])) <= {0, 128, 255}
    assert np.array_equal(out, patch_normalise(img.astype(np.float32), 8, "minmax"))


def test_zncc_is_invariant_to_gain_and_offset():
    img = _img(3)
    brighter = np.clip(img.astype(np.float32) * 1.2 + 30, 0, 255).astype(np.uint8)
    other = _img(4)
    f = np.stack([prepare(x, comparison="zncc", **PARAMS) for x in (img, brighter, other)])
    d = difference_block(f[:1], f, "zncc")[0]
    assert d[0] == pytest.approx(0.0, abs=1e-5)
    assert d[1] == pytest.approx(0.0, abs=2e-3)  # only uint8 rounding differs
    assert d[2] > 0.5


def test_abs_zncc_matches_contrast_inversion_and_zncc_does_not():
    img = _img(5)
    inverted = (255 - img).astype(np.uint8)
    fa = prepare(img, comparison="zncc", **PARAMS)[None]
    fb = prepare(inverted, comparison="zncc", **PARAMS)[None]
    assert difference_block(fa, fb, "zncc")[0, 0] == pytest.approx(2.0, abs=1e-5)  # R = -1
    assert difference_block(fa, fb, "abs_zncc")[0, 0] == pytest.approx(0.0, abs=1e-5)


def test_isc_bits_and_similarity_by_hand():
    g = np.array([[1, 3, 2], [5, 4, 6]], np.uint8)  # raster: 1 3 2 5 4 6
    np.testing.assert_array_equal(increment_signs(g), [1, 0, 1, 0, 1])
    h = np.array([[2, 1, 3], [4, 5, 0]], np.uint8)  # raster: 2 1 3 4 5 0 -> 0 1 1 1 0
    np.testing.assert_array_equal(increment_signs(h), [0, 1, 1, 1, 0])
    # agreements: positions 3 only (1 vs 1 at index 2) -> b = 10101 vs 01110 agree at index 2 -> R = 1/5
    d = difference_block(increment_signs(g)[None], increment_signs(h)[None], "isc")
    assert d[0, 0] == pytest.approx(1 - 1 / 5)
    assert difference_block(increment_signs(g)[None], increment_signs(g)[None], "isc")[0, 0] == pytest.approx(0.0)


def test_orientation_codes_of_ramps_and_flat_image():
    x = np.tile(np.arange(16, dtype=np.float32) * 10, (16, 1))  # brightness grows to the right: 0 deg
    assert set(orientation_codes(x, 5.0)[5 * 16 + 2:5 * 16 + 14]) == {0}
    y = x.T.copy()  # grows downward: +90 deg in image coordinates -> code 4
    assert set(orientation_codes(y, 5.0)[2 * 16 + 5:14 * 16:16]) == {4}
    flat = np.full((8, 8), 100, np.float32)
    assert (orientation_codes(flat, 5.0) == 16).all()
    diag = np.add.outer(np.arange(16.0) * 1.5, np.arange(16.0)) * 10  # atan(1.5) = 56.3 deg -> code 2
    assert orientation_codes(diag, 5.0)[8 * 16 + 8] == 2


def test_ocm_weights_by_hand():
    a = np.array([[0, 1, 2, 16, 5, 15]], np.uint8)
    b = np.array([[0, 2, 4, 3, 5, 0]], np.uint8)
    # weights: diff 0 -> 1, diff 1 -> .5, diff 2 -> .25, code 16 -> 0, diff 0 -> 1, 15 vs 0 (diff 1 circular) -> .5
    expected = 1 - (1 + 0.5 + 0.25 + 0 + 1 + 0.5) / 6
    assert difference_block(a, b, "ocm")[0, 0] == pytest.approx(expected)


def test_half_resolution_averages_four_pixels():
    x = np.array([[0, 4, 8, 8], [4, 8, 0, 0]], np.float32)
    np.testing.assert_allclose(half_resolution(x), [[4, 4]])


@pytest.mark.parametrize("comparison", COMPARISONS)
def test_every_comparison_prefers_the_same_place_under_light_change(comparison):
    rng = np.random.default_rng(7)
    scene = [np.clip(np.kron(rng.integers(0, 255, (8, 16)), np.ones((4, 4))), 0, 255).astype(np.uint8) for _ in range(4)]
    darker = [np.clip(s.astype(np.float32) * 0.6 + 10 + rng.normal(0, 2, s.shape), 0, 255).astype(np.uint8) for s in scene]
    ref = np.stack([prepare(s, comparison=comparison, **PARAMS) for s in scene])
    qry = np.stack([prepare(s, comparison=comparison, **PARAMS) for s in darker])
    d = difference_block(ref, qry, comparison)
    assert d.shape == (4, 4)
    np.testing.assert_array_equal(np.argmin(d, axis=0), np.arange(4))


def test_sad_kernels_agree_exactly_on_odd_sizes():
    """Both compiled uint8 kernels (vpsadbw where the CPU has AVX2, the plain loop
    everywhere) against NumPy's exact sums, on sizes that leave partial 32-byte blocks and
    partial tiles, with one thread and with several."""
    from placeloc.seqslam import l1

    variants = [False] + ([True] if l1.host_has_avx2() else [])
    rng = np.random.default_rng(5)
    for n, m, d in ((7, 5, 50), (100, 97, 2048), (33, 70, 2053), (1, 1, 31), (4, 130, 7)):
        a = rng.integers(0, 256, (n, d), dtype=np.uint8)
        b = rng.integers(0, 256, (m, d), dtype=np.uint8)
        expect = (np.abs(a.astype(np.int64)[:, None] - b.astype(np.int64)[None]).sum(-1) / d).astype(np.float32)
        for avx2 in variants:
            for threads in (1, 3):
                out = np.full((n, m), np.nan, np.float32)
                l1.l1_uint8(a, b, out, avx2=avx2, threads=threads)
                np.testing.assert_array_equal(out, expect)


def test_float_kernel_matches_numpy():
    from placeloc.seqslam import l1

    rng = np.random.default_rng(6)
    a, b = rng.normal(size=(9, 301)).astype(np.float32), rng.normal(size=(50, 301)).astype(np.float32)
    out = np.empty((9, 50), np.float32)
    l1.l1_float(a, b, out, threads=2)
    np.testing.assert_allclose(out, np.abs(a.astype(np.float64)[:, None] - b[None]).mean(-1), rtol=1e-5)


def test_sad_kernel_machine_code_is_cached_and_reloaded(tmp_path):
    """The first process compiles the kernel and stores its machine code; the next one loads
    that file (it does not compile) and gets the same exact sums; a damaged file is rebuilt."""
    import subprocess
    import sys

    code = ("import numpy as np, time; from placeloc.seqslam import l1; "
            "a = np.arange(3 * 70, dtype=np.uint8).reshape(3, 70); b = a[::-1].copy(); "
            "o = np.empty((3, 3), np.float32); l1.l1_uint8(a, b, o, threads=1); "
            "e = (np.abs(a.astype(int)[:, None] - b.astype(int)[None]).sum(-1) / 70).astype(np.float32); "
            "print(int(np.array_equal(o, e)))")
    env = {**__import__("os").environ, "XDG_CACHE_HOME": str(tmp_path)}
    first = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    cached = list((tmp_path / "placeloc" / "kernels").glob("l1_u8-*.o"))
    assert first.strip() == "1" and len(cached) == 1
    stamp = cached[0].stat().st_mtime_ns
    second = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert second.strip() == "1" and cached[0].stat().st_mtime_ns == stamp  # loaded, not rewritten
    # A damaged file (LLVM would crash loading it) is recompiled and replaced.
    cached[0].write_bytes(cached[0].read_bytes()[:100])
    third = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert third.strip() == "1" and cached[0].stat().st_size > 100
