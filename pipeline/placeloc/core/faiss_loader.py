"""The one way placeloc loads faiss (an optional library several methods use).

A core module, so no method imports another for it (PIRF-nav2's indexes and retrieval's
flat index both load faiss here).
"""

from __future__ import annotations

from typing import Any


def import_faiss() -> Any:
    """faiss, with OpenMP's idle threads sleeping instead of spinning (``OMP_WAIT_POLICY``
    PASSIVE unless set already: ``placeloc/__init__.py`` sets it when placeloc is
    imported, before faiss or numba can load libgomp).

    One PIRF frame's m_t is ~100 queries, a few milliseconds. At 481k words, efSearch 24,
    two threads: 3.4 ms per frame spinning, 3.1 ms sleeping on an idle machine, but 16 ms
    spinning against 5.3 ms sleeping beside another busy process (one thread: 5.5-6.6 ms).
    """
    import faiss

    return faiss
