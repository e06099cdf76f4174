"""SeqSLAM's brought descriptors: the shared reader :mod:`placeloc.core.descriptors`, re-exported."""

from __future__ import annotations

from placeloc.core.descriptors import DISTANCES, DescriptorError, descriptor_difference, load_descriptors, prepare_descriptors

__all__ = ["DISTANCES", "DescriptorError", "descriptor_difference", "load_descriptors", "prepare_descriptors"]
