"""Per-image features for SeqSLAM: shrink to a thumbnail, prepare for the comparison.

The engine (:mod:`placeloc.core.imagework`) reads the images and calls
:func:`thumbnail_arrays` on each, then :func:`feature_rows` once per chunk on the stacked
thumbnails (the comparisons' preparation is vectorised over a stack, and treats each
thumbnail on its own, so a chunk's cut never changes a row).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from placeloc.core.imagework import ImageWork, describe_chunk, worker_threads
from placeloc.seqslam.comparisons import feature_dtype, prepare_many, thumbnail


def thumbnail_arrays(image: np.ndarray, *, thumbnail_size: tuple[int, int], **_prepare: Any) -> dict[str, np.ndarray]:
    """One greyscale image -> its ``thumbnails`` row (h, w) uint8, area-averaged."""
    return {"thumbnails": thumbnail(image, thumbnail_size)}


def feature_rows(arrays: dict[str, np.ndarray], *, comparison: str, patch: int, normalisation: str,
                 gaussian_sigma: float, ocm_epsilon: float, **_size: Any) -> dict[str, np.ndarray]:
    """Stacked thumbnails (n, h, w) -> the ``features`` (n, d) the comparison works on."""
    f = prepare_many(arrays["thumbnails"], comparison=comparison, patch=patch, normalisation=normalisation,
                     gaussian_sigma=gaussian_sigma, ocm_epsilon=ocm_epsilon)
    return {"features": f.astype(feature_dtype(comparison, normalisation), copy=False)}


def feature_work(*, thumbnail_size: tuple[int, int], comparison: str, patch: int, normalisation: str,
                 gaussian_sigma: float, ocm_epsilon: float, images_per_task: int | None = None) -> ImageWork:
    """SeqSLAM's per-image work for the engine."""
    settings = {"thumbnail_size": (int(thumbnail_size[0]), int(thumbnail_size[1])), "comparison": comparison,
                "patch": int(patch), "normalisation": normalisation, "gaussian_sigma": float(gaussian_sigma),
                "ocm_epsilon": float(ocm_epsilon)}
    return ImageWork(fn=thumbnail_arrays, settings=settings, batch=feature_rows, images_per_task=images_per_task)


def image_features(paths: list[str], *, on_error: str, thumbnail_size: tuple[int, int], comparison: str, patch: int,
                   normalisation: str, gaussian_sigma: float, ocm_epsilon: float,
                   ) -> tuple[np.ndarray, np.ndarray, list[int], list[str]]:
    """Features (n_ok, d), thumbnails (n_ok, h, w), the positions in ``paths`` that were
    read and the messages of those that could not be (``on_error == "skip"``; otherwise
    the first unreadable image raises :class:`ImageError`), in this process (for
    experiments that need the rows of a few frames without a run)."""

    work = feature_work(thumbnail_size=thumbnail_size, comparison=comparison, patch=patch, normalisation=normalisation,
                        gaussian_sigma=gaussian_sigma, ocm_epsilon=ocm_epsilon)
    res = describe_chunk((list(paths), work, on_error == "skip", worker_threads(None, str(paths[0]) if len(paths) else None)))
    w, h = thumbnail_size
    if not res.kept:
        return np.zeros((0, 0), feature_dtype(comparison, normalisation)), np.zeros((0, h, w), np.uint8), [], []
    return res.fixed["features"], res.fixed["thumbnails"], res.kept, [m for _, m in res.errors]
