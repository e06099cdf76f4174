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
        assert (moved <= 0).all() and (moved < 0).mean() > 0.4  # backwards at 0.5x-1.5x
    elif family == "burst":
        assert 2.4 <= moved.mean() <= 4.1
    elif family == "crawl":
        assert 0.2 <= moved.mean() <= 0.45
    elif family == "fast":
        assert 2.2 <= 599 / len(pos) <= 3.05  # one speed of 2.25x-3.0x throughout
    else:
        assert (step >= 0).all()


# ---------------------------------------------------------------------------------------
# stops collapsed (collapse_stops) and paths driven backwards throughout (backward_paths)
# ---------------------------------------------------------------------------------------
def _standing_route(n_ref: int, places: np.ndarray, seed: int,
                    ref_stands: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """As :func:`_route` (each view of a place +-40 grey levels off the reference's, as
    another season), but a query frame that repeats its place repeats its view up to
    +-4 levels, as a stopped camera's frames differ by sensor noise only; ``ref_stands``
    = (first, last): the reference stands there too (its rows repeat the first, +-4), as
    at a station."""
    rng = np.random.default_rng(seed)
    ref = rng.integers(0, 256, (n_ref, 32)).astype(int)
    if ref_stands is not None:
        a, b = ref_stands
        ref[a:b + 1] = ref[a] + rng.integers(-4, 5, (b + 1 - a, 32))
    query = ref[places] + rng.integers(-40, 41, (len(places), 32))
    for j in range(1, len(places)):
        if places[j] == places[j - 1]:
            query[j] = query[j - 1] + rng.integers(-4, 5, 32)
    return np.clip(ref, 0, 255).astype(np.uint8), np.clip(query, 0, 255).astype(np.uint8)


def test_standing_runs_collapse_stops_and_never_a_slow_drift():
    from placeloc.seqslam.matching import standing_runs

    rng = np.random.default_rng(11)
    moving = rng.integers(0, 256, (60, 32)).astype(np.float64)
    frames = np.concatenate([moving[:20], np.repeat(moving[20:21], 15, axis=0), moving[21:40],
                             np.repeat(moving[40:41], 8, axis=0), moving[41:]])
    frames = np.clip(frames + rng.normal(0, 2, frames.shape), 0, 255).astype(np.uint8)
    first, run_of = standing_runs(frames, "sad")
    # the 15-frame stop (frames 20-34) and the 8-frame one (54-61) each become one frame
    keep = np.concatenate([np.arange(21), np.arange(35, 55), np.arange(62, len(frames))])
    np.testing.assert_array_equal(first, keep)
    np.testing.assert_array_equal(first[run_of[20:35]], [20] * 15)
    np.testing.assert_array_equal(first[run_of[54:62]], [54] * 8)
    # a crawl: 40 frames each 2 grey levels brighter than the one before (frame to frame
    # far below a moving frame's change of about 85, but 80 levels over the stretch)
    crawl = np.concatenate([moving[:30], moving[30:31] + 2.0 * np.arange(40)[:, None] % 256, moving[31:]])
    first, _ = standing_runs(np.clip(crawl, 0, 255).astype(np.uint8), "sad")
    assert len(first) >= 30 + 40 // 11 + 29  # cut whenever it drifts past the threshold (~21 levels)


STANDING = dict(comparison="sad", enhance_window=3, ds=40, v_min=0.5, v_max=2.0, v_step=0.1, v_auto=True,
                search="centred", sequence_shape="flexible", edges="shift", top_k=2, exclude_recent=None,
                block_size=1024)


@pytest.mark.parametrize("features", ["uint8", "float32"])
@pytest.mark.parametrize("block_size", [1024, 70])
def test_collapsed_search_reads_the_full_search_differences_and_answers_the_same(monkeypatch, features, block_size):
    # the second search of collapse_stops takes the differences the full search computed
    # (from the blocks as they pass, each group searched once all its frames have passed)
    # instead of computing them again:
    # every answer, score and confidence as when it computes them itself, and fewer computed
    from placeloc.seqslam import matching

    places = np.concatenate([np.arange(10, 80), np.full(40, 80), np.arange(81, 150), np.full(30, 150),
                             np.arange(151, 200)])
    ref, query = _standing_route(220, places, seed=21)
    if features == "float32":  # the float kernel (zscore features) as well as the uint8 one
        ref, query = (x.astype(np.float32) / 17 for x in (ref, query))
    common = {**STANDING, "block_size": block_size}
    computed = []
    real_difference = matching.difference_block_t

    def counting(r: np.ndarray, q: np.ndarray, comparison: str) -> np.ndarray:
        computed.append(len(q))
        return real_difference(r, q, comparison)

    monkeypatch.setattr(matching, "difference_block_t", counting)
    kept = sequence_match(ref, query, collapse_stops=True, **common)
    with_kept = sum(computed)
    real_search = matching.collapsed_search

    def computing_itself(*a, **k):  # takes no block: computes every difference it reads
        search = real_search(*a, **k)
        search.take = lambda q0, dt: None
        return search

    monkeypatch.setattr(matching, "collapsed_search", computing_itself)
    computed.clear()
    again = sequence_match(ref, query, collapse_stops=True, **common)
    for name in ("candidates", "scores", "confidence"):
        np.testing.assert_array_equal(getattr(kept, name), getattr(again, name))
    assert sum(computed) > with_kept  # the second search computed its own differences only without them
    computed.clear()
    sequence_match(ref, query, **common)
    assert with_kept == sum(computed)  # with them, none beyond the full search's: its blocks held every one
    assert (np.abs(kept.candidates[:, 0] - places) <= 1).mean() > 0.95


def test_collapsed_stop_is_followed_to_within_a_frame():
    # a query that stops for 50 frames where the reference moves on: with collapse_stops
    # every frame of the stop is within a frame; the frames the stop repeats take the
    # collapsed search's answer and confidence
    places = np.concatenate([np.arange(10, 110), np.full(50, 110), np.arange(111, 200)])
    ref, query = _standing_route(220, places, seed=12)
    collapsed = sequence_match(ref, query, collapse_stops=True, **STANDING)
    err = np.abs(collapsed.candidates[:, 0] - places)
    assert (err <= 1).all()
    stop = slice(100, 150)
    plain = sequence_match(ref, query, **STANDING)  # moving only: the middle of the stop is lost
    assert (np.abs(plain.candidates[stop, 0] - places[stop]) > 1).sum() >= 10
    # the stop opens at frame 100 (its first view of place 110), which keeps its own answer;
    # frames 101-149 repeat it: those whose own answer was more than a frame off carry the
    # collapsed answer, confidence included; those within a frame keep their own (the
    # reference moves: between them lies no frame of it)
    np.testing.assert_array_equal(collapsed.candidates[100], plain.candidates[100])
    repeats = slice(101, 150)
    took = np.abs(plain.candidates[repeats, 0] - collapsed.candidates[repeats, 0]) > 1
    assert took.sum() >= 10
    assert (collapsed.confidence[repeats][took] == collapsed.confidence[repeats][took][0]).all()
    np.testing.assert_array_equal(collapsed.candidates[repeats][~took], plain.candidates[repeats][~took])
    np.testing.assert_array_equal(collapsed.confidence[repeats][~took], plain.confidence[repeats][~took])
    # away from the stop, the full search's answers are untouched
    np.testing.assert_array_equal(collapsed.candidates[:100], plain.candidates[:100])
    np.testing.assert_array_equal(collapsed.candidates[150:], plain.candidates[150:])


def test_a_stop_both_traverses_made_stays_aligned():
    # a station: the reference stands at 100-129 (30 frames of one place) and so does
    # the query (its own 30 frames): every query frame lands inside the station (where
    # any of its frames is as right as another), every other within a frame
    places = np.concatenate([np.arange(10, 100), np.full(30, 100), np.arange(130, 220)])
    ref, query = _standing_route(240, places, seed=13, ref_stands=(100, 129))
    best = sequence_match(ref, query, collapse_stops=True, **STANDING).candidates[:, 0]
    inside = places == 100
    assert ((best[inside] >= 100) & (best[inside] <= 129)).all()
    assert (np.abs(best[~inside] - places[~inside]) <= 1).all()


def test_a_shared_station_keeps_the_synchronous_answers():
    # the same station, scored by the synchronous frame (what a +-2 ground truth wants):
    # inside it every reference frame looks alike, so only the path's continuity places a
    # query frame, and the full search keeps to the synchronous frame; the collapsed
    # search answers the station's first frame, 0-29 frames back. collapse_stops must leave
    # the full search's answers: they are within one kept frame of the collapsed one
    places = np.concatenate([np.arange(10, 100), np.full(30, 100), np.arange(130, 220)])
    synchronous = np.arange(10, 220)
    ref, query = _standing_route(240, places, seed=13, ref_stands=(100, 129))
    full = sequence_match(ref, query, **STANDING).candidates[:, 0]
    best = sequence_match(ref, query, collapse_stops=True, **STANDING).candidates[:, 0]
    np.testing.assert_array_equal(best, full)
    station = places == 100
    assert (np.abs(best[station] - synchronous[station]) <= 2).mean() >= 0.8  # the station's first frame: 5 of 30
    assert (np.abs(best[~station] - synchronous[~station]) <= 1).all()


def test_runs_that_open_a_frame_apart_leave_the_station_edge_right():
    # the query's camera already sees the station one frame before the train stops (its
    # run opens at place 99, the reference's at 100): the frame that opens the query's
    # run keeps its own answer, 99 (copying the run's answer put it a frame off), and
    # the station's frames land inside it
    places = np.concatenate([np.arange(10, 100), np.full(30, 100), np.arange(130, 220)])
    ref, query = _standing_route(240, places, seed=18, ref_stands=(100, 129))
    at99 = int(np.flatnonzero(places == 99)[0])
    rng = np.random.default_rng(18)
    query[at99] = np.clip(query[at99 + 1].astype(int) + rng.integers(-4, 5, query.shape[1]), 0, 255)
    from placeloc.seqslam.matching import standing_runs

    first, run_of = standing_runs(query, "sad")
    assert first[run_of[at99 + 1]] == at99  # the run opens at place 99
    best = sequence_match(ref, query, collapse_stops=True, **STANDING).candidates[:, 0]
    assert best[at99] == 99
    inside = places == 100
    assert ((best[inside] >= 99) & (best[inside] <= 129)).all()
    assert (np.abs(best[~inside] - places[~inside]) <= 1).all()


def test_a_query_moving_where_only_the_reference_stands_keeps_every_frame():
    # the reference stands at 100-129 (its frames alike) where the query drives on at the
    # reference's own speed: every query frame there stays within a frame of its place
    # with collapse_stops, as without (collapsing the reference's run under a moving
    # query once gave every query frame there the run's first frame, up to 29 off)
    places = np.arange(10, 220)
    ref, query = _standing_route(240, places, seed=19, ref_stands=(100, 129))
    for collapse in (False, True):
        best = sequence_match(ref, query, collapse_stops=collapse, **STANDING).candidates[:, 0]
        assert (np.abs(best - places) <= 1).all(), collapse


def test_stop_answers_take_only_repeated_frames_between_the_runs_neighbours():
    from placeloc.seqslam.matching import stop_answers

    moving = np.arange(40)  # a reference that never stands: every frame is its own kept frame
    # frames 0-6: a run 1-3 (frame 1 kept, 2 and 3 repeat it) and a run 5-6 that ends the traverse
    first = np.array([0, 1, 4, 5])
    run_of = np.array([0, 1, 1, 1, 2, 3, 3])
    full = np.array([10, 11, 30, 31, 14, 15, 16])
    # the first run's answer 12 lies between 11 (its first frame) and 14 (the frame after):
    # its repeats take it; the last run's 20 is not between 15 and 16 (its own last frame)
    stop = np.array([-1, 12, 12, 12, -1, 20, 20])
    np.testing.assert_array_equal(stop_answers(full, stop, first, run_of, moving), [0, 0, 1, 1, 0, 0, 0])
    # both ends of the bracket count (14 for the first run); the last run's 16 is frame 6's own answer
    np.testing.assert_array_equal(stop_answers(full, np.array([-1, 14, 14, 14, -1, 16, 16]), first, run_of, moving),
                                  [0, 0, 1, 1, 0, 0, 0])
    # a repeated frame whose own answer is a frame from the run's keeps it (no moving
    # reference frame between them); two frames off, 14, one lies between (13)
    np.testing.assert_array_equal(stop_answers(np.array([10, 11, 13, 14, 14, 15, 16]), stop, first, run_of, moving),
                                  [0, 0, 0, 1, 0, 0, 0])
    no_after = full.copy()
    no_after[4] = -1  # no answer after the run: nothing to bracket with
    assert not stop_answers(no_after, stop, first, run_of, moving)[2:4].any()


def test_stop_answers_leave_a_shared_station_to_the_full_search():
    from placeloc.seqslam.matching import stop_answers

    # the reference stands at a station it splits in two runs, 20-27 and 28-33, and moves
    # elsewhere; the query's run (frames 0-5) opens a frame early, at place 19, so the
    # collapsed search answers 19, the frame before the station. The full search's answers
    # inside the station (23, 30, 33) or the frame after it (34) have nothing but standing
    # reference between them and 19, and stay (they are the synchronous frames); 35 has a
    # moving frame, 34, between, and takes 19
    opens = np.ones(40, bool)
    opens[21:28] = opens[29:34] = False
    ref_run_of = np.cumsum(opens) - 1
    first = np.array([0, 6])
    run_of = np.array([0, 0, 0, 0, 0, 0, 1])
    full = np.array([19, 23, 30, 33, 34, 35, 36])
    collapsed = np.full(7, 19)
    np.testing.assert_array_equal(stop_answers(full, collapsed, first, run_of, ref_run_of), [0, 0, 0, 0, 0, 1, 0])
    # a reference that never stands: every answer more than a frame from 19 takes it
    np.testing.assert_array_equal(stop_answers(full, collapsed, first, run_of, np.arange(40)), [0, 1, 1, 1, 1, 1, 0])


@pytest.mark.parametrize("search", ["causal", "centred"])
def test_collapsing_and_backward_paths_never_depend_on_the_block_size(search):
    places = np.concatenate([np.arange(5, 40), np.full(12, 40), np.arange(41, 60), np.full(9, 60), np.arange(61, 85)])
    ref, query = _standing_route(95, places, seed=14, ref_stands=(70, 76))
    common = dict(comparison="sad", enhance_window=3, ds=20, v_min=0.5, v_max=1.5, v_step=0.25, v_auto=False,
                  search=search, sequence_shape="flexible", edges="shift", top_k=3, exclude_recent=None,
                  collapse_stops=True, backward_paths=True, plain_k=5)
    seen: dict[int, list] = {}
    one = sequence_match(ref, query, block_size=1000,
                         on_difference=lambda c0, c1, d: seen.setdefault(1000, []).append((c0, c1, d.copy())), **common)
    for block in (16, 5, 1):
        cut = sequence_match(ref, query, block_size=block,
                             on_difference=lambda c0, c1, d, b=block: seen.setdefault(b, []).append((c0, c1, d.copy())),
                             **common)
        np.testing.assert_array_equal(one.candidates, cut.candidates)
        np.testing.assert_array_equal(one.scores, cut.scores)
        np.testing.assert_array_equal(one.plain_candidates, cut.plain_candidates)
        # the stored differences are every frame's own, whatever was collapsed
        d = np.concatenate([x[2] for x in seen[block]], axis=1)
        np.testing.assert_array_equal(d, np.concatenate([x[2] for x in seen[1000]], axis=1))
    assert np.concatenate([x[2] for x in seen[1000]], axis=1).shape == (len(ref), len(query))


def test_collapse_stops_refuses_loop_closure():
    ref, _ = _route(50, np.arange(50), seed=15)
    with pytest.raises(ValueError, match="loop closure"):
        sequence_match(ref, ref, comparison="sad", enhance_window=3, ds=10, v_min=0.8, v_max=1.2, v_step=0.1,
                       v_auto=False, search="causal", sequence_shape="flexible", edges="skip", top_k=2,
                       exclude_recent=5, block_size=64, collapse_stops=True)


def test_backward_paths_follow_a_reversal_to_within_a_frame():
    # forward speeds only (0.3-4.0) and the family driven backwards throughout: the
    # queries whose window lies inside a 90-frame reversal land within a frame; without
    # the backward family they are lost
    speeds = np.concatenate([np.ones(100), np.full(90, -1.0), np.ones(100)])
    et, path = _planted(speeds, seed=16)
    vels = velocities(0.3, 4.0, 0.1)
    back, _ = sequence_search(et, 0, len(et), 40, vels, "centred", 5, 2, None, 0, shape="flexible", edges="shift",
                              backward_paths=True, reverse_cost=0.5)
    ahead, _ = sequence_search(et, 0, len(et), 40, vels, "centred", 5, 2, None, 0, shape="flexible", edges="shift")
    inside = slice(125, 165)  # the windows (41 frames) lie inside the reversal
    assert (np.abs(back[inside, 0] - path[inside]) <= 1).all()
    assert (np.abs(ahead[inside, 0] - path[inside]) > 1).mean() > 0.5
    steady = np.r_[0:80, 210:290]  # away from the turns, forward queries keep their matches
    assert (np.abs(back[steady, 0] - path[steady]) <= 1).all()


def test_backward_paths_take_the_better_family_per_reference():
    # the combined scores are the elementwise minimum of the two families' scores: a
    # planted reversal scored with only the backward speeds agrees with backward_paths
    # wherever the backward family wins
    speeds = np.concatenate([np.ones(60), np.full(60, -1.0), np.ones(60)])
    et, _ = _planted(speeds, seed=17)
    vels = velocities(0.5, 2.0, 0.1)
    k = 3
    both, s_both = sequence_search(et, 0, len(et), 20, vels, "centred", 5, k, None, 0, shape="flexible", edges="shift",
                                   backward_paths=True, reverse_cost=0.25)
    _, s_fwd = sequence_search(et, 0, len(et), 20, vels, "centred", 5, k, None, 0, shape="flexible", edges="shift")
    np.testing.assert_array_less(s_both[:, 0] - 1e-4, s_fwd[:, 0])  # never worse than forward alone
    with pytest.raises(ValueError, match="forward speeds only"):
        sequence_search(et, 0, len(et), 20, velocities(0.5, 2.0, 0.1, v_reverse=1.0), "centred", 5, k, None, 0,
                        shape="flexible", edges="shift", backward_paths=True)


def test_the_backward_family_spans_the_forward_speeds_up_to_its_own_fastest():
    from placeloc.seqslam.matching import search_velocities
    from placeloc.seqslam.search import backward_velocities

    vels = velocities(0.3, 4.0, 0.1)
    np.testing.assert_allclose(backward_velocities(vels, 1.5), -np.round(np.arange(1.5, 0.25, -0.1), 9))
    assert len(backward_velocities(vels, 4.0)) == len(vels) == 38
    assert len(backward_velocities(vels, 0.2)) == 0  # slower than the slowest: no family
    # the limit is not scaled by v_auto: 600 references, 750 query frames (a query that
    # drove 150 frames twice) -> speeds x0.8, 0.24..3.2; the family 0.24..1.44 (16 speeds)
    scaled = search_velocities(0.3, 4.0, 0.1, True, 600, 750)
    np.testing.assert_allclose(backward_velocities(scaled, 1.5), -scaled[:16][::-1])
    assert scaled[16] > 1.5


@pytest.mark.parametrize("back_speed", [1.0, 1.4])
def test_a_limited_backward_family_follows_a_reversal_it_spans_and_scores_as_its_speeds_alone(back_speed):
    # a 90-frame reversal at 1.0x and at 1.4x (the limit 1.5 above both): the queries whose
    # window lies inside it land within a frame, as with the whole family; the combined
    # scores are exactly the minimum of the forward family's and the limited backward
    # family's; a limit below the reversal's speed (0.5) loses it
    from placeloc.seqslam.search import _flexible_scores, _scores, backward_velocities, query_offsets

    speeds = np.concatenate([np.ones(100), np.full(90, -back_speed), np.ones(100)])
    et, path = _planted(speeds, seed=18)
    vels = velocities(0.3, 4.0, 0.1)

    def search(limit: float) -> tuple[np.ndarray, np.ndarray]:
        return sequence_search(et, 0, len(et), 40, vels, "centred", 5, 2, None, 0, shape="flexible", edges="shift",
                               backward_paths=True, reverse_cost=0.0, backward_v_max=limit)

    limited, _ = search(1.5)
    whole, _ = search(4.0)
    slow, _ = search(0.5)
    inside = slice(125, 165)
    assert (np.abs(limited[inside, 0] - path[inside]) <= 1).all()
    np.testing.assert_array_equal(limited[inside, 0], whole[inside, 0])
    assert (np.abs(slow[inside, 0] - path[inside]) > 1).mean() > 0.5
    t_off = query_offsets(40, "centred")
    rows = (60, 70)
    fwd = _flexible_scores(et, rows, t_off, vels, reverse_cost=0.0)
    back = _flexible_scores(et, rows, t_off, backward_velocities(vels, 1.5), reverse_cost=0.0)
    both = _scores(et, rows, t_off, np.zeros((1, 1), np.int64), "flexible", 5, 2, np.full(10, et.shape[1]), vels,
                   {"speed_change_cost": 1.0, "stop_cost": 2.0, "reverse_cost": 0.0, "stops": None,
                    "backward_paths": True, "backward_v_max": 1.5})
    np.testing.assert_array_equal(both, np.minimum(fwd, back))


@pytest.mark.parametrize("seqslam,query,message", [
    ({"collapse_stops": True}, False, r"seqslam\.collapse_stops needs a query traverse"),
    ({"backward_paths": True, "sequence_shape": "flexible", "v_reverse": 1.0}, True,
     r"seqslam\.backward_paths needs sequence_shape: flexible with forward speeds only"),
    ({"backward_paths": True, "sequence_shape": "trajectory"}, True, r"seqslam\.backward_paths needs"),
])
def test_the_config_refuses_what_the_search_cannot_do(tmp_path, seqslam, query, message):
    from placeloc.core.config import ConfigError, load_config

    (tmp_path / "imgs").mkdir()
    config = {"method": "seqslam", "reference": {"images": str(tmp_path / "imgs")}, "seqslam": seqslam}
    if query:
        config["query"] = {"images": str(tmp_path / "imgs")}
    with pytest.raises(ConfigError, match=message):
        load_config(data=config)


def test_the_experiment_searches_as_localize_does():
    # seqslam_motion.search (on a precomputed enhanced matrix) and sequence_match (what
    # localize runs) give the same matches and confidences with both switches on: a stop
    # only the query makes, a station both make, and a stretch driven backwards
    from placeloc.experiments.seqslam_motion import search
    from placeloc.seqslam.comparisons import difference_block
    from placeloc.seqslam.search import enhance

    places = np.concatenate([np.arange(10, 80), np.full(25, 80), np.arange(81, 100), np.full(20, 100),
                             np.arange(121, 180), np.arange(179, 149, -1), np.arange(150, 230)])
    ref, query = _standing_route(240, places, seed=20, ref_stands=(100, 120))
    # the part's data as seqslam_motion.part makes it, but enhanced with a window of 6, not
    # configs/nordland.yaml's 10: the kept references' enhancement must take the window of
    # the setting under test too; the query's own frames stand for the part's winter
    # frames, each shown once
    d = difference_block(ref, query, "sad")
    data = {"difference": d, "enhanced": np.ascontiguousarray(enhance(d, 6).T), "reference_features": ref,
            "query_features": query}
    pos = np.arange(len(query))
    setting = dict(comparison="sad", enhance_window=6, ds=40, v_min=0.5, v_max=2.0, v_step=0.1, v_auto=True,
                   search="centred", sequence_shape="flexible", edges="shift", top_k=2, v_reverse=0.0,
                   speed_change_cost=1.0, stop_cost=2.0, reverse_cost=0.0, collapse_stops=True, backward_paths=True,
                   backward_v_max=1.5)
    best, conf = search(data, pos, setting)
    m = sequence_match(ref, query, exclude_recent=None, block_size=64, **setting)
    np.testing.assert_array_equal(best, m.candidates[:, 0])
    np.testing.assert_allclose(conf, m.confidence)
    assert (np.abs(best - places) <= 1).mean() > 0.9
