"""SeqSLAM following a query that stops, crawls, bursts and reverses; block cutting and edges."""

from __future__ import annotations

import numpy as np
import pytest

from placeloc.seqslam.matching import block_spans, sequence_match


def _route(n_ref: int, places: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Reference rows of random 32-byte images and a query that sees ``places`` with noise."""
    rng = np.random.default_rng(seed)
    ref = rng.integers(0, 256, (n_ref, 32), dtype=np.uint8)
    query = np.clip(ref[places].astype(int) + rng.integers(-40, 41, (len(places), 32)), 0, 255).astype(np.uint8)
    return ref, query


def test_block_spans_hold_a_whole_window_at_both_ends():
    # 1056 queries, blocks of 1024, a 121-frame centred window: the last block (32
    # queries) must read the 121 frames nearest the end, the first at least 121
    spans = block_spans(1056, 1024, 60, 60)
    assert spans == [(0, 1024, 0, 1056), (1024, 1056, 1056 - 121, 1056)]
    assert block_spans(300, 100, 5, 5) == [(0, 100, 0, 105), (100, 200, 95, 205), (200, 300, 195, 300)]
    assert block_spans(5, 2, 3, 3) == [(0, 2, 0, 5), (2, 4, 0, 5), (4, 5, 0, 5)]  # shorter than a window


def test_1056_queries_in_blocks_of_1024_are_all_matched_with_shifted_edges():
    places = np.arange(1056) % 150
    ref, query = _route(150, places, seed=7)  # the route driven seven times and a bit
    common = dict(comparison="sad", enhance_window=4, ds=120, v_min=0.8, v_max=1.2, v_step=0.1, v_auto=False,
                  search="centred", sequence_shape="trajectory", edges="shift", top_k=2, exclude_recent=None)
    cut = sequence_match(ref, query, block_size=1024, **common)
    assert (cut.candidates[:, 0] >= 0).all()  # the 32 queries of the last block too
    one = sequence_match(ref, query, block_size=2048, **common)
    np.testing.assert_array_equal(one.candidates, cut.candidates)
    np.testing.assert_array_equal(one.scores, cut.scores)


@pytest.mark.parametrize("shape", ["trajectory", "cone", "hybrid", "flexible"])
@pytest.mark.parametrize("edges", ["skip", "shift"])
@pytest.mark.parametrize("search", ["causal", "centred"])
def test_block_size_never_changes_a_result(shape, edges, search):
    places = np.minimum(5 + np.arange(66), 79)
    ref, query = _route(90, places, seed=8)
    common = dict(comparison="sad", enhance_window=3, ds=30, v_min=0.5, v_max=1.5, v_step=0.25, v_auto=False,
                  search=search, sequence_shape=shape, edges=edges, top_k=3, exclude_recent=None)
    one = sequence_match(ref, query, block_size=1000, **common)
    for block in (64, 7, 1):
        cut = sequence_match(ref, query, block_size=block, **common)
        np.testing.assert_array_equal(one.candidates, cut.candidates)
        np.testing.assert_array_equal(one.scores, cut.scores)
    matched = one.candidates[:, 0] >= 0
    assert matched.all() if edges == "shift" else matched.sum() == 66 - 30
