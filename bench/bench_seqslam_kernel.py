"""The flexible search's compiled kernel alone: CPU per anchor at the Nordland preset's shape.

    python bench/bench_seqslam_kernel.py                        # this tree's kernel
    python bench/bench_seqslam_kernel.py --against OLD/flexible.py   # and another version's, alternating

``flexible_rows`` (``seqslam/flexible.py``) scores ``--anchors`` consecutive anchors of a
random matrix (``--references`` wide, Gaussian values around 4, as enhanced differences
are) with the preset's window (ds 120, centred: segments of 10 frames) for the forward
family (0.3-4.0 in steps of 0.1: 38 speeds) and ``backward_paths``' family (up to 1.5: 13
speeds), on one core (this process pinned to its first allowed CPU), CPU seconds by
``time.process_time``. With ``--against``, a copy of another version of the module (for
instance ``git show BASE:pipeline/placeloc/seqslam/flexible.py > /tmp/old_flexible.py``)
runs the same calls, alternating with this tree's, and every score of the two is compared
bit for bit. Prints milliseconds per anchor, run by run, and the load average.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import time
from pathlib import Path
from types import ModuleType

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "pipeline"))

from placeloc.seqslam import flexible  # noqa: E402
from placeloc.seqslam.search import (  # noqa: E402
    backward_velocities,
    flexible_model,
    query_offsets,
    trajectory_offsets,
    velocities,
)


def load(path: str) -> ModuleType:
    """Another version of ``seqslam/flexible.py``, imported by its file's name from its
    folder (numba's cache imports it again by that name)."""
    file = Path(path).resolve()
    if file.suffix != ".py" or not file.is_file():
        raise SystemExit(f"{path}: not a Python file; give the path of a copy of seqslam/flexible.py")
    sys.path.insert(0, str(file.parent))
    return importlib.import_module(file.stem)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--anchors", type=int, default=512, help="consecutive anchors a call scores (one chunk)")
    ap.add_argument("--references", type=int, default=3576)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--against", default=None, help="a copy of another version of seqslam/flexible.py")
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    kernels = [("this tree", flexible)] + ([("against", load(args.against))] if args.against else [])
    rng = np.random.default_rng(0)
    t_off = query_offsets(120, "centred")
    n = args.anchors
    et = (rng.normal(0, 1, (n + len(t_off), args.references)) + 4).astype(np.float32)
    forward = velocities(0.3, 4.0, 0.1)
    a, b = -int(t_off[0]), -int(t_off[0]) + n
    load0 = os.getloadavg()[0]
    for family, vels in (("forward, 38 speeds", forward), ("backward, 13 speeds", backward_velocities(forward, 1.5))):
        seg, v, _, bend, before, after = flexible_model(et, t_off, vels, 1.0, None)
        offs = np.ascontiguousarray(trajectory_offsets(v, np.arange(min(seg, max(before, after) + 1) + 1)))
        steps = np.array([np.float32(bend * (v[i + 1] - v[i])) for i in range(len(v) - 1)], np.float32)
        scores = {}
        for _ in range(args.repeat):
            for name, kernel in kernels:
                s = np.empty((n, args.references), np.float32)
                kernel.flexible_rows(et, et, et, np.zeros(1), False, a, a + 1, seg, before, after, v, offs, steps, 0.0,
                                     0.0, s[:1], 4096)  # loads the machine code
                c0 = time.process_time()
                kernel.flexible_rows(et, et, et, np.zeros(1), False, a, b, seg, before, after, v, offs, steps, 0.0,
                                     0.0, s, 4096)
                ms = 1000 * (time.process_time() - c0) / n
                print(f"{family:20s} {name:10s} {ms:.3f} ms an anchor, load {os.getloadavg()[0]:.1f}", flush=True)
                scores[name] = s
        if len(scores) == 2:
            print(f"{family:20s} scores bit-identical: {np.array_equal(scores['this tree'], scores['against'])}")
    print(f"load average (1 min) before/after {load0:.1f} / {os.getloadavg()[0]:.1f}; {n} anchors, "
          f"{args.references} references, one core")


if __name__ == "__main__":
    main()
