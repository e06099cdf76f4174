"""The co-embedding map figure (the paper's fig. 4): estimates, truth, error lines, landmarks,
paths. It is the ``map`` result contract's picture (:func:`placeloc.evaluation.maps.plot_map`),
re-exported here where co-embedding's experiments read it."""

from __future__ import annotations

from placeloc.evaluation.maps import plot_map

__all__ = ["plot_map"]
