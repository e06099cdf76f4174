"""Which known points are landmarks: an explicit list, or a documented rule."""

from __future__ import annotations

import numpy as np
from placeloc.coembed.observations import ObservationError


def take_landmarks(ids: np.ndarray, coords: np.ndarray, want: tuple[int, ...] | list[int], source: str) -> tuple[np.ndarray, np.ndarray]:
    """The rows of (ids, coords) for the ids in ``want``, in that order; an unknown id is an error naming ``source``."""
    want_arr = np.asarray(want, dtype=np.int64)
    missing = want_arr[~np.isin(want_arr, ids)]
    if missing.size:
        raise ObservationError(f"coembed.landmark_ids {missing.tolist()} are not in {source}")
    row = {int(f): j for j, f in enumerate(ids)}
    sel = np.array([row[int(w)] for w in want_arr], dtype=np.int64)
    return ids[sel], coords[sel]
