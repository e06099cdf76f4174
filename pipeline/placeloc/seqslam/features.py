"""Per-image features for SeqSLAM: read, shrink to a thumbnail, prepare for the comparison.

``extract_chunk`` is the unit of work the executor runs (in a worker process or inline):
a list of image paths in, feature rows and thumbnails out. Unreadable images are skipped
or raise, as the traverse's ``on_error`` says.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from placeloc.core.images import ImageError, read_gray
from placeloc.seqslam.comparisons import feature_dtype, prepare_many, thumbnail


def image_features(paths: list[str], *, on_error: str, thumbnail_size: tuple[int, int], comparison: str, patch: int,
                   normalisation: str, gaussian_sigma: float, ocm_epsilon: float,
                   ) -> tuple[np.ndarray, np.ndarray, list[int], list[str]]:
    """Features (n_ok, d), thumbnails (n_ok, h, w), the positions in ``paths`` that were
    read and the messages of those that could not be (``on_error == "skip"``; otherwise
    the first unreadable image raises :class:`ImageError`)."""
    def read(part: list[str]) -> list[np.ndarray | ImageError]:
        out: list[np.ndarray | ImageError] = []
        for path in part:
            try:
                out.append(thumbnail(read_gray(path), thumbnail_size))
            except ImageError as exc:
                out.append(exc)
        return out

    # Decoding releases the GIL: threads read the chunk on every core of this worker, one
    # contiguous part each (a task per image costs more in Python than a small PNG's decode).
    n_threads = max(1, min(8, os.cpu_count() or 1, len(paths)))
    parts = [paths[i * len(paths) // n_threads:(i + 1) * len(paths) // n_threads] for i in range(n_threads)]
    with ThreadPoolExecutor(max_workers=n_threads) as pool:
        results = [res for part in pool.map(read, parts) for res in part]
    thumbs, ok, errors = [], [], []
    for i, res in enumerate(results):
        if isinstance(res, ImageError):
            if on_error != "skip":
                raise res
            errors.append(str(res))
            continue
        thumbs.append(res)
        ok.append(i)
    w, h = thumbnail_size
    dtype = feature_dtype(comparison, normalisation)
    if not thumbs:
        return np.zeros((0, 0), dtype), np.zeros((0, h, w), np.uint8), ok, errors
    t = np.stack(thumbs)
    f = prepare_many(t, comparison=comparison, patch=patch, normalisation=normalisation,
                     gaussian_sigma=gaussian_sigma, ocm_epsilon=ocm_epsilon).astype(dtype, copy=False)
    return f, t, ok, errors


def extract_chunk(job: tuple[list[str], dict[str, Any], str]) -> tuple[np.ndarray, np.ndarray, list[int], list[str]]:
    """One work item: ``(paths, settings, on_error)`` -> :func:`image_features`. ``settings``
    holds :func:`image_features`' keyword arguments (a tuple keeps the job picklable and
    lets the executor name its first and last path when it fails)."""
    paths, settings, on_error = job
    return image_features(paths, on_error=on_error, **settings)
