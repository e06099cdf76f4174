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


def generate(out_dir: Path, seed: int = 0, world: str = "abcd", **params: Any) -> dict[str, Any]:
    """``world`` abcd: the paper's simulated world (:func:`generate_abcd`); camera: a perspective camera track
    with lens distortion (:func:`generate_camera`)."""
    if world == "abcd":
        return generate_abcd(out_dir, seed=seed, **params)
    if world == "camera":
        return generate_camera(out_dir, seed=seed, **params)
    raise ValueError(f"synth coembed: world must be abcd or camera, got {world!r}")


def generate_abcd(out_dir: Path, seed: int = 0, steps: int = 2000, n_features: int = 200, n_letter: int = 100, n_landmarks: int = 11,
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


def _rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """World-to-camera rotation for a camera looking along +Z, turned by yaw (about Y), pitch (X), roll (Z)."""
    cy, sy, cp, sp_, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cp, -sp_], [0, sp_, cp]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return (rz @ rx @ ry).T


def distort(xn: np.ndarray, k1: float, k2: float, k3: float, p1: float, p2: float) -> np.ndarray:
    """OpenCV's lens model on normalised coordinates (n, 2): radial k1..k3, tangential p1, p2."""
    x, y = xn[:, 0], xn[:, 1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    return np.column_stack([x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y])


def generate_camera(out_dir: Path, seed: int = 0, frames: int = 300, n_near: int = 30, n_far: int = 6, sideways: float = 1.7,
                    pan_deg: float = 4.0, focal: float = 2500.0, width: int = 2048, height: int = 1080, k1: float = -0.12,
                    k2: float = 0.03, noise_px: float = 0.7, min_track: int = 30, **unknown: Any) -> dict[str, Any]:
    """A perspective camera track of the kind film tracking gives, with a known answer.

    The camera looks along +Z and moves ``sideways`` metres along X over ``frames`` frames
    (with a slight forward drift and a pan of ``pan_deg``), past ``n_near`` points 5-9 m away
    and ``n_far`` points 20-50 m away. Each point is tracked over a random part of the frames
    where it is in view (at least ``min_track`` frames), as a tracker loses and finds points.
    Pixels carry radial distortion (OpenCV's k1, k2) and Gaussian noise of ``noise_px``.

    Files as in the tears-of-steel folder: markers.csv (image,track,x,y), points.csv
    (track,X,Y,Z), cameras.csv (image, R row-major, t; x_cam = R X + t), intrinsics.csv
    (problem,f,cx,cy,k1,k2,k3,p1,p2), and camera.yaml (co-embedding, 10 landmarks by the fixed rule).
    """
    if unknown:
        raise TypeError(f"unknown parameter(s) {sorted(unknown)} for synth coembed world=camera")
    if frames < min_track or n_near + n_far < 8:
        raise ValueError("synth coembed world=camera needs frames >= min_track and at least 8 points")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    near = np.column_stack([rng.uniform(-2.0, 2.0 + sideways, n_near), rng.uniform(-1.0, 1.0, n_near), rng.uniform(5.0, 9.0, n_near)])
    zf = rng.uniform(20.0, 50.0, n_far)
    far = np.column_stack([rng.uniform(-0.15, 0.15, n_far) * zf + sideways / 2, rng.uniform(-0.08, 0.08, n_far) * zf, zf])
    pts = np.vstack([near, far])
    s = np.linspace(0.0, 1.0, frames)
    centres = np.column_stack([sideways * s, 0.02 * np.sin(3 * s), 0.3 * s])
    rots = np.stack([_rotation(np.deg2rad(pan_deg) * (s_ - 0.5), 0.01 * np.sin(5 * s_), 0.005 * s_) for s_ in s])
    tvecs = -np.einsum("mab,mb->ma", rots, centres)
    cam = np.einsum("mab,nb->mna", rots, pts) + tvecs[:, None, :]          # (frames, points, 3)
    xn = cam[..., :2] / cam[..., 2:3]
    px = distort(xn.reshape(-1, 2), k1, k2, 0.0, 0.0, 0.0).reshape(xn.shape) * focal + [width / 2, height / 2]
    inside = (cam[..., 2] > 0.1) & (px[..., 0] >= 0) & (px[..., 0] < width) & (px[..., 1] >= 0) & (px[..., 1] < height)
    rows = []
    for j in range(len(pts)):
        seen = np.flatnonzero(inside[:, j])
        if len(seen) < min_track:
            continue
        length = int(rng.integers(min_track, len(seen) + 1))
        start = int(rng.integers(0, len(seen) - length + 1))
        for t in seen[start:start + length]:
            rows.append((t + 1, j, *(px[t, j] + rng.normal(0.0, noise_px, 2))))
    obs = np.array(rows)
    tracks = np.unique(obs[:, 1]).astype(int)
    _write_csv(out_dir / "markers.csv", "image,track,x,y", [obs[:, 0], obs[:, 1], obs[:, 2:]], ["%d", "%d", "%.4f", "%.4f"])
    _write_csv(out_dir / "points.csv", "track,X,Y,Z", [tracks, pts[tracks]], ["%d", "%.6f", "%.6f", "%.6f"])
    _write_csv(out_dir / "cameras.csv", "image," + ",".join(f"R{a}{b}" for a in range(3) for b in range(3)) + ",tx,ty,tz",
               [np.arange(1, frames + 1), rots.reshape(frames, 9), tvecs], ["%d"] + ["%.9f"] * 12)
    _write_csv(out_dir / "intrinsics.csv", "problem,f,cx,cy,k1,k2,k3,p1,p2",
               [np.array([[1, focal, width / 2, height / 2, k1, k2, 0.0, 0.0, 0.0]])], ["%d"] + ["%.6f"] * 8)
    cfg = {"method": "coembed", "seed": seed,
           "coembed": {"source": "csv", "observations": "markers.csv", "intrinsics": "intrinsics.csv", "landmarks": "points.csv",
                       "landmark_count": 10, "truth": "points.csv", "dim": 3, "camera_model": "pinhole"}}
    (out_dir / "camera.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    return {"out_dir": str(out_dir), "frames": frames, "tracks": len(tracks), "observations": len(obs),
            "fill": round(len(obs) / (frames * len(tracks)), 4), "config": "camera.yaml"}
