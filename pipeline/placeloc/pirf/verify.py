"""Geometric check of a loop closure's bearing layout on omnidirectional frames.

Not in Sasaki and Hamagami's paper, whose loop closure is the similarity threshold alone
(eq. 9). It counts a closure correct when the matched node L_c lies within 1 m of where
the camera stands (sec. 5.1.3), but PIRFs are chosen to be insensitive to camera motion
(sec. 2), so the similarity cannot tell a place from one 1-2 m beside it: on our generated
video the wrong closures that remain after the direction correction all walk 1-2 m beside
the first pass through the same room, where no earlier frame lies within 1 m at all.

What does tell them apart is parallax. In an equirectangular frame a feature's column is
its bearing. Seen from the same spot, the bearings of shared features differ by one
rotation (the heading change); seen from a spot d metres away, a feature at range r
shifts by up to about d / r more. The residual spread of the bearing differences once the
rotation is removed (:func:`bearing_residual`, median absolute residual) grows with d, but
it depends on the scene's depth (a corridor's walls are near, a room's far), so it has no
fixed threshold. The map supplies the yardstick instead: the same residual between the
matched node c and the mapping frames ``k`` before and after it, which stand where the
camera moved in k frames. A closure (t, c) is kept when its residual is no larger than
that reference (:func:`verify_closures`): t stands no further from c, in parallax, than
c's own map neighbours k frames away. With the paper's camera (5 frames/s, carried at a
walking pace of about 1 m/s, so about 0.2 m per frame) k = 5 puts the yardstick at the
paper's 1 m.

Features are detected afresh on the two frames (the detector of ``pirf.features``) and
matched with the ratio test of eq. (1): raw features, not PIRFs, because the check is
about where the camera stood, which PIRFs are built to ignore. Only the frames of
candidate closures and their reference frames are read.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from placeloc.pirf.chain import ratio_match

# Feature of one frame for the check: (bearing of each feature in radians, descriptors).
Bearings = tuple[np.ndarray, np.ndarray]


def bearings(x: np.ndarray, width: int) -> np.ndarray:
    """Equirectangular column -> bearing in radians (the full 360 degrees across the width)."""
    return np.asarray(x, np.float64) / float(width) * 2.0 * np.pi


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.angle(np.exp(1j * a))


def bearing_residual(a: Bearings, b: Bearings, *, ratio: float, min_matches: int) -> float:
    """Median absolute bearing residual (radians) of the ratio-test matches between two
    frames once their rotation is removed; NaN with fewer than ``min_matches`` matches.

    The rotation is the circular mean of the bearing differences, taken again over the
    matches within twice the median residual so that a few wrong matches do not move it.
    """
    (ta, da), (tb, db) = a, b
    m = ratio_match(da, db, ratio)
    ok = np.flatnonzero(m >= 0)
    if len(ok) < min_matches:
        return float("nan")
    diff = _wrap(ta[ok] - tb[m[ok]])
    psi = np.angle(np.exp(1j * diff).mean())
    res = np.abs(_wrap(diff - psi))
    inl = res <= 2 * np.median(res)
    psi = np.angle(np.exp(1j * diff[inl]).mean())
    return float(np.median(np.abs(_wrap(diff - psi))))


def frames_needed(frames: np.ndarray, nodes: np.ndarray, k: int, n_frames: int) -> np.ndarray:
    """Every frame :func:`verify_closures` reads: the closures' frames and nodes and the
    nodes' reference frames c - k and c + k (those inside the video)."""
    ref = np.concatenate([nodes - k, nodes + k])
    return np.unique(np.concatenate([frames, nodes, ref[(ref >= 0) & (ref < n_frames)]])).astype(np.int64)


def verify_closures(frames: np.ndarray, nodes: np.ndarray, features: Callable[[int], Bearings], *, k: int, n_frames: int,
                    ratio: float, min_matches: int) -> dict[str, np.ndarray]:
    """Keep loop closure (frame t, node c) when its bearing residual is no larger than the
    mean residual between c and the frames c - k and c + k (those that exist).

    A closure whose two frames share fewer than ``min_matches`` matches is dropped (no
    geometric support); one whose reference cannot be measured is kept (no yardstick, no
    evidence against it). Returns ``keep`` (bool), ``residual`` and ``reference`` (radians).
    """
    cache: dict[tuple[int, int], float] = {}

    def res(i: int, j: int) -> float:
        key = (min(i, j), max(i, j))
        if key not in cache:
            cache[key] = bearing_residual(features(i), features(j), ratio=ratio, min_matches=min_matches)
        return cache[key]

    n = len(frames)
    residual, reference = np.full(n, np.nan), np.full(n, np.nan)
    keep = np.zeros(n, bool)
    for q, (t, c) in enumerate(zip(np.asarray(frames, np.int64), np.asarray(nodes, np.int64))):
        residual[q] = res(int(t), int(c))
        refs = [res(int(c), int(j)) for j in (c - k, c + k) if 0 <= j < n_frames]
        refs = [r for r in refs if r == r]
        reference[q] = float(np.mean(refs)) if refs else np.nan
        if residual[q] != residual[q]:
            keep[q] = False
        elif reference[q] != reference[q]:
            keep[q] = True
        else:
            keep[q] = residual[q] <= reference[q]
    return {"keep": keep, "residual": residual, "reference": reference}
