"""The simulated world of Nakamura and Yairi, "Experimental Study on Mapping by Dimensionality Reduction" (sec. 3, fig. 3): "ABCD".

A 20 m x 20 m square with N = 200 point features: 100 spell "ABCD" (25 per letter, evenly
spaced along the strokes), 100 are uniform at random; 11 of the random ones, spread by
farthest-point sampling, are landmarks with known positions. A robot drives like the
paper's Pioneer: straight runs at ``speed`` m/step between random waypoints and turns on
the spot at ``turn_rate`` rad/step. It sees the features within ``max_range`` (8 m) and within its forward field of view (180 degrees).
Two sensors: bearing only (radians, left positive) and range only (metres), each with
Gaussian noise.

Files written: features.csv (feature,x,y,letter,landmark), landmarks.csv (feature,x,y),
poses.csv (t,x,y,heading), obs_bearing.csv and obs_range.csv (t,feature,value), and the
ready-to-run configs bearing.yaml and range.yaml.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

WORLD = 20.0


def _letter_strokes() -> list[list[np.ndarray]]:
    """Polylines of A, B, C, D in a 4 m x 6 m cell (origin at the cell's lower left)."""
    def arc(cx: float, cy: float, r: float, a0: float, a1: float, k: int = 24) -> np.ndarray:
        a = np.linspace(a0, a1, k)
        return np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)])

    a_strokes = [np.array([[0, 0], [2, 6], [4, 0]], float), np.array([[0.67, 2], [3.33, 2]], float)]
    b_strokes = [np.array([[0, 0], [0, 6]], float),
                 np.vstack([[0, 6], [2.5, 6], arc(2.5, 4.5, 1.5, np.pi / 2, -np.pi / 2)[1:], [0, 3]]),
                 np.vstack([[0, 3], [2.5, 3], arc(2.5, 1.5, 1.5, np.pi / 2, -np.pi / 2)[1:], [0, 0]])]
    c_strokes = [arc(3.0, 3.0, 3.0, np.deg2rad(60), np.deg2rad(300), 48) - [1.0, 0]]
    d_strokes = [np.array([[0, 0], [0, 6]], float), np.vstack([[0, 6], [1, 6], arc(1, 3, 3, np.pi / 2, -np.pi / 2, 48)[1:], [0, 0]])]
    return [a_strokes, b_strokes, c_strokes, d_strokes]


def _sample_polylines(lines: list[np.ndarray], count: int) -> np.ndarray:
    """``count`` points evenly spaced by arc length over a set of polylines."""
    segs = np.vstack([np.hstack([p[:-1], p[1:]]) for p in lines])
    lengths = np.linalg.norm(segs[:, 2:] - segs[:, :2], axis=1)
    cum = np.concatenate([[0], np.cumsum(lengths)])
    s = (np.arange(count) + 0.5) / count * cum[-1]
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(segs) - 1)
    f = ((s - cum[k]) / np.maximum(lengths[k], 1e-12))[:, None]
    return segs[k, :2] + f * (segs[k, 2:] - segs[k, :2])


def abcd_features(rng: np.random.Generator, n_features: int = 200, n_letter: int = 100,
                  n_landmarks: int = 11) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions (N, 2), letter flags, landmark flags."""
    if n_letter % 4 or n_letter > n_features:
        raise ValueError("letter features must be a multiple of 4 and at most n_features")
    if n_landmarks > n_features - n_letter:
        raise ValueError("landmarks are drawn from the non-letter features: n_landmarks <= n_features - n_letter")
    pts = []
    for j, strokes in enumerate(_letter_strokes()):
        # Letters side by side across the middle: cells at x = 1, 5.5, 10, 14.5 ... (4 m wide, 0.5 m gaps)
        pts.append(_sample_polylines(strokes, n_letter // 4) + [1.0 + 4.75 * j, 7.0])
    letters = np.vstack(pts) if n_letter else np.zeros((0, 2))
    others = rng.uniform(0.0, WORLD, (n_features - n_letter, 2))
    xy = np.vstack([letters, others])
    letter = np.zeros(n_features, bool)
    letter[:n_letter] = True
    landmark = np.zeros(n_features, bool)
    if n_landmarks:
        # Farthest-point sampling: landmarks spread over the square, as in fig. 3.
        cand = np.arange(n_letter, n_features)
        chosen = [cand[np.argmin(np.linalg.norm(xy[cand], axis=1))]]
        dist = np.linalg.norm(xy[cand] - xy[chosen[0]], axis=1)
        for _ in range(n_landmarks - 1):
            nxt = cand[np.argmax(dist)]
            chosen.append(nxt)
            dist = np.minimum(dist, np.linalg.norm(xy[cand] - xy[nxt], axis=1))
        landmark[chosen] = True
    return xy, letter, landmark


def robot_path(rng: np.random.Generator, steps: int, speed: float = 0.1, turn_rate: float = np.deg2rad(5.0),
               margin: float = 1.0) -> np.ndarray:
    """(steps, 3) poses x, y, heading: straight runs and turns on the spot.

    The robot picks a waypoint uniformly in the square (inside ``margin``), turns on the spot
    toward it at ``turn_rate`` and drives straight to it at ``speed``; waypoints spread the
    runs over the whole square, so every feature is seen from several places.
    """
    poses = np.empty((steps, 3))
    x, y = rng.uniform(margin, WORLD - margin, 2)
    th = rng.uniform(-np.pi, np.pi)
    goal = rng.uniform(margin, WORLD - margin, 2)
    for t in range(steps):
        poses[t] = (x, y, th)
        dx, dy = goal[0] - x, goal[1] - y
        dist = np.hypot(dx, dy)
        if dist < speed:
            goal = rng.uniform(margin, WORLD - margin, 2)
            continue
        turn = (np.arctan2(dy, dx) - th + np.pi) % (2 * np.pi) - np.pi
        if abs(turn) > 1e-9:
            th = (th + np.sign(turn) * min(turn_rate, abs(turn)) + np.pi) % (2 * np.pi) - np.pi
            continue
        x, y = x + speed * np.cos(th), y + speed * np.sin(th)
    return poses


def observe(poses: np.ndarray, xy: np.ndarray, max_range: float = 8.0, fov: float = np.pi) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Visible (t, feature) pairs with their true bearing and range."""
    dx = xy[None, :, 0] - poses[:, None, 0]
    dy = xy[None, :, 1] - poses[:, None, 1]
    rng_ = np.hypot(dx, dy)
    bearing = (np.arctan2(dy, dx) - poses[:, None, 2] + np.pi) % (2 * np.pi) - np.pi
    vis = (rng_ <= max_range) & (np.abs(bearing) <= fov / 2)
    t, i = np.nonzero(vis)
    return t, i, bearing[t, i], rng_[t, i]


