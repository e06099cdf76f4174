"""SeqSLAM's brought descriptors: the shared reader :mod:`placeloc.descriptors`, re-exported."""

from __future__ import annotations

from placeloc.descriptors import DISTANCES, DescriptorError, descriptor_difference, load_descriptors, prepare_descriptors

__all__ = ["DISTANCES", "DescriptorError", "descriptor_difference", "load_descriptors", "prepare_descriptors"]
