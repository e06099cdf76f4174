"""Known answers for the oriented (directional) chamfer score of whole panoramas: line
directions of the map renders and the query's LSD lines, the score by hand, against a
pixel loop built on OpenCV's distance transform, and the search with it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_umap_panorama import PLAN, H, W, _chamfer_reference, _grey_panorama

from placeloc.geometry.floorplan import floor_plan_model
from placeloc.geometry.panorama import orientation_bit, panorama_line_image, render_panoramas
from placeloc.umap.bits import unpack
from placeloc.umap.panorama import (
    chamfer_at_shifts,
    chamfer_spectra,
    chamfer_table,
    compatible_lines,
    orientation_channels,
    precision_rows,
    row_weights,
)


def test_orientation_bit_by_hand():
    # bin 0 centred on the image's horizontal, 180 / B degrees a bin, directions modulo 180
    assert orientation_bit(1.0, 0.0, 4) == 1 and orientation_bit(-1.0, 0.0, 4) == 1
    assert orientation_bit(0.0, 1.0, 4) == 4 and orientation_bit(0.0, -1.0, 4) == 4
    assert orientation_bit(1.0, 1.0, 4) == 2 and orientation_bit(1.0, -1.0, 4) == 8
    assert orientation_bit(1.0, math.tan(math.radians(22.0)), 4) == 1     # below the 22.5 deg boundary
    assert orientation_bit(1.0, math.tan(math.radians(23.0)), 4) == 2
    assert orientation_bit(0.0, 1.0, 2) == 2 and orientation_bit(0.3, 1.0, 1) == 1


def test_map_directions_are_exact_and_the_union_is_the_line_image():
    m = floor_plan_model(PLAN)
    pose = np.array([[2.1, 5.3, 1.4, 62.5]])
    binary = unpack(render_panoramas(m.segments, m.faces, pose, width=W, height=H, hidden=True), H, W)[0]
    for bins in (2, 4, 8):
        masks = render_panoramas(m.segments, m.faces, pose, width=W, height=H, hidden=True, orientation_bins=bins)[0]
        assert ((masks != 0) == (binary != 0)).all()
        # world-vertical segments (corners, jambs) run straight down the image: the vertical
        # bin, bins / 2, exactly
        vert = render_panoramas(m.segments, m.faces, pose, width=W, height=H, hidden=True, which="vertical",
                                orientation_bins=bins)[0]
        assert vert.sum() > 0 and set(np.unique(vert[vert > 0])) == {1 << (bins // 2)}
    # a floor plan's horizontal edges at the camera's height would be horizontal; the floor
    # and ceiling edges curve, so every bin of 8 but the near-vertical ones occurs
    masks = render_panoramas(m.segments, m.faces, pose, width=W, height=H, hidden=True, orientation_bins=8)[0]
    seen = orientation_channels(masks, 8).sum(axis=(1, 2))
    assert seen[0] > 0 and seen[1] > 0 and seen[7] > 0 and seen[4] > 0


def test_query_directions_agree_with_the_map():
    # LSD lines of a grey panorama drawn from the map: where a query line pixel lies on a map
    # line pixel, their direction bins agree (one bin of 8 is 22.5 degrees)
    pose = [2.1, 5.3, 1.4, 62.5]
    m = floor_plan_model(PLAN)
    img = _grey_panorama(pose, np.random.default_rng(1))
    plain = panorama_line_image(img, width=W, height=H, face_px=256, min_length=8.0)
    for bins in (4, 8):
        q = panorama_line_image(img, width=W, height=H, face_px=256, min_length=8.0, orientation_bins=bins)
        assert ((q != 0) == (plain != 0)).all()
        ref = render_panoramas(m.segments, m.faces, np.array([pose]), width=W, height=H, hidden=True,
                               orientation_bins=bins)[0]
        both = (q != 0) & (ref != 0)
        assert both.sum() > 300
        assert ((q & ref)[both] != 0).mean() > 0.93


def test_compatible_lines_wrap_at_180_degrees():
    ch = np.zeros((6, 1, 1), np.uint8)
    ch[0] = 1
    assert compatible_lines(ch, 1)[:, 0, 0].tolist() == [1, 1, 0, 0, 0, 1]
    assert compatible_lines(ch, 0)[:, 0, 0].tolist() == [1, 0, 0, 0, 0, 0]
    assert compatible_lines(ch, 3)[:, 0, 0].tolist() == [1] * 6


def _hand_case(bins):
    # one horizontal map line along row 2 (12 pixels, bin 0); two query pixels on it, at
    # column 3 horizontal (bin 0) and at column 8 vertical (bin bins / 2)
    m = np.zeros((bins, 5, 12), np.uint8)
    m[0, 2, :] = 1
    q = np.zeros((bins, 5, 12), np.uint8)
    q[0, 2, 3] = 1
    q[bins // 2, 2, 8] = 1
    return m, q


@pytest.mark.parametrize("bins,spread,expected", [(4, 1, 1 / 3), (2, 0, 1 / 3), (4, 2, 2 / 3), (1, 0, 2 / 3)])
def test_oriented_score_by_hand(bins, spread, expected):
    # tau 2 px, unit row weights, shift 0. Plain: both query pixels lie on the map line
    # (precision 1); the map pixels within one pixel of a query pixel score 0.5, on one 1
    # (columns 2-4 and 7-9: 0.5 + 1 + 0.5 twice = 4 of 12, recall 1/3): (1/3 + 1) / 2 = 2/3.
    # Oriented, the vertical query pixel is near no line of its bins (precision 1/2) and
    # the map's line is near the horizontal pixel only (2 of 12, recall 1/6): 1/3. Two
    # bins either side of four cover all of them: the plain score.
    m, q = _hand_case(max(bins, 2))
    if bins == 1:
        m, q = m.max(axis=0, keepdims=True), q.max(axis=0, keepdims=True)
    ones = np.ones(5, np.float32)
    at = chamfer_at_shifts(m[None], q, np.array([[0]]), tau_px=2.0, weights=ones, chance="none", spread=spread)
    assert at[0, 0] == pytest.approx(expected, abs=1e-6)
    table = chamfer_table(chamfer_spectra(m[None], tau_px=2.0, weights=ones, spread=spread), q[None], tau_px=2.0,
                          weights=ones, chance="none", spread=spread)
    assert table[0, 0, 0] == pytest.approx(expected, abs=1e-5)


@pytest.mark.parametrize("bins,spread", [(4, 1), (6, 1), (3, 0)])
def test_oriented_table_and_shifts_equal_the_pixel_loop(bins, spread):
    rng = np.random.default_rng(bins)
    h, w = 16, 24
    db = (rng.random((3, bins, h, w)) < 0.04).astype(np.uint8)
    q = (rng.random((bins, h, w)) < 0.04).astype(np.uint8)
    weights = row_weights(h, polar_deg=60.0, polar_weight=1.0, solid_angle=True)
    prows = precision_rows(h, 75.0)
    ref = _chamfer_reference(db, q, tau=3.0, weights=weights, prows=prows, spread=spread)
    table = chamfer_table(chamfer_spectra(db, tau_px=3.0, weights=weights, spread=spread), q[None], tau_px=3.0,
                          weights=weights, chance="none", precision_rows=prows, spread=spread)[0]
    assert np.abs(table - ref).max() < 1e-5
    shifts = np.array([[0, 5, 23], [1, 2, 3], [20, 21, 22]])
    at = chamfer_at_shifts(db, q, shifts, tau_px=3.0, weights=weights, chance="none", precision_rows=prows,
                           spread=spread)
    assert np.abs(at - np.take_along_axis(ref, shifts, axis=1)).max() < 1e-6     # float32 closeness
    with pytest.raises(ValueError, match="chance none"):
        chamfer_table(chamfer_spectra(db, tau_px=3.0, weights=weights, spread=spread), q[None], tau_px=3.0,
                      weights=weights, chance="area", spread=spread)


def _oriented(m, poses, bins):
    masks = render_panoramas(m.segments, m.faces, np.asarray(poses, float), width=W, height=H, hidden=True,
                             orientation_bins=bins)
    return orientation_channels(masks, bins)


def test_clutter_across_another_place_s_lines_wins_it_only_without_directions():
    # The query: half the true view's line pixels, and clutter lying on every line pixel of
    # another place's view but running across those lines (each pixel's bin turned by 90
    # degrees: carpet stripes crossing a floor edge, say). Without directions the other
    # place explains every clutter pixel and wins; with them only the true view explains
    # anything.
    m = floor_plan_model(PLAN)
    bins = 4
    truth, other = [1.2, 1.1, 1.4, 0.0], [2.3, 5.8, 1.4, 0.0]
    views = _oriented(m, [truth, other], bins)
    q = views[0].copy()
    q[:, :, ::2] = 0                                          # half the true view's columns lost
    q = np.maximum(q, np.roll(views[1], bins // 2, axis=0))   # clutter across the other's lines
    weights = row_weights(H, polar_deg=60.0, polar_weight=1.0, solid_angle=True)
    plain = chamfer_table(chamfer_spectra(views.max(axis=1), tau_px=3.0, weights=weights), q.max(axis=0)[None],
                          tau_px=3.0, weights=weights, chance="none")[0]
    oriented = chamfer_table(chamfer_spectra(views, tau_px=3.0, weights=weights, spread=1), q[None], tau_px=3.0,
                             weights=weights, chance="none", spread=1)[0]
    assert plain[1, 0] > plain[0, 0]
    assert oriented[0, 0] > oriented[1, 0]
    assert np.unravel_index(np.argmax(oriented), oriented.shape) == (0, 0)


def test_oriented_search_finds_off_grid_cameras_wherever_the_grid_falls():
    # Two off-grid cameras, one 0.35 m from a wall: with four direction bins the search ends
    # within 0.05 m and one yaw column of the truth for grid origins shifted by 0, 1/3, 2/3.
    from dataclasses import replace

    from placeloc.geometry.floorplan import plan_grid
    from placeloc.umap.panorama import search_panoramas
    from placeloc.umap.params import PanoramaParams

    m = floor_plan_model(PLAN)
    bins = 4
    truth = np.array([[5.65, 1.37, 1.4, 117.5], [0.35, 5.52, 1.4, 250.0]])
    q = _oriented(m, truth, bins)
    q[..., ::3, ::4] = 0                                      # a few line pixels lost
    pp = replace(PanoramaParams(), orientation_bins=bins)
    wts = row_weights(H, polar_deg=pp.polar_deg, polar_weight=pp.polar_weight, solid_angle=pp.solid_angle)
    for frac in (0.0, 1 / 3, 2 / 3):
        start = 0.1 + frac * 0.3
        poses, _ = plan_grid(m, x=[start, 6.0, 0.3], y=[start, 7.0, 0.3], z=1.4, headings=[0.0])
        db = {"spectra": chamfer_spectra(_oriented(m, poses, bins), tau_px=pp.chamfer_tau_px, weights=wts,
                                         spread=pp.orientation_spread)}
        _, xy, hd, *_ = search_panoramas(q, poses, m.segments, m.faces, db, pp, tolerance_px=2, wall_margin_m=0.1,
                                        hidden=True)
        assert np.hypot(*(xy - truth[:, :2]).T).max() <= 0.05, frac
        assert np.abs((hd - truth[:, 3] + 180) % 360 - 180).max() <= 2.5, frac


@pytest.mark.parametrize("bins,spread", [(2, 0), (4, 1), (6, 2), (8, 1), (3, 3)])
def test_oriented_closeness_from_bitmasks_equals_the_channels_closeness(bins, spread):
    from placeloc.umap.panorama import closeness, oriented_closeness

    rng = np.random.default_rng(bins + spread)
    ch = (rng.random((3, bins, 12, 20)) < 0.05).astype(np.uint8)
    ch[0, :, :, 0] = 1                                          # lines on the seam
    fast = oriented_closeness(ch, 3.0, spread)
    slow = closeness(compatible_lines(ch, spread), 3.0)
    assert fast.shape == ch.shape and (fast == slow).all()
    assert (oriented_closeness(ch.astype(np.float32), 3.0, spread) == slow).all()


def test_the_renderer_s_direction_bins_equal_the_arctangent_s():
    from placeloc.geometry.panorama import orientation_bit_fast

    rng = np.random.default_rng(5)
    for bins in (2, 3, 4, 6, 8):
        bound = (np.arange(bins) + 0.5) * np.pi / bins
        for du, dv in rng.normal(size=(400, 2)):
            assert orientation_bit_fast(du, dv, bins, np.cos(bound), np.sin(bound)) == orientation_bit(du, dv, bins)


def test_the_oriented_score_with_a_chance_correction_is_refused_with_the_keys_named(tmp_path):
    import yaml

    from placeloc.core.config import ConfigError, load_config
    from placeloc.core.methods import get_method

    (tmp_path / "plan.yaml").write_text(yaml.safe_dump(PLAN))
    (tmp_path / "q").mkdir()
    data = {"method": "umap", "query": {"images": str(tmp_path / "q")},
            "umap": {"model": str(tmp_path / "plan.yaml"), "query_kind": "panorama",
                     "panorama": {"chamfer_chance": "area"}}}
    with pytest.raises(ConfigError, match="orientation_bins.*chamfer_chance none"):
        get_method("umap").check(load_config(data=data, base_dir=tmp_path))
    data["umap"]["panorama"]["orientation_bins"] = 1                    # the plain score takes any chance
    get_method("umap").check(load_config(data=data, base_dir=tmp_path))


def _shifts_in_kernel_order(masks, query, shifts, *, tau, weights, spread, prows):
    """The local oriented halves the way the search computed them before its own-bin
    stamping: each map's closeness to the compatible bins' lines stamped whole
    (``oriented_closeness_of_masks``), then summed in the kernel's order in float64, so that
    the two agree to the bit."""
    from placeloc.umap.panorama import channel_masks, oriented_closeness_of_masks, stack_channels

    b, h, w = query.shape
    m_close = oriented_closeness_of_masks(masks, b, tau, spread)                   # (L, B, H, W) float32
    q_close = stack_channels(oriented_closeness_of_masks(channel_masks(query), b, tau, spread))
    qs = stack_channels(query)
    rows, cols = np.nonzero(qs)
    vals = [float(qs[r, c]) * float(prows[r % h]) for r, c in zip(rows, cols)]
    nq = 0.0
    for r, v in zip(rows, vals):
        nq += float(weights[r % h]) * v
    out = np.zeros(shifts.shape)
    for i in range(len(masks)):
        rec, n_map = [0.0] * shifts.shape[1], 0.0
        for y in range(h):
            wr = float(weights[y])
            for x in range(w):
                for c in range(b):
                    if (int(masks[i, y, x]) >> c) & 1:
                        n_map += wr
                        for s, k in enumerate(shifts[i]):
                            rec[s] += wr * float(q_close[c * h + y, (x + k) % w])
        pre = [0.0] * shifts.shape[1]
        for r, c, v in zip(rows, cols, vals):
            ch, y = divmod(int(r), h)
            for s, k in enumerate(shifts[i]):
                pre[s] += float(weights[y]) * v * float(m_close[i, ch, y, (c - k) % w])
        for s in range(shifts.shape[1]):
            out[i, s] = 0.5 * ((rec[s] / n_map if n_map > 0 else 0.0) + (pre[s] / nq if nq > 0 else 0.0))
    return out


@pytest.mark.parametrize("bins,spread", [(6, 1), (4, 1), (3, 0), (5, 2), (8, 3)])
def test_the_local_scores_stamping_own_bins_equal_the_compatible_closeness_to_the_bit(bins, spread):
    # The local search stamps each map element into its own bin's channel and reads the
    # largest of the compatible channels at the query's elements; a maximum is exact, so
    # this equals stamping every compatible channel, bit for bit.
    from placeloc.umap.panorama import oriented_at_shifts

    rng = np.random.default_rng(10 * bins + spread)
    h, w = 12, 20
    masks = (rng.random((4, h, w)) < 0.12) * rng.integers(1, 1 << bins, (4, h, w))   # several bins a pixel
    masks[0, :, 0] |= 1                                        # lines on the seam
    masks[1, :, w - 1] |= 1 << (bins - 1)
    masks = masks.astype(np.uint8)
    query = (rng.random((bins, h, w)) < 0.06).astype(np.uint8)
    query[0, :, 1] = 1
    weights = row_weights(h, polar_deg=60.0, polar_weight=0.5, solid_angle=True)
    prows = precision_rows(h, 75.0)
    shifts = rng.integers(0, w, (4, 5))
    shifts[0] = [0, 1, 2, w - 2, w - 1]
    got = oriented_at_shifts(masks, query, shifts, tau_px=3.0, weights=weights, spread=spread, precision_rows=prows)
    ref = _shifts_in_kernel_order(masks, query, shifts, tau=3.0, weights=weights, spread=spread, prows=prows)
    assert (got == ref).all()
    # the query's elements made once and passed in, as the local search does, give the same bits
    from placeloc.umap.panorama import oriented_query_pixels

    kept = oriented_query_pixels(query, prows)
    for _ in range(2):   # the kept stamp (_rank_stamp) is read, not written, by a call
        again = oriented_at_shifts(masks, query, shifts, tau_px=3.0, weights=weights, spread=spread,
                                   precision_rows=prows, query_pixels=kept)
        assert (again == ref).all()


def test_the_render_cache_renders_each_point_once_and_returns_the_fresh_renders():
    from placeloc.umap.panorama import RenderCache

    m = floor_plan_model(PLAN)

    def render(pts):
        local = np.column_stack([pts, np.full(len(pts), 1.4), np.zeros(len(pts))])
        return render_panoramas(m.segments, m.faces, local, width=W, height=H, hidden=True, orientation_bins=6)

    a, b, c = [1.2, 1.1], [2.3, 5.8], [1.2 + 1e-15, 1.1]    # c: a by less than a micron, not the same point
    cache = RenderCache(render)
    pts = np.array([a, b, a, c])
    got = cache(pts)
    assert (got == render(pts)).all()
    assert (cache.rendered, cache.reused) == (3, 1)          # a's repeat in the same call reused
    again = cache(np.array([b, a]))
    assert (again == render(np.array([b, a]))).all() and (cache.rendered, cache.reused) == (3, 3)
    # past max_bytes the oldest renders go: with room for two, the third evicts a
    small = RenderCache(render, max_bytes=2 * H * W)
    small(np.array([a, b])), small(np.array([c]))
    assert small.bytes <= 2 * H * W and len(small.kept) == 2
    small(np.array([a]))
    assert small.rendered == 4


def test_a_query_s_table_is_the_same_whatever_batch_it_is_scored_in():
    # The search scores its queries in batches (one matrix product per frequency for the
    # whole batch); each query's column of the product is its own dot products, so its
    # table does not depend on the batch it came in (a lone query is scored beside a zero
    # one: numpy's product of a single column rounds differently): the answers do not
    # depend on the batch size.
    rng = np.random.default_rng(3)
    bins, h, w = 6, 12, 24
    db = (rng.random((40, bins, h, w)) < 0.05).astype(np.uint8)
    q = (rng.random((5, bins, h, w)) < 0.05).astype(np.uint8)
    weights = row_weights(h, polar_deg=60.0, polar_weight=1.0, solid_angle=True)
    spectra = chamfer_spectra(db, tau_px=3.0, weights=weights, spread=1)

    def table(queries):
        return chamfer_table(spectra, queries, tau_px=3.0, weights=weights, chance="none",
                             precision_rows=precision_rows(h, 75.0), spread=1)

    whole = table(q)
    assert (np.concatenate([table(q[:2]), table(q[2:])]) == whole).all()
    assert (np.concatenate([table(q[:4]), table(q[4:])]) == whole).all()
    assert all((table(q[k:k + 1])[0] == whole[k]).all() for k in range(len(q)))
