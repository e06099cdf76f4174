"""What the compiled-kernel cache saves: SeqSLAM's four kernels (the two difference
kernels, the enhancement and the straight search) compiled in
memory against loaded from the (private, keyed) cache, each in a fresh process, several
times, with the ratio measured in the same run.

    python bench/bench_kernel_cache.py [repeats]
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile

CHILD = """
import os, sys, time
import llvmlite.binding  # the import is paid either way: not timed
from placeloc.seqslam import l1, row_kernels
def load():
    l1.kernel("l1_u8"); l1.kernel("l1_f32"); row_kernels.warm_up()
if sys.argv[1] == "cached":  # fill the cache in this process, then time loading from it
    load(); l1.kernel.cache_clear(); l1._compiled.cache_clear(); row_kernels._kernels.cache_clear()
t = time.perf_counter()
load()
print((time.perf_counter() - t) * 1000)
"""


def one(mode: str) -> float:
    with tempfile.TemporaryDirectory() as cache:
        out = subprocess.run([sys.executable, "-c", CHILD, mode], capture_output=True, text=True, check=True,
                             env={**os.environ, "XDG_CACHE_HOME": cache})
    return float(out.stdout.strip())


def main() -> None:
    repeats = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    times = {mode: [one(mode) for _ in range(repeats)] for mode in ("compile", "cached")}
    for mode, ms in times.items():
        print(f"{mode:8s} median {statistics.median(ms):6.1f} ms  range {min(ms):.1f}-{max(ms):.1f} ms  ({repeats} processes)")
    print(f"compile / cached: {statistics.median(times['compile']) / statistics.median(times['cached']):.0f}x")
    print(f"load average: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
