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


def farthest_point_landmarks(ids: np.ndarray, coords: np.ndarray, sightings: np.ndarray, n: int) -> np.ndarray:
    """The fixed landmark rule: farthest-point sampling on the known positions.

    Start from the most-seen point (``sightings`` per row; ties go to the smaller id), then
    repeatedly add the point farthest from those chosen (ties: smaller id). Uses only the
    known positions and the observation counts, never anything about the unknown points.
    Returns the chosen ids in the order chosen.
    """
    ids = np.asarray(ids, dtype=np.int64)
    coords = np.asarray(coords, dtype=np.float64)
    if n > len(ids):
        raise ObservationError(f"coembed.landmark_count is {n} but only {len(ids)} known points are observed")
    order = np.lexsort((ids, -np.asarray(sightings)))
    chosen = [int(order[0])]
    dist = np.linalg.norm(coords - coords[chosen[0]], axis=1)
    while len(chosen) < n:
        far = np.flatnonzero(dist == dist.max())
        nxt = int(far[np.argmin(ids[far])])
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(coords - coords[nxt], axis=1))
    return ids[chosen]


def landmark_warnings(coords: np.ndarray, dim: int) -> list[str]:
    """Plain-language warnings for landmark sets that leave the map poorly fixed (see :func:`landmark_warnings_by_cause`)."""
    return list(landmark_warnings_by_cause(coords, dim).values())


def landmark_warnings_by_cause(coords: np.ndarray, dim: int) -> dict[str, str]:
    """The warnings keyed by their cause (``too-few``, ``clustered``), so that a caller running many sets can report each once.

    - fewer than 2 (dim + 1): one bad landmark already decides the frame, and leave-one-out
      cross-validation has little to go on;
    - clustered: the landmarks' spread along their thinnest direction is under 5 % of the
      widest (nearly on a line or plane), so the map is extrapolated across that direction.
    """
    coords = np.asarray(coords, dtype=np.float64)[:, :dim]
    out: dict[str, str] = {}
    n = len(coords)
    if n < 2 * (dim + 1):
        out["too-few"] = (f"only {n} landmarks for a {dim}-D map: {dim + 1} fix the frame exactly and nothing is left to check it; "
                          f"give at least {2 * (dim + 1)}")
    if n >= 2:
        sv = np.linalg.svd(coords - coords.mean(axis=0), compute_uv=False)
        if sv[0] > 0 and (len(sv) < dim or sv[dim - 1] < 0.05 * sv[0]):
            ratio = 0.0 if len(sv) < dim else sv[dim - 1] / sv[0]
            out["clustered"] = (f"the landmarks are clustered: their thinnest spread is {ratio:.1%} of their widest, so points away "
                                "from that line/plane are extrapolated; add landmarks spread in every direction")
    return out
