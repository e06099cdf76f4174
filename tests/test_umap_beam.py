"""Known answers for the beam of whole-panorama localization (``umap.panorama.refine_beam``
and ``refine_beam_within``): which poses go on from the cell stage, by hand, and the search's
answers with the beam cut to the places that can still win the same as with the whole beam,
from fewer renders."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from test_umap_final_search import NEAR_TWINS, _answers_by_origin
from test_umap_panorama import PLAN, _render_all

import placeloc.umap.panorama as panorama
from placeloc.geometry.floorplan import floor_plan_model
from placeloc.umap.panorama import beam_of
from placeloc.umap.params import PanoramaParams


def test_beam_of_by_hand():
    # five poses after the cell stage: the best 0.52 (index 2), then 0.51 (4), 0.50 (0),
    # 0.48 (1), 0.40 (3)
    scores = np.array([0.50, 0.48, 0.52, 0.40, 0.51])
    assert beam_of(scores, size=4, within=0.0).tolist() == [2, 4, 0, 1]       # the 4 best, best first
    assert beam_of(scores, size=4, within=0.03).tolist() == [2, 4, 0]         # 0.48 < 0.52 - 0.03
    assert beam_of(scores, size=2, within=0.5).tolist() == [2, 4]             # never more than size
    assert beam_of(scores, size=4, within=0.001).tolist() == [2]              # the best always goes on
    # equal scores: the first of equals first, as np.argsort(kind="stable") ranks them
    assert beam_of(np.array([0.5, 0.6, 0.6, 0.5]), size=3, within=0.0).tolist() == [1, 2, 0]
    assert beam_of(np.zeros(0), size=4, within=0.05).tolist() == []


def _counting_renders(monkeypatch):
    """The number of poses the local search renders, counted from here on."""
    count = [0]
    render = panorama.render_panoramas

    def counted(segments, faces, poses, **kw):
        count[0] += len(poses)
        return render(segments, faces, poses, **kw)

    monkeypatch.setattr(panorama, "render_panoramas", counted)
    return count


def test_cut_beam_gives_the_whole_beams_answers_from_fewer_renders(monkeypatch):
    # Cameras in the L-shaped room and in the near-twin rooms (one door 0.15 m wider: a place
    # 3.2 m east nearly ties), grids at two origins. With the default (only the poses within
    # 0.05 of the cell stage's best go on) every answer is the whole beam's, to the bit, and the
    # local search renders a fifth fewer poses (5,573 against 6,997, measured).
    count = _counting_renders(monkeypatch)
    scenes = [(floor_plan_model(PLAN), np.array([[5.653, 1.374, 1.4, 117.5], [0.347, 5.516, 1.4, 250.0],
                                                 [1.234, 2.871, 1.4, 75.0]]), 0.1, (6.0, 7.0)),
              (floor_plan_model(NEAR_TWINS), np.array([[1.801, 1.858, 1.5, 221.5], [0.994, 0.457, 1.5, 138.1],
                                                      [2.189, 1.867, 1.5, 246.8]]), 0.15, (6.2, 2.5))]
    renders = {}
    for m, truth, start, end in scenes:
        q = _render_all(m, truth)
        q[:, ::3, ::4] = 0                                # a few line pixels lost
        answers = {}
        for within in (0.0, PanoramaParams().refine_beam_within):
            count[0] = 0
            pp = replace(PanoramaParams(), orientation_bins=1, refine_beam_within=within)
            answers[within] = _answers_by_origin(m, q, {within: pp}, start=start, end=end, z=truth[0, 2],
                                                 fracs=(0.0, 0.55))[within]
            renders[within] = renders.get(within, 0) + count[0]
        whole, cut = answers.values()
        assert np.array_equal(whole, cut)
    assert PanoramaParams().refine_beam_within == 0.05
    assert renders[0.05] < 0.85 * renders[0.0]
