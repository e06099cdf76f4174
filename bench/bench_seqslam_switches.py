"""What SeqSLAM's two motion switches cost in localize, against straight trajectories.

    python bench/bench_seqslam_switches.py --frames 3576 --repeat 1

localize's numerics (``sequence_match``) with the settings of ``configs/nordland.yaml`` on
the rows of ``bench_seqslam_full.features`` (nordland-dev's features tiled with noise to
``--frames`` + ``--frames``), six ways, alternating so that all see the same load:
straight trajectories over the preset's speeds and window (switches off), the preset
without its two switches, without ``collapse_stops``, without ``backward_paths``, with
the whole backward family (``backward_v_max`` 4.0, the forward range), and as shipped
(both on, ``reverse_cost`` 0). Prints
wall and CPU seconds of each run, the medians and their ratios to straight trajectories
measured in the same run, and the load average before and after.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "pipeline"))
sys.path.insert(0, str(ROOT / "bench"))

from bench_seqslam_full import features  # noqa: E402

from placeloc.experiments.seqslam_motion import preset  # noqa: E402
from placeloc.seqslam.matching import sequence_match  # noqa: E402

KEYS = ("enhance_window", "ds", "v_min", "v_max", "v_step", "v_auto", "search", "sequence_shape", "edges", "top_k",
        "block_size", "speed_change_cost", "stop_cost", "reverse_cost", "collapse_stops", "backward_paths",
        "backward_v_max")
OFF = {"collapse_stops": False, "backward_paths": False}
SETTINGS = {"straight trajectories": {"sequence_shape": "trajectory", **OFF},
            "preset without the switches": OFF,
            "preset without collapse_stops": {"collapse_stops": False},
            "preset without backward_paths": {"backward_paths": False},
            "preset, whole backward family (backward_v_max 4.0)": {"backward_v_max": 4.0},
            "preset": {}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=3576, help="frames per traverse")
    ap.add_argument("--repeat", type=int, default=2, help="runs of each setting (the median is reported)")
    args = ap.parse_args()
    ref, query = features(args.frames)
    p = preset()
    runs: dict[str, list[tuple[float, float]]] = {name: [] for name in SETTINGS}
    load0 = os.getloadavg()
    for _ in range(args.repeat):
        for name, setting in SETTINGS.items():
            kw = {**{k: p[k] for k in KEYS}, **setting}
            c0, t0 = time.process_time(), time.perf_counter()
            sequence_match(ref, query, comparison=p["comparison"], exclude_recent=None, **kw)
            runs[name].append((time.perf_counter() - t0, time.process_time() - c0))
            print(f"{name:50s} {runs[name][-1][0]:.1f} s wall, {runs[name][-1][1]:.1f} s CPU, "
                  f"load {os.getloadavg()[0]:.1f}", flush=True)
    base = runs["straight trajectories"]
    bw, bc = float(np.median([r[0] for r in base])), float(np.median([r[1] for r in base]))
    for name, r in runs.items():
        w, c = float(np.median([x[0] for x in r])), float(np.median([x[1] for x in r]))
        print(f"{name}: median {w:.1f} s wall, {c:.1f} s CPU; / straight trajectories: wall {w / bw:.2f}x, "
              f"CPU {c / bc:.2f}x")
    load1 = os.getloadavg()
    print(f"load average (1 min) before/after {load0[0]:.1f} / {load1[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
