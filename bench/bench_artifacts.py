"""Cost of writing artifacts through placeloc's guarded file (full-disk safety) vs plain h5py.

    python bench/bench_artifacts.py [--reps 3]

Writes the same 56 MB artifact (a chunked, compressed uint8 table appended in blocks, as
SeqSLAM's extract does, and one float32 matrix) with plain ``h5py.File(path, "w")`` (the
sec2 driver) and with :func:`placeloc.core.artifacts.atomic_h5`, which writes through a Python
file object so that a full disk never reaches HDF5 as a failed deferred write. Prints the
median wall and CPU time of each and their ratio.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

from placeloc.core.artifacts import atomic_h5


def _work(f: h5py.File, table: np.ndarray, matrix: np.ndarray) -> None:
    d = f.create_dataset("table", shape=(0, table.shape[1]), maxshape=(None, table.shape[1]),
                         chunks=(256, table.shape[1]), compression="gzip", compression_opts=1, dtype=table.dtype)
    for i in range(0, len(table), 100):
        d.resize(i + 100, axis=0)
        d[i:i + 100] = table[i:i + 100]
    f.create_dataset("matrix", data=matrix)


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=3)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    table = rng.integers(0, 50, size=(4000, 8192), dtype=np.uint8)
    matrix = rng.random((4000, 2000)).astype(np.float32)
    with tempfile.TemporaryDirectory(prefix="placeloc-bench-") as tmp:
        path = Path(tmp) / "artifact.h5"
        times: dict[str, list[tuple[float, float]]] = {"plain h5py": [], "atomic_h5": []}
        for _ in range(args.reps):
            for name in times:
                t0, c0 = time.perf_counter(), _cpu()
                if name == "plain h5py":
                    with h5py.File(path, "w") as f:
                        _work(f, table, matrix)
                else:
                    with atomic_h5(path, {"stamp": "bench"}) as f:
                        _work(f, table, matrix)
                times[name].append((time.perf_counter() - t0, _cpu() - c0))
        size = os.path.getsize(path) / 1e6
    med = {k: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v)) for k, v in times.items()}
    print(f"artifact of {size:.0f} MB, median of {args.reps}")
    for k, (w, c) in med.items():
        print(f"  {k:11s} wall {w:6.2f} s  cpu {c:6.2f} s")
    print(f"  ratio atomic_h5 / plain: wall {med['atomic_h5'][0] / med['plain h5py'][0]:.2f}, "
          f"cpu {med['atomic_h5'][1] / med['plain h5py'][1]:.2f}")


if __name__ == "__main__":
    main()
