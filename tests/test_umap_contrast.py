"""``umap.panorama.equalize_clip``: each cube face's contrast equalised locally (CLAHE)
before LSD, so that a junction of two surfaces painted alike is found."""

import numpy as np

from placeloc.geometry.panorama import detect_segments, equalized, panorama_lines
from placeloc.umap.bits import unpack
from placeloc.umap.query_features import panorama_arrays


def _faint_edge(delta: float, sigma: float, seed: int = 0) -> np.ndarray:
    # a 256-pixel face: a ceiling ``delta`` grey levels brighter than the wall under it
    # (rows 0-99), camera noise of ``sigma`` levels
    rng = np.random.default_rng(seed)
    img = np.full((256, 256), 200.0)
    img[:100] += delta
    return np.clip(img + rng.normal(0.0, sigma, img.shape), 0, 255).astype(np.uint8)


def _along_edge(segs: np.ndarray) -> float:
    on = segs[(np.abs(segs[:, 1] - 99.5) < 3) & (np.abs(segs[:, 3] - 99.5) < 3)]
    return float(np.hypot(on[:, 2] - on[:, 0], on[:, 3] - on[:, 1]).sum())


def test_a_faint_junction_is_found_only_once_equalised():
    # LSD's gradient threshold (about 5 levels after its own smoothing) misses a 6-level
    # junction across the whole face; equalised at clip 2 it is found end to end, and the
    # flat, noisy areas either side give no segment
    face = _faint_edge(6.0, 1.0)
    assert len(detect_segments(face)) == 0
    segs = detect_segments(equalized(face, 2.0))
    assert _along_edge(segs) > 240.0
    assert _along_edge(segs) >= 0.95 * float(np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]).sum())


def test_a_strong_junction_is_found_either_way():
    face = _faint_edge(40.0, 1.0)
    assert _along_edge(detect_segments(face)) > 240.0
    assert _along_edge(detect_segments(equalized(face, 2.0))) > 240.0


def test_equalized_takes_images_other_than_8_bit():
    face = _faint_edge(6.0, 1.0)
    assert np.array_equal(equalized(face.astype(np.float32), 2.0), equalized(face, 2.0))


def test_panorama_lines_are_the_same_with_equalisation_off():
    face = _faint_edge(40.0, 1.0)
    pano = np.tile(np.vstack([face, face]), (1, 4))      # 512 x 1024
    plain = panorama_lines(pano, face_px=128, min_length=8.0)
    off = panorama_lines(pano, face_px=128, min_length=8.0, equalize_clip=0.0)
    assert all(np.array_equal(a, b) for a, b in zip(plain, off))


def test_a_panoramas_faint_wall_corners_are_drawn_where_they_stand():
    # a wall 6 levels brighter than its neighbours between columns 300 and 700 of 1,024:
    # two vertical junctions, at line-image columns 42.2 and 98.4 of 144
    rng = np.random.default_rng(1)
    pano = np.full((512, 1024), 190.0)
    pano[:, 300:700] += 6.0
    pano = np.clip(pano + rng.normal(0.0, 1.0, pano.shape), 0, 255).astype(np.uint8)
    kw = dict(width=144, height=72, face_px=256, min_length=8.0)
    assert unpack(panorama_arrays(pano, **kw)["lines"], 72, 144).sum() == 0
    per_col = unpack(panorama_arrays(pano, equalize_clip=2.0, **kw)["lines"], 72, 144)[0].sum(axis=0)
    # most of each corner's 72 rows, and nearly nothing elsewhere (a stray pixel of noise)
    assert per_col[41:44].sum() > 50 and per_col[97:100].sum() > 50
    assert per_col[41:44].sum() + per_col[97:100].sum() >= 0.9 * per_col.sum()
