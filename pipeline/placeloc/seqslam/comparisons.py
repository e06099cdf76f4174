"""The eight image comparisons studied for SeqSLAM under changing illumination.

SeqSLAM itself is M. Milford and G. Wyeth, "SeqSLAM: Visual route-based navigation for
sunny summer days and stormy winter nights", ICRA 2012 (sum of absolute differences of
patch-normalised thumbnails). The other seven comparisons (histogram equalisation, ZNCC
and its absolute value, increment sign correlation ISC, orientation code matching OCM and
their four-pixel-average extensions) are those of the study of illumination-robust image
comparisons for SeqSLAM this project reproduces; the equation numbers below are that
study's.

Every comparison has two halves:

- ``prepare(thumbnail, comparison=..., patch=..., ...)`` turns one greyscale thumbnail
  into the feature vector that comparison works on (done once per image, in ``extract``);
- ``difference_block(ref_features, query_features, comparison)`` returns the difference
  block ``D[i, j]`` between reference ``i`` and query ``j``.

Matrix convention, everywhere in placeloc's SeqSLAM: rows = reference, columns = query,
and *lower = more alike*. Similarities ``R`` are turned into differences ``1 - R``.

Readings of the paper where it is terse (recorded here, the one place they are used):

- ``sad``: patch normalisation (min-max to 0..255 by default, or z-score), then the mean
  absolute difference over pixels, as SeqSLAM.
- ``histeq``: ``cv2.equalizeHist`` on the thumbnail, then the mean absolute difference.
- ``zncc``: eq. (4) on the thumbnail; ``abs_zncc`` takes ``|R|`` so a contrast-inverted
  image (day/night) still matches.
- ``isc``: eq. (5)-(6): ``b_n = [g_{n+1} > g_n]`` over the raster-ordered pixels of the
  Gaussian-filtered thumbnail, ``R = (1/N) sum (b b' + (1-b)(1-b'))`` with ``N`` bits.
- ``ocm``: eq. (7)-(8): Sobel gradient angle in 16 codes of 22.5 deg; pixels whose
  gradient magnitude is below ``ocm_epsilon`` get code 16 and count for nothing; weight
  1 / 0.5 / 0.25 for circular code difference 0 / 1 / 2; divided by the pixel count.
- ``*_ext``: the paper extends "the pixel of interest and the compared pixel from one pixel
  to the average of four". We take non-overlapping 2x2 averages (the image at half
  resolution) and apply ISC/OCM to those, which is what absorbs the small shifts.

The kernels: SAD is a uint8 L1 kernel compiled with llvmlite (x86 ``vpsadbw`` where the
CPU has AVX2, see :mod:`placeloc.seqslam.l1`); ZNCC, ISC and OCM are matrix products (BLAS) of suitably
encoded vectors, which is why their features are stored encoded.
"""

from __future__ import annotations

import numpy as np

# OpenCV is imported where an image is worked (extract), not with the module: localize and
# evaluate import these comparisons for their difference blocks and never call OpenCV, and
# its import cost each of their processes 20 ms

COMPARISONS = ("sad", "histeq", "zncc", "abs_zncc", "isc", "isc_ext", "ocm", "ocm_ext")
# the comparisons whose difference is the mean absolute difference of the feature rows
L1_COMPARISONS = ("sad", "histeq")
OCM_CODES = 16

# Circular weights of eq. (8): code difference 0 -> 1, 1 or 15 -> 0.5, 2 or 14 -> 0.25.
_OCM_DIFF_WEIGHT = np.zeros(OCM_CODES, np.float32)
_OCM_DIFF_WEIGHT[[0, 1, 15, 2, 14]] = [1.0, 0.5, 0.5, 0.25, 0.25]
OCM_WEIGHTS = np.array([[_OCM_DIFF_WEIGHT[(a - b) % OCM_CODES] for b in range(OCM_CODES)] for a in range(OCM_CODES)],
                       np.float32)


