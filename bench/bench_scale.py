"""Extraction throughput on a synthetic 20,000-image traverse: local workers 1, 2, 4, ..., nproc, and a 2-worker Dask LocalCluster.

    python bench/bench_scale.py                 # 20,000 images, 64x32 PNGs in a temp folder
    python bench/bench_scale.py --frames 2000   # quicker

The traverse is generated on the fly (a short synthetic route rendered once, its frames
reused with fresh pixel noise) and deleted afterwards. Each configuration runs SeqSLAM's
extract stage in its own process, so the peak RSS printed is that of the process that
writes extract.h5 (Dask/pool workers are separate processes and not counted in it).
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

sys.path.insert(0, str(Path(__file__).resolve().parent))
from scaling import worker_counts  # noqa: E402

CONFIGS = [  # label, executor section: the scaling table over local workers, then Dask
    *((f"local, {w} worker{'s' if w > 1 else ' (inline)'}", {"kind": "local", "workers": w}) for w in worker_counts()),
    ("dask LocalCluster, 2 workers", {"kind": "dask", "workers": 2, "scheduler": "local-cluster"}),
]


def make_traverse(out: Path, frames: int, width: int, height: int, seed: int = 0) -> Path:
    """Write ``frames`` PNGs: a 400-frame generated route, frames reused with Gaussian noise."""
    from placeloc.synth.route import generate

    base = out / "base"
    generate(base, seed=seed, frames=400, width=width, height=height)
    src = [cv2.imread(str(base / "reference" / f"frame{i}.png"), cv2.IMREAD_GRAYSCALE).astype(np.int16) for i in range(400)]
    rng = np.random.default_rng(seed)
    folder = out / "traverse"
    folder.mkdir()
    for i in range(frames):
        img = np.clip(src[i % len(src)] + rng.integers(-6, 7, src[0].shape), 0, 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"img{i:06d}.png"), img)
    shutil.rmtree(base)
    return folder


def child(folder: str, section: str, run_dir: str) -> None:
    """One configuration: run extract, print seconds and this (writing) process's peak RSS as JSON."""
    from placeloc.core.config import load_config
    from placeloc.core.runner import run_stage

    cfg = load_config(data={"method": "seqslam", "reference": {"images": folder}, "plots": False,
                            "seqslam": {"comparison": "sad", "thumbnail": [64, 32]},
                            "executor": json.loads(section)}, base_dir=folder)
    t0 = time.perf_counter()
    path = run_stage(cfg, run_dir, "extract", force=True, quiet=True)
    wall = time.perf_counter() - t0
    import h5py

    with h5py.File(path) as f:
        n = len(f["reference/features"])
        stage = float(f.attrs["seconds"])
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    print(json.dumps({"images": n, "stage_s": stage, "wall_s": wall, "peak_rss_mb": peak_mb}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=20000)
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--height", type=int, default=32)
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(*args.child)
        return
    try:
        import distributed  # noqa: F401

        configs = CONFIGS
    except ImportError:
        print("dask[distributed] is not installed (pip install 'placeloc[dask]'): the Dask row is left out")
        configs = CONFIGS[:-1]
    tmp = Path(tempfile.mkdtemp(prefix="placeloc-bench-scale-"))
    try:
        t0 = time.perf_counter()
        folder = make_traverse(tmp, args.frames, args.width, args.height)
        print(f"generated {args.frames} {args.width}x{args.height} PNGs in {time.perf_counter() - t0:.1f} s ({folder})")
        rows = []
        for label, section in configs:
            out = subprocess.run([sys.executable, __file__, "--child", str(folder), json.dumps(section), str(tmp / "run")],
                                 capture_output=True, text=True, check=False)
            if out.returncode != 0:
                sys.exit(f"{label} failed:\n{out.stderr[-3000:]}")
            r = json.loads(out.stdout.strip().splitlines()[-1])
            r["label"] = label
            rows.append(r)
            print(f"  {label}: {r['images'] / r['stage_s']:.0f} images/s", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    base = rows[0]["images"] / rows[0]["stage_s"]
    print()
    print(f"SeqSLAM extract (sad, 64x32 thumbnails), {rows[0]['images']} images of {args.width}x{args.height}")
    print(f"{'executor':32s} {'stage s':>8s} {'wall s':>8s} {'images/s':>9s} {'vs 1':>6s} {'writer peak RSS':>16s}")
    for r in rows:
        rate = r["images"] / r["stage_s"]
        print(f"{r['label']:32s} {r['stage_s']:8.1f} {r['wall_s']:8.1f} {rate:9.0f} {rate / base:5.2f}x {r['peak_rss_mb']:13.0f} MB")
    worst = max(r["peak_rss_mb"] for r in rows)
    print(f"stage s: the extract stage alone; wall s: also starting the pool/cluster. Peak RSS limit 2048 MB: "
          f"{'OK' if worst < 2048 else 'EXCEEDED'} (max {worst:.0f} MB)")
    if worst >= 2048:
        sys.exit(1)


if __name__ == "__main__":
    main()
