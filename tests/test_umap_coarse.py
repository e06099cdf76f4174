"""Known answers for candidates chosen by a tolerant score (``umap.panorama.coarse_candidates``):
the tolerant table against a pixel loop built on OpenCV's distance transform, its blur and
the candidate choice by hand, and a search whose truth's cell only the tolerant score ranks
among the candidates."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_umap_panorama import PLAN, H, W, _chamfer_reference, _render_all, search_answer

from placeloc.geometry.floorplan import floor_plan_model, plan_grid
from placeloc.umap.panorama import (
    box_blur,
    chamfer_spectra,
    chamfer_table,
    coarse_to_fine_candidates,
    distinct_candidates,
    precision_rows,
    row_weights,
    search_panoramas,
    tolerant_bands,
    tolerant_chamfer_table,
)
from placeloc.umap.params import PanoramaParams


def test_box_blur_by_hand():
    img = np.zeros((4, 6), np.float32)
    img[0, 0] = 9.0                 # a corner: the square crosses the seam and the pole
    img[2, 3] = 9.0
    out = box_blur(img, 1)
    # the corner's 9 spread as 1 over its square: rows 0-1, columns 5, 0, 1; row -1 lost
    want = np.zeros((4, 6), np.float32)
    for y, x in ((0, 5), (0, 0), (0, 1), (1, 5), (1, 0), (1, 1)):
        want[y, x] += 1.0
    want[1:4, 2:5] += 1.0           # the inner pixel: its whole square
    assert np.allclose(out, want)
    assert np.array_equal(box_blur(img, 0), img)


def test_coarse_to_fine_candidates_by_hand():
    # six places on a line 0.25 m apart and one far; best per row (over two shifts), exact:
    # 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.85 -> order 0, 6, 1, 2, 3, 4, 5; tolerant: row 3 best,
    # then 2, 4, 0, 6, 1, 5
    xy = np.array([[0.0, 0.0], [0.25, 0.0], [0.5, 0.0], [0.75, 0.0], [1.0, 0.0], [1.25, 0.0], [9.0, 0.0]])
    exact = np.array([[0.9, 0.1], [0.8, 0.0], [0.1, 0.7], [0.6, 0.6], [0.5, 0.2], [0.4, 0.0], [0.0, 0.85]])
    tolerant = np.array([[0.6, 0.0], [0.4, 0.0], [0.8, 0.0], [0.9, 0.1], [0.0, 0.7], [0.3, 0.0], [0.5, 0.0]])
    # 0.3 m apart. No tolerant share: the exact choice (0, 6, then 2 as 1 is 0.25 m from 0, then 4)
    assert coarse_to_fine_candidates(exact, tolerant, xy, count=4, coarse=0, min_separation_m=0.3).tolist() == \
        distinct_candidates(exact, xy, count=4, min_separation_m=0.3).tolist() == [0, 6, 2, 4]
    # two by the exact table (0, 6), then the tolerant's order: 3 (0.75 m from 0), 2 (0.25 m from 3:
    # out), 4 (0.25 m from 3: out), 0 and 6 (taken), 1 (0.25 m from 0: out), 5 (0.5 m from 3)
    assert coarse_to_fine_candidates(exact, tolerant, xy, count=4, coarse=2, min_separation_m=0.3).tolist() == [0, 6, 3, 5]
    # all by the tolerant table: 3, 0 (0.75 m from 3), 6, 5
    assert coarse_to_fine_candidates(exact, tolerant, xy, count=4, coarse=4, min_separation_m=0.3).tolist() == [3, 0, 6, 5]
    assert coarse_to_fine_candidates(exact, tolerant, xy, count=4, coarse=9, min_separation_m=0.3).tolist() == [3, 0, 6, 5]
    # more than there are distinct places: 6 of 9 by the exact table give its 4 distinct places
    # (0, 6, 2, 4; 5 is 0.25 m from 4), and no place of the tolerant order is 0.3 m from all of them
    got = coarse_to_fine_candidates(exact, tolerant, xy, count=9, coarse=3, min_separation_m=0.3)
    assert got.tolist() == [0, 6, 2, 4]


def test_tolerant_bands_by_hand():
    # 144 columns: 8 px -> 144 / 8 = 18 cycles, 19 frequencies with 0; 3 px -> 49 of 73; a
    # tolerance under 2 px would keep more than there are: all
    assert tolerant_bands(144, 8.0) == 19
    assert tolerant_bands(144, 3.0) == 49
    assert tolerant_bands(144, 1.5) == 73


@pytest.mark.parametrize("bins,spread", [(1, None), (4, 1), (3, 0)])
def test_tolerant_table_equals_the_pixel_loop(bins, spread):
    rng = np.random.default_rng(7 + bins)
    h, w = 16, 24
    db = (rng.random((3, bins, h, w)) < 0.05).astype(np.uint8)
    q = (rng.random((bins, h, w)) < 0.05).astype(np.uint8)
    q[0, 0, 0] = q[0, h - 1, w - 1] = 1                # at the poles and the seam
    weights = row_weights(h, polar_deg=60.0, polar_weight=1.0, solid_angle=True)
    prows = precision_rows(h, 75.0)
    plain = spread is None
    spectra = chamfer_spectra(db[:, 0] if plain else db, tau_px=3.0, weights=weights, spread=spread)
    queries = q if plain else q[None]                  # plain: (1, H, W); oriented: (1, B, H, W)
    for recall_tau, blur in ((5.5, 2), (8.0, 1), (3.0, 3)):
        ref = _chamfer_reference(db, q, tau=3.0, recall_tau=recall_tau, blur=blur, weights=weights, prows=prows,
                                  spread=0 if plain else spread)
        table = tolerant_chamfer_table(spectra, queries, recall_tau_px=recall_tau, blur_px=blur, weights=weights,
                                       precision_rows=prows, spread=spread)[0]
        assert np.abs(table - ref).max() < 1e-5, (recall_tau, blur)
        # the lowest 4 column frequencies only: the reference low-passed over the shifts
        low = np.fft.rfft(ref, axis=1)
        low[:, 4:] = 0
        banded = tolerant_chamfer_table(spectra, queries, recall_tau_px=recall_tau, blur_px=blur, weights=weights,
                                        precision_rows=prows, spread=spread, bands=4)[0]
        assert np.abs(banded - np.fft.irfft(low, n=w, axis=1)).max() < 1e-5, (recall_tau, blur)
    # the exact score's own tolerance and no blur: the exact table
    exact = chamfer_table(spectra, queries, tau_px=3.0, weights=weights, chance="none", precision_rows=prows,
                          spread=spread)
    same = tolerant_chamfer_table(spectra, queries, recall_tau_px=3.0, blur_px=0, weights=weights, precision_rows=prows,
                                  spread=spread)
    assert np.abs(same - exact).max() < 1e-6


def test_the_tolerant_choice_finds_the_truth_s_cell_the_exact_one_misses():
    # The L-shaped room on a grid of 1 m steps: the cell stage, the beam's steps and the
    # separation scale with the step, so a camera between grid points is 0.3-0.7 m from
    # them, as a camera near a wall is 0.1 m from the grid points of the default 0.25 m steps
    # (its views there move the near wall's lines by several pixels). At the truth T (4.8,
    # 2.78), heading 168 deg, the exact table ranks T's cell (the grid point (5.1, 3.1), 0.44 m
    # away) 5th, below four places in the room's west half (x 1.1 and 3.1); the tolerant table
    # (8 px, blur 2 px: the defaults of coarse_tau_px and coarse_blur_px; 19 bands, as the
    # search computes it) ranks it 2nd.
    # Measured: with 2 candidates, both by the exact table, the answer is 3.92 m off at a
    # heading 178 deg away; with the 2nd, or both, by the tolerant table, 0.017 m off.
    m = floor_plan_model(PLAN)
    truth = np.array([[4.8, 2.78, 1.4, 168.0]])
    q = _render_all(m, truth)
    poses, _ = plan_grid(m, x=[0.1, 6.0, 1.0], y=[0.1, 7.0, 1.0], z=1.4, headings=[0.0])
    pp = replace(PanoramaParams(), orientation_bins=1, refine_candidates=2)
    wts = row_weights(H, polar_deg=pp.polar_deg, polar_weight=pp.polar_weight, solid_angle=pp.solid_angle)
    prows = precision_rows(H, pp.precision_polar_deg)
    db = {"spectra": chamfer_spectra(_render_all(m, poses), tau_px=pp.chamfer_tau_px, weights=wts)}
    exact = chamfer_table(db["spectra"], q, tau_px=pp.chamfer_tau_px, weights=wts, chance="none", precision_rows=prows)[0]
    tolerant = tolerant_chamfer_table(db["spectra"], q, recall_tau_px=pp.coarse_tau_px, blur_px=pp.coarse_blur_px,
                                      weights=wts, precision_rows=prows, bands=tolerant_bands(W, pp.coarse_tau_px))[0]
    cell = int(np.flatnonzero(np.abs(poses[:, :2] - truth[0, :2]).max(axis=1) <= 0.5)[0])   # the grid point whose cell holds T

    def rank_of_cell(table):
        return distinct_candidates(table, poses[:, :2], count=len(poses),
                                   min_separation_m=pp.refine_separation_m).tolist().index(cell) + 1

    # the premise: the exact table ranks T's cell below 2 distinct places, the tolerant one not
    assert rank_of_cell(exact) == 5 and rank_of_cell(tolerant) == 2

    def answer(coarse):
        return search_answer(q, poses, m, db, replace(pp, coarse_candidates=coarse), truth[0], 168.0)

    off, yaw, before = answer(0)
    assert off > 3.0 and abs(yaw) > 90
    for coarse in (1, 2):
        off, yaw, after = answer(coarse)
        assert off <= 0.05 and abs(yaw) <= 2.5, coarse
        # the answer's score is the exact score, higher than the wrong answer's
        assert after > before + 0.1
    # a chance-corrected score has no tolerant form here: every candidate by the exact table
    area = [search_panoramas(q, poses, m.segments, m.faces, db, replace(pp, chamfer_chance="area", coarse_candidates=c),
                             tolerance_px=2, wall_margin_m=0.1, hidden=True) for c in (0, 2)]
    assert np.array_equal(area[0].xy, area[1].xy) and np.array_equal(area[0].score, area[1].score)
    # chosen on generated homes (docs/umap.md, "Candidates by a tolerant score")
    assert PanoramaParams().coarse_candidates == 8
