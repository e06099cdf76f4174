"""placeloc: appearance-based localization as a staged batch pipeline.

The package lives in ``pipeline/placeloc/`` (a src-style layout). The names
below come from :mod:`placeloc.api` and are imported on first use, so ``import placeloc``
stays cheap for the command line.
"""

from __future__ import annotations

from typing import Any

from placeloc.core.caches import private_numba_cache

__version__ = "0.1.0"
__all__ = ["__version__", "describe", "load_config", "read_metrics", "run"]


# numba loads its cached machine code (and pickled indexes) unchecked: point it at a private
# folder before any placeloc module imports numba (docs/reliability.md, "Caches")
private_numba_cache()


def __getattr__(name: str) -> Any:
    if name in ("describe", "load_config", "read_metrics", "run"):
        from placeloc import api

        return getattr(api, name)
    raise AttributeError(f"module 'placeloc' has no attribute {name!r}")
