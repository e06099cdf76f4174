"""placeloc: appearance-based localization as a staged batch pipeline.

The package lives in ``pipeline/placeloc/`` (a src-style layout). The names
below come from :mod:`placeloc.api` and are imported on first use, so ``import placeloc``
stays cheap for the command line.
"""

from __future__ import annotations

import os
from typing import Any

from placeloc.core.caches import private_numba_cache

__version__ = "0.1.0"
__all__ = ["__version__", "describe", "load_config", "read_metrics", "run"]


# numba loads its cached machine code (and pickled indexes) unchecked: point it at a private
# folder before any placeloc module imports numba (docs/reliability.md, "Caches")
private_numba_cache()

# OpenMP's idle threads (numba's parallel kernels, faiss) sleep instead of spinning unless
# the user chose otherwise; it must be set before either loads libgomp. Spinning threads
# wait for a core another process needs: UMap's panorama search took 114-126 ms CPU a
# panorama with them and 77 ms without at load 2-2.7 on 2 cores (docs/umap.md), PIRF's
# m_t 16.1 ms against 5.3 ms a frame beside a busy process (docs/pirf.md, "Threads").
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# OpenBLAS's idle threads (NumPy's, SciPy's) spin 2**28 clock cycles, about 0.1 s, after
# their pool starts and after every BLAS call before they sleep; 2**20 (about 0.4 ms) keeps
# them ready for back-to-back calls. Read when NumPy loads OpenBLAS, so set before any
# placeloc module imports NumPy; a value the user set is kept. Every stage process spent
# 0.1-0.25 s more CPU on 2 cores without it (SeqSLAM extract 0.94-1.15 s against
# 0.72-0.77 s, evaluate 0.86-0.91 against 0.65-0.69 s at 3576 x 3576), CPU a process
# sharing the cores goes without; with one thread per core that spin is per core.
os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "20")


def __getattr__(name: str) -> Any:
    if name in ("describe", "load_config", "read_metrics", "run"):
        from placeloc import api

        return getattr(api, name)
    raise AttributeError(f"module 'placeloc' has no attribute {name!r}")