# ---------------------------------------------------------------------------------------
# Per-image preparation
# ---------------------------------------------------------------------------------------
def thumbnail(gray: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize to ``size = (width, height)`` with area averaging (SeqSLAM's down-sampling)."""
    w, h = int(size[0]), int(size[1])
    if gray.shape[1] == w and gray.shape[0] == h:
        return gray
    import cv2

    return cv2.resize(gray, (w, h), interpolation=cv2.INTER_AREA)


def patch_normalise(img: np.ndarray, patch: int, mode: str) -> np.ndarray:
    """Normalise each ``patch x patch`` block on its own.

    ``minmax`` (the paper's "existing method") stretches each block to 0..255 and returns
    uint8; a flat block becomes 0. ``zscore`` (OpenSeqSLAM) returns float32 with zero mean
    and unit standard deviation per block. Edge blocks may be smaller than ``patch``.
    ``img`` is one image (h, w) or a stack (n, h, w), normalised image by image.
    Vectorised: each image is viewed as (rows of blocks, patch, columns of blocks, patch)
    and reduced over the two in-block axes.
    """
    *lead, h, w = img.shape
    x = img.astype(np.float32)
    ph, pw = -(-h // patch) * patch, -(-w // patch) * patch
    pad = [(0, 0)] * len(lead) + [(0, ph - h), (0, pw - w)]
    shape = (*lead, ph // patch, patch, pw // patch, patch)
    axes = (len(lead) + 1, len(lead) + 3)
    if mode == "minmax" and (ph, pw) == (h, w) and img.dtype == np.uint8:
        # The common case: blocks gathered contiguously, min/max taken exactly in uint8. The
        # scale is per block (0 for a flat block, whose pixels less its minimum are all 0) and
        # the pixels are worked in place: the same float32 operations as the general route
        # below, so the same bits (tested), at 0.85x the time of np.where over every pixel (64
        # frames of 64 x 32: 619-628 us against 715-732, three runs each, best of 7): a 2 %
        # smaller extract of 7152 such frames (medians of 8 alternating runs 0.430 / 0.439 s)
        n = int(np.prod(lead)) if lead else 1
        b = img.reshape(n, h // patch, patch, w // patch, patch).transpose(0, 1, 3, 2, 4)
        b = b.reshape(n, h // patch, w // patch, patch * patch)
        lo = b.min(axis=3, keepdims=True)
        rng = (b.max(axis=3, keepdims=True) - lo).astype(np.float32)
        scale = np.zeros_like(rng)
        np.divide(np.float32(255.0), rng, out=scale, where=rng > 0)
        x = b.astype(np.float32)
        x -= lo
        x *= scale
        out = np.rint(x, out=x).astype(np.uint8).reshape(n, h // patch, w // patch, patch, patch).transpose(0, 1, 3, 2, 4)
        return np.ascontiguousarray(out).reshape(*lead, h, w)
    if mode == "minmax":
        # Edge padding repeats pixels of the same (smaller) edge block: its min/max stay.
        xp = x if (ph, pw) == (h, w) else np.pad(x, pad, mode="edge")
        blocks = xp.reshape(shape)
        lo = blocks.min(axis=axes, keepdims=True)
        rng = blocks.max(axis=axes, keepdims=True) - lo
        with np.errstate(divide="ignore", invalid="ignore"):
            out = np.where(rng > 0, (blocks - lo) * (np.float32(255.0) / rng), np.float32(0.0))
        return np.rint(out.reshape(*lead, ph, pw)[..., :h, :w]).astype(np.uint8)
    if mode != "zscore":
        raise ValueError(f"unknown patch normalisation {mode!r}; choose minmax or zscore")
    # NaN padding so partial edge blocks average over their own pixels only. Without padding
    # the plain mean (the same sums and counts, so the same bits: tested): nanmean copies the
    # array to replace NaNs, 45 % of the Nordland preset's feature preparation
    padded = (ph, pw) != (h, w)
    xp = np.pad(x, pad, constant_values=np.nan) if padded else x
    blocks = xp.reshape(shape)
    average = np.nanmean if padded else np.mean
    mean = average(blocks, axis=axes, keepdims=True)
    sd = np.sqrt(average((blocks - mean) ** 2, axis=axes, keepdims=True))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(sd > 1e-6, (blocks - mean) / sd, np.float32(0.0)).astype(np.float32)
    return np.ascontiguousarray(out.reshape(*lead, ph, pw)[..., :h, :w])


def half_resolution(img: np.ndarray) -> np.ndarray:
    """Average non-overlapping 2x2 blocks: each new pixel is the mean of four (``*_ext``)."""
    h, w = (img.shape[0] // 2) * 2, (img.shape[1] // 2) * 2
    x = img[:h, :w].astype(np.float32)
    return 0.25 * (x[0::2, 0::2] + x[1::2, 0::2] + x[0::2, 1::2] + x[1::2, 1::2])


def increment_signs(img: np.ndarray) -> np.ndarray:
    """ISC bits ``b_n = [g_{n+1} > g_n]`` over the raster-ordered pixels (N-1 bits)."""
    g = img.astype(np.float32).ravel()
    return (g[1:] > g[:-1]).astype(np.uint8)


def orientation_codes(img: np.ndarray, epsilon: float) -> np.ndarray:
    """OCM codes 0..15 (22.5 deg bins of the gradient angle); 16 where |grad| < epsilon."""
    import cv2

    x = img.astype(np.float32)
    gx = cv2.Sobel(x, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(x, cv2.CV_32F, 0, 1, ksize=3)
    angle = np.degrees(np.arctan2(gy, gx)) % 360.0
    codes = np.floor(angle / (360.0 / OCM_CODES)).astype(np.int64) % OCM_CODES
    codes[np.hypot(gx, gy) < epsilon] = OCM_CODES
    return codes.astype(np.uint8).ravel()


def _unit_centred(thumb: np.ndarray) -> np.ndarray:
    """ZNCC's vector: mean removed, unit length (row by row: the float sums stay as they were)."""
    v = thumb.astype(np.float32).ravel()
    v = v - v.mean()
    n = float(np.linalg.norm(v))
    return (v / n if n > 0 else v).astype(np.float32)


def _gaussian(img: np.ndarray, sigma: float) -> np.ndarray:
    if sigma <= 0:
        return img.astype(np.float32)
    import cv2

    return cv2.GaussianBlur(img.astype(np.float32), (0, 0), sigma)


def prepare(thumb: np.ndarray, *, comparison: str, patch: int, normalisation: str, gaussian_sigma: float,
            ocm_epsilon: float) -> np.ndarray:
    """Feature vector of one thumbnail for ``comparison`` (see the module docstring).

    ``patch`` and ``normalisation`` matter for ``sad`` only; ``gaussian_sigma`` for
    ``isc*``/``ocm*``; ``ocm_epsilon`` for ``ocm*``.
    """
    return prepare_many(thumb[None], comparison=comparison, patch=patch, normalisation=normalisation,
                        gaussian_sigma=gaussian_sigma, ocm_epsilon=ocm_epsilon)[0]


def prepare_many(thumbs: np.ndarray, *, comparison: str, patch: int, normalisation: str, gaussian_sigma: float,
                 ocm_epsilon: float) -> np.ndarray:
    """Feature rows (n, d) of a stack of thumbnails (n, h, w); ``sad`` is done in one vectorised pass."""
    if comparison == "sad":
        return patch_normalise(thumbs, int(patch), normalisation).reshape(len(thumbs), -1)
    if comparison == "histeq":
        import cv2

        return np.stack([cv2.equalizeHist(t).ravel() for t in thumbs]).reshape(len(thumbs), -1)
    if comparison in ("zncc", "abs_zncc"):
        return np.stack([_unit_centred(t) for t in thumbs]).reshape(len(thumbs), -1)
    if comparison not in COMPARISONS:
        raise ValueError(f"unknown comparison {comparison!r}; choose one of {', '.join(COMPARISONS)}")
    rows = []
    for t in thumbs:
        img = _gaussian(t, float(gaussian_sigma))
        if comparison.endswith("_ext"):
            img = half_resolution(img)
        rows.append(increment_signs(img) if comparison.startswith("isc") else orientation_codes(img, float(ocm_epsilon)))
    return np.stack(rows) if rows else np.zeros((0, 0), np.uint8)


def feature_dtype(comparison: str, normalisation: str) -> np.dtype:
    """The dtype ``prepare`` returns for this comparison (uint8 wherever it can)."""
    if comparison == "sad" and normalisation == "zscore":
        return np.dtype(np.float32)
    if comparison in ("zncc", "abs_zncc"):
        return np.dtype(np.float32)
    return np.dtype(np.uint8)


# ---------------------------------------------------------------------------------------
# Difference blocks
# ---------------------------------------------------------------------------------------
def mean_abs_difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``out[i, j] = mean_k |a[i, k] - b[j, k]|`` as float32 (compiled kernels, all cores)."""
    # The kernels live in their own module, imported here: extract never compiles them.
    from placeloc.seqslam.l1 import l1_float, l1_uint8

    out = np.empty((a.shape[0], b.shape[0]), np.float32)
    if a.dtype == np.uint8 and b.dtype == np.uint8:
        l1_uint8(np.ascontiguousarray(a), np.ascontiguousarray(b), out)
    else:
        l1_float(np.ascontiguousarray(a, dtype=np.float32), np.ascontiguousarray(b, dtype=np.float32), out)
    return out


def _ocm_onehot(codes: np.ndarray, weighted: bool) -> np.ndarray:
    """(n, N*16) encoding: one-hot of each pixel's code, or its row of OCM weights.

    Code 16 (low contrast) encodes as all zeros, so it contributes nothing either way.
    """
    n, npx = codes.shape
    table = np.vstack([OCM_WEIGHTS if weighted else np.eye(OCM_CODES, dtype=np.float32),
                       np.zeros((1, OCM_CODES), np.float32)])
    return table[codes].reshape(n, npx * OCM_CODES)


def difference_block(ref: np.ndarray, query: np.ndarray, comparison: str) -> np.ndarray:
    """Difference block (rows = reference, columns = query, lower = more alike), float32."""
    if comparison in L1_COMPARISONS:
        return mean_abs_difference(ref, query)
    if comparison in ("cosine", "l2"):  # descriptors brought from elsewhere (see descriptors.py)
        from placeloc.seqslam.descriptors import descriptor_difference

        return descriptor_difference(ref, query, comparison)
    if comparison == "zncc":
        return (1.0 - ref @ query.T).astype(np.float32)
    if comparison == "abs_zncc":
        return (1.0 - np.abs(ref @ query.T)).astype(np.float32)
    if comparison in ("isc", "isc_ext"):
        # Agreement count = (N + s.s') / 2 with s = 2b - 1: one BLAS product.
        nbits = ref.shape[1]
        s_ref = ref.astype(np.float32) * 2.0 - 1.0
        s_q = query.astype(np.float32) * 2.0 - 1.0
        agree = (nbits + s_ref @ s_q.T) * 0.5
        return (1.0 - agree / nbits).astype(np.float32)
    if comparison in ("ocm", "ocm_ext"):
        npx = ref.shape[1]
        out = np.empty((ref.shape[0], query.shape[0]), np.float32)
        qw = _ocm_onehot(query, weighted=True)
        step = max(1, int(2**27 // max(1, npx * OCM_CODES * 4)))  # ~128 MB of one-hot rows at a time
        for r0 in range(0, ref.shape[0], step):
            onehot = _ocm_onehot(ref[r0:r0 + step], weighted=False)
            out[r0:r0 + step] = 1.0 - (onehot @ qw.T) / npx
        return out
    raise ValueError(f"unknown comparison {comparison!r}; choose one of {', '.join(COMPARISONS)}")
