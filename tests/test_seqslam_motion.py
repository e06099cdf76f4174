"""SeqSLAM following a query that stops, crawls, bursts and reverses; block cutting and edges."""

from __future__ import annotations

import numpy as np
import pytest

from placeloc.seqslam.matching import block_spans, sequence_match
from placeloc.seqslam.search import sequence_search, velocities


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


# ---------------------------------------------------------------------------------------
# each motion planted in a synthetic matrix: the flexible path over every speed it may
# take (backwards to -1.0, standing, crawling, bursting to 4.0, in steps of 0.1) and the
# default costs
# ---------------------------------------------------------------------------------------
PRESET_SPEEDS = velocities(0.0, 4.0, 0.1, v_reverse=1.0)


def _planted(speeds: np.ndarray, seed: int, snr: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """Enhanced-like query-major matrix (Gaussian noise around 4) with the path a query
    moving at ``speeds`` (negative: backwards) traces lowered by ``snr`` standard
    deviations, its neighbours by half that; a query that has not moved since its last frame sees that frame again
    (its column repeats), as a stopped camera does."""
    rng = np.random.default_rng(seed)
    x = np.concatenate([[0.0], np.cumsum(speeds[:-1])])
    path = 30 + np.floor(x + 0.5).astype(np.int64)
    n_ref = int(path.max()) + 40
    et = (rng.normal(0, 1, (len(speeds), n_ref)) + 4).astype(np.float32)
    q = np.arange(len(speeds))
    et[q, path] -= snr
    et[q, path - 1] -= snr / 2  # neighbouring frames look alike: the valley is three frames wide
    et[q, path + 1] -= snr / 2
    for q in range(1, len(speeds)):
        if path[q] == path[q - 1]:
            et[q] = et[q - 1]
    return et, path


def _follow(et: np.ndarray) -> np.ndarray:
    best, _ = sequence_search(et, 0, len(et), 80, PRESET_SPEEDS, "centred", 5, 2, None, 0, shape="flexible",
                              edges="shift")
    return best[:, 0]


@pytest.mark.parametrize("motion,speeds", [
    ("a 30-frame stop", np.concatenate([np.ones(70), np.zeros(30), np.ones(70)])),
    ("an 80-frame crawl at 0.3x", np.concatenate([np.ones(60), np.full(80, 0.3), np.ones(60)])),
    ("a 40-frame burst at 3x", np.concatenate([np.ones(60), np.full(40, 3.0), np.ones(60)])),
    ("50 frames driven backwards", np.concatenate([np.ones(90), np.full(50, -1.0), np.ones(90)])),
    ("60 frames backing out at half speed", np.concatenate([np.ones(90), np.full(60, -0.5), np.ones(90)])),
])
def test_flexible_path_follows_each_motion_to_within_a_frame(motion, speeds):
    # an 81-frame window spans each motion with frames of the route on both sides. A
    # path bends only between 10-frame segments counted from the anchor, so a query a few
    # frames from a change of motion, or inside a stop (whose repeated frames carry no
    # evidence of place: only the path's continuity does), may land up to 3 frames off
    et, path = _planted(speeds, seed=len(speeds))
    err = np.abs(_follow(et) - path)
    assert err.max() <= 3, motion
    assert (err <= 1).mean() >= 0.95, motion


def test_straight_lines_and_the_old_speed_range_lose_the_reversal_and_the_burst():
    # the same planted motions with speeds 0.5-2.0 (the previous preset): the reversal and
    # the burst lie outside, and the queries inside them are lost
    for speeds, stretch in ((np.concatenate([np.ones(90), np.full(50, -1.0), np.ones(90)]), slice(100, 130)),
                            (np.concatenate([np.ones(60), np.full(40, 3.0), np.ones(60)]), slice(65, 95))):
        et, path = _planted(speeds, seed=len(speeds))
        best, _ = sequence_search(et, 0, len(et), 40, velocities(0.5, 2.0, 0.1), "centred", 5, 2, None, 0,
                                  shape="flexible", edges="shift")
        assert (np.abs(best[stretch, 0] - path[stretch]) > 1).mean() > 0.5


def test_backward_speeds_mirror_the_forward_ones():
    np.testing.assert_allclose(velocities(0.3, 0.6, 0.1, v_reverse=0.5), [-0.5, -0.4, -0.3, 0.3, 0.4, 0.5, 0.6])
    np.testing.assert_allclose(velocities(0.0, 0.2, 0.1, v_reverse=0.2), [-0.2, -0.1, 0.0, 0.1, 0.2])  # 0 once
    np.testing.assert_allclose(velocities(0.8, 1.2, 0.1), [0.8, 0.9, 1.0, 1.1, 1.2])  # v_reverse 0: forward only


def test_localize_passes_the_path_settings_through():
    # a reversal that only a path allowed to back out follows: sequence_match (what
    # localize calls) with v_reverse set finds it, without it does not
    places = np.concatenate([np.arange(20, 80), np.arange(79, 49, -1), np.arange(50, 110)])
    ref, query = _route(130, places, seed=9)
    common = dict(comparison="sad", enhance_window=3, ds=30, v_min=0.5, v_max=1.5, v_step=0.1, v_auto=False,
                  search="centred", sequence_shape="flexible", edges="shift", top_k=2, exclude_recent=None,
                  block_size=1024)
    back = sequence_match(ref, query, v_reverse=1.0, reverse_cost=0.1, **common)
    ahead = sequence_match(ref, query, **common)
    backing = slice(65, 85)  # queries whose window is mostly the backward stretch
    assert (np.abs(back.candidates[backing, 0] - places[backing]) <= 1).all()
    assert (np.abs(ahead.candidates[backing, 0] - places[backing]) > 1).sum() >= 5
    assert back.velocities.min() == -1.0 and ahead.velocities.min() == 0.5


# ---------------------------------------------------------------------------------------
# the experiment's own numerics: profiles, the soft ground truth, recall at 100 % precision
# ---------------------------------------------------------------------------------------
def test_shared_stops_cover_only_stretches_where_both_traverses_stand():
    from placeloc.experiments.seqslam_motion import shared_stops

    rng = np.random.default_rng(10)
    ref = rng.normal(0, 1, (40, 16))
    query = ref + rng.normal(0, 0.1, ref.shape)
    ref[10:16] = ref[10]  # both stand at frames 10-15
    query[10:16] = query[10]
    ref[25:30] = ref[25]  # only the reference stands: not shared
    truth = shared_stops(ref, query)
    np.testing.assert_array_equal(truth[10:16], [[10, 15]] * 6)
    np.testing.assert_array_equal(truth[:10], np.stack([np.arange(10)] * 2, axis=1))
    np.testing.assert_array_equal(truth[25:30], np.stack([np.arange(25, 30)] * 2, axis=1))


def test_recall_at_100_precision_counts_matches_above_the_most_confident_wrong_one():
    from placeloc.experiments.seqslam_motion import recall_at_100_precision

    correct = np.array([True, True, False, True, True])
    conf = np.array([0.9, 0.5, 0.6, 0.6, 0.8])
    assert recall_at_100_precision(correct, conf) == pytest.approx(2 / 5)  # 0.9 and 0.8; the tie at 0.6 is out
    assert recall_at_100_precision(np.ones(3, bool), np.zeros(3)) == 1.0


@pytest.mark.parametrize("family", ["stop", "crawl", "burst", "reverse", "fast", "varying", "steady"])
def test_motion_profiles_do_what_their_family_says(family):
    from placeloc.experiments.seqslam_motion import query_positions

    pos, inside = query_positions(family, 600, seed=3)
    assert pos[0] == 0 and pos.min() >= 0 and pos.max() <= 599 and pos[-1] >= 595  # the whole route, start to end
    step = np.diff(pos)
    moved = step[inside[:-1]]
    if family == "stop":
        assert (moved == 0).all() and inside.sum() >= 90  # three stops of 30-60 frames
    elif family == "reverse":
        assert (moved <= 0).all() and (moved < 0).mean() > 0.4  # backwards at 0.5x-1.0x
    elif family == "burst":
        assert 2.4 <= moved.mean() <= 4.1
    elif family == "crawl":
        assert 0.2 <= moved.mean() <= 0.45
    elif family == "fast":
        assert 2.2 <= 599 / len(pos) <= 3.05  # one speed of 2.25x-3.0x throughout
    else:
        assert (step >= 0).all()