def _write_csv(path: Path, header: str, cols: list[np.ndarray], fmts: list[str]) -> None:
    data = np.column_stack(cols)
    np.savetxt(path, data, delimiter=",", header=header, comments="", fmt=fmts)


def generate(out_dir: Path, seed: int = 0, steps: int = 2000, n_features: int = 200, n_letter: int = 100, n_landmarks: int = 11,
             max_range: float = 8.0, fov_deg: float = 180.0, bearing_noise: float = 0.01, range_noise: float = 0.05,
             speed: float = 0.1, turn_rate_deg: float = 5.0, pose_label_every: int = 50, **unknown: Any) -> dict[str, Any]:
    """Write the ABCD world and both sensors' observations; returns a summary.

    Noise levels are standard deviations: ``bearing_noise`` in radians, ``range_noise`` in metres.
    """
    if unknown:
        raise TypeError(f"unknown parameter(s) {sorted(unknown)} for synth coembed")
    if steps < 2:
        raise ValueError("steps must be >= 2")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    xy, letter, landmark = abcd_features(rng, n_features, n_letter, n_landmarks)
    # ``steps`` is a minimum: the drive goes on (up to 4x) until every feature has been seen once,
    # so that no landmark or letter feature is missing from the map for lack of coverage.
    poses = robot_path(rng, 4 * steps, speed, np.deg2rad(turn_rate_deg))
    t, i, bearing, dist = observe(poses, xy, max_range, np.deg2rad(fov_deg))
    first = np.full(n_features, len(poses))
    np.minimum.at(first, i, t)
    steps = int(max(steps, min(first.max() + 1, len(poses))))
    keep = t < steps
    poses, t, i, bearing, dist = poses[:steps], t[keep], i[keep], bearing[keep], dist[keep]
    bearing_obs = bearing + rng.normal(0.0, bearing_noise, len(t))
    range_obs = dist + rng.normal(0.0, range_noise, len(t))
    ids = np.arange(n_features)
    _write_csv(out_dir / "features.csv", "feature,x,y,letter,landmark", [ids, xy, letter, landmark], ["%d", "%.6f", "%.6f", "%d", "%d"])
    _write_csv(out_dir / "landmarks.csv", "feature,x,y", [ids[landmark], xy[landmark]], ["%d", "%.6f", "%.6f"])
    _write_csv(out_dir / "poses.csv", "t,x,y,heading", [np.arange(steps), poses], ["%d", "%.6f", "%.6f", "%.6f"])
    _write_csv(out_dir / "obs_bearing.csv", "t,feature,bearing", [t, i, bearing_obs], ["%d", "%d", "%.8f"])
    _write_csv(out_dir / "obs_range.csv", "t,feature,range", [t, i, range_obs], ["%d", "%d", "%.8f"])
    for sensor in ("bearing", "range"):
        cfg = {"method": "coembed", "seed": seed,
               "coembed": {"source": "csv", "observations": f"obs_{sensor}.csv", "landmarks": "landmarks.csv",
                           "truth": "features.csv", "poses": "poses.csv", "pose_label_every": pose_label_every}}
        (out_dir / f"{sensor}.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    seen = np.unique(i)
    return {"out_dir": str(out_dir), "steps": steps, "features": n_features, "landmarks": int(landmark.sum()),
            "observations": len(t), "fill": round(len(t) / (steps * n_features), 4),
            "unobserved_features": int(n_features - len(seen)), "configs": "bearing.yaml, range.yaml"}
