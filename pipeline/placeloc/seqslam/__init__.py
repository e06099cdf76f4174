"""SeqSLAM (M. Milford and G. Wyeth, "SeqSLAM: Visual route-based navigation for sunny summer
days and stormy winter nights", ICRA 2012) with eight illumination-robust image comparisons
and OpenSeqSLAM2's search shapes (see docs/seqslam.md).

Array-level entry points: :func:`placeloc.seqslam.matching.sequence_match` (features in,
ranked matches out), :func:`placeloc.seqslam.search.sequence_search` (on an enhanced
difference matrix), :func:`placeloc.seqslam.comparisons.prepare`. Nothing is imported here,
so that ``extract`` loads neither the kernels nor llvmlite.
"""
