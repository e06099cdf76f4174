"""A synthetic route pair for SeqSLAM: the same street driven twice, the second time at
another speed and under very different light, with exact ground truth.

The world is a long street panorama in two parallax layers (a far skyline that moves at
half speed and a near layer of trees, poles, walls and road marks). A frame is the
camera window at a position along the street. The reference traverse moves at a constant
step; the query traverse moves at a speed that wanders in [0.8, 1.2] of it, with a small
vertical jitter, sensor noise and blur, and its light is changed three ways: a global
gain/gamma change (overcast), local shadows fixed in the world (so each place gets its
own), and a night segment where the image is contrast-inverted (lit windows and street
lights bright on dark) as day/night does to appearance.

Ground truth: query j is correct for every reference whose position is within
``tolerance`` reference steps of the query's position (``ground_truth.csv`` as
``query,ref_first,ref_last``); positions are in ``poses_*.csv``.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml


def _far_layer(rng: np.random.Generator, length: int, height: int) -> np.ndarray:
    img = np.zeros((height, length), np.float32)
    sky = np.linspace(200, 150, height)[:, None]
    img[:] = sky
    x = 0
    while x < length:
        w = int(rng.integers(12, 60))
        top = int(rng.integers(height // 8, max(height // 2, height // 8 + 1)))  # a non-empty range at any height
        shade = float(rng.uniform(60, 140))
        img[top:, x:x + w] = shade
        # windows: a regular grid, some lit
        for wy in range(top + 4, height - 6, 7):
            for wx in range(x + 3, x + w - 4, 6):
                if rng.random() < 0.6:
                    img[wy:wy + 3, wx:wx + 3] = shade + float(rng.uniform(-50, 60))
        x += w + int(rng.integers(0, 8))
    return img


def _near_layer(rng: np.random.Generator, length: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Near objects as (image, alpha)."""
    img = np.zeros((height, length), np.float32)
    alpha = np.zeros((height, length), np.float32)
    ground = int(height * 0.72)
    img[ground:] = 90
    alpha[ground:] = 1
    for x in range(0, length, 40):  # lane marks
        img[height - 6:height - 3, x:x + 18] = 220
    x = int(rng.integers(0, 30))
    while x < length:
        kind = rng.random()
        if kind < 0.45:  # tree: trunk + textured crown
            cx, r = x, int(rng.integers(10, 22))
            cy = ground - int(rng.integers(25, 45))
            img[cy:ground, cx - 2:cx + 2] = 50
            alpha[cy:ground, cx - 2:cx + 2] = 1
            crown = np.zeros_like(img)
            cv2.circle(crown, (cx, cy), r, 1.0, -1)
            tex = rng.uniform(30, 110, size=img.shape).astype(np.float32)
            tex = cv2.GaussianBlur(tex, (0, 0), 1.5)
            m = crown > 0
            img[m] = tex[m]
            alpha[m] = 1
        elif kind < 0.7:  # pole with a sign
            top = ground - int(rng.integers(35, 60))
            img[top:ground, x:x + 2] = 40
            alpha[top:ground, x:x + 2] = 1
            sw = int(rng.integers(8, 16))
            img[top:top + 8, x - sw // 2:x + sw // 2] = float(rng.choice([30, 230]))
            alpha[top:top + 8, x - sw // 2:x + sw // 2] = 1
        else:  # garden wall with bricks
            w = int(rng.integers(20, 50))
            h = int(rng.integers(8, 18))
            wall = float(rng.uniform(110, 180))
            img[ground - h:ground, x:x + w] = wall
            img[ground - h:ground:4, x:x + w] = wall - 40
            alpha[ground - h:ground, x:x + w] = 1
        x += int(rng.integers(18, 55))
    return img, alpha


def _shadows(rng: np.random.Generator, length: int, height: int, count: int) -> np.ndarray:
    """Multiplicative shadow map fixed in the world (values in [0.35, 1])."""
    s = np.ones((height, length), np.float32)
    for _ in range(count):
        cx = int(rng.integers(0, length))
        w = int(rng.integers(20, 90))
        pts = np.array([[cx, int(rng.integers(0, height))], [cx + w, int(rng.integers(0, height))],
                        [cx + w + int(rng.integers(-20, 20)), height], [cx - int(rng.integers(0, 30)), height]], np.int32)
        cv2.fillPoly(s, [pts], float(rng.uniform(0.35, 0.6)))
    return cv2.GaussianBlur(s, (0, 0), 3)


def render(far: np.ndarray, near: np.ndarray, alpha: np.ndarray, x: float, width: int, dy: int = 0) -> np.ndarray:
    """Camera window at position ``x`` (near-layer pixels); the far layer moves at half speed."""
    h = near.shape[0]
    xf = x * 0.5
    m_near = np.float32([[1, 0, -x], [0, 1, -dy]])
    m_far = np.float32([[1, 0, -xf], [0, 1, -dy]])
    a = cv2.warpAffine(alpha, m_near, (width, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    n = cv2.warpAffine(near, m_near, (width, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    f = cv2.warpAffine(far, m_far, (width, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return a * n + (1 - a) * f


def generate(out_dir: Path, seed: int = 0, frames: int = 200, width: int = 128, height: int = 64, step: float = 6.0,
             tolerance: int = 2, night_fraction: float = 0.25, shadows: int | None = None, **unknown: Any) -> dict[str, Any]:
    """Write ``reference/``, ``query/``, ``ground_truth.csv``, poses and a ready ``config.yaml``."""
    if unknown:
        raise TypeError(f"unknown route parameter(s) {', '.join(unknown)}; known: frames, width, height, step, "
                        "tolerance, night_fraction, shadows")
    if frames < 10:
        raise ValueError("frames must be >= 10")
    out_dir = Path(out_dir)
    rng = np.random.default_rng(seed)
    length = int(frames * step + width + 64)
    far = _far_layer(rng, length, height)
    near, alpha = _near_layer(rng, length + 4 * width, height)
    shadow = _shadows(rng, length + 4 * width, height, shadows if shadows is not None else max(4, frames // 6))

    ref_x = np.arange(frames) * step
    # Query speed wanders smoothly within [0.8, 1.2] of the reference step.
    speed = 1.0 + 0.2 * np.sin(np.linspace(0, 3 * np.pi, frames) + rng.uniform(0, np.pi))
    q_x = np.concatenate([[0.0], np.cumsum(speed * step)])
    q_x = q_x[q_x <= ref_x[-1]]

    for sub in ("reference", "query"):
        (out_dir / sub).mkdir(parents=True, exist_ok=True)
    for i, x in enumerate(ref_x):
        img = render(far, near, alpha, x, width)
        cv2.imwrite(str(out_dir / "reference" / f"frame{i}.png"), np.clip(img, 0, 255).astype(np.uint8))

    n_q = len(q_x)
    night_len = int(round(night_fraction * n_q))
    night_start = int(rng.integers(n_q // 4, max(n_q // 4 + 1, n_q - night_len))) if night_len else n_q
    gain, gamma = 0.75, 1.3
    for j, x in enumerate(q_x):
        dy = int(rng.integers(-1, 2))
        img = render(far, near, alpha, x, width, dy)
        shade = render(np.ones_like(far), shadow, np.ones_like(shadow), x, width, dy)
        img = 255.0 * (np.clip(img, 0, 255) / 255.0) ** gamma * gain
        if night_start <= j < night_start + night_len:
            img = 0.8 * (255.0 - img)  # contrast inversion: dark sky, bright structures
        else:
            img = img * shade
        img = cv2.GaussianBlur(img, (0, 0), 0.7) + rng.normal(0, 4.0, img.shape)
        cv2.imwrite(str(out_dir / "query" / f"frame{j}.png"), np.clip(img, 0, 255).astype(np.uint8))

    with (out_dir / "ground_truth.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["query", "ref_first", "ref_last"])
        for j, x in enumerate(q_x):
            lo = int(np.ceil(x / step - tolerance - 1e-9))
            hi = int(np.floor(x / step + tolerance + 1e-9))
            w.writerow([j, max(0, lo), min(frames - 1, hi)])
    for name, xs in (("poses_reference.csv", ref_x), ("poses_query.csv", q_x)):
        with (out_dir / name).open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["frame", "position_px"])
            w.writerows([[i, f"{x:.3f}"] for i, x in enumerate(xs)])
    config = {
        "method": "seqslam",
        "reference": {"images": "reference"},
        "query": {"images": "query"},
        "ground_truth": {"kind": "csv", "path": "ground_truth.csv"},
        "seqslam": {"comparison": "sad", "thumbnail": [64, 32]},
    }
    (out_dir / "config.yaml").write_text("# generated by placeloc synth route\n" + yaml.safe_dump(config, sort_keys=False))
    return {"out": str(out_dir), "reference_frames": frames, "query_frames": n_q,
            "night_frames": f"{night_start}..{night_start + night_len - 1}" if night_len else "none",
            "config": str(out_dir / "config.yaml")}
