"""Known answers for the weight of the chamfer score's two halves
(``umap.panorama.recall_weight``): by hand, every table and local score against the pixel
loop, and the chance-corrected halves mixed after their correction."""

from __future__ import annotations

import numpy as np
import pytest
from test_umap_oriented import _hand_case
from test_umap_panorama import _chamfer_reference

from placeloc.umap.panorama import (
    chamfer_at_shifts,
    chamfer_spectra,
    chamfer_table,
    halves_mixed,
    precision_rows,
    row_weights,
    tolerant_chamfer_table,
)


@pytest.mark.parametrize("bins,spread,recall,precision", [(4, 1, 1 / 6, 1 / 2), (1, 0, 1 / 3, 1.0)])
@pytest.mark.parametrize("weight", [0.0, 0.25, 0.5, 1.0])
def test_mixed_halves_by_hand(bins, spread, recall, precision, weight):
    # the hand case of test_umap_oriented: plain, recall 4 of 12 map pixels' closeness
    # (1/3) and precision 1; oriented (4 bins, spread 1), recall 1/6 and precision 1/2
    m, q = _hand_case(max(bins, 2))
    if bins == 1:
        m, q = m.max(axis=0, keepdims=True), q.max(axis=0, keepdims=True)
    ones = np.ones(5, np.float32)
    expected = weight * recall + (1 - weight) * precision
    at = chamfer_at_shifts(m[None], q, np.array([[0]]), tau_px=2.0, weights=ones, chance="none", spread=spread,
                           recall_weight=weight)
    assert at[0, 0] == pytest.approx(expected, abs=1e-6)
    table = chamfer_table(chamfer_spectra(m[None], tau_px=2.0, weights=ones, spread=spread), q[None], tau_px=2.0,
                          weights=ones, chance="none", spread=spread, recall_weight=weight)
    assert table[0, 0, 0] == pytest.approx(expected, abs=1e-5)


@pytest.mark.parametrize("bins,spread", [(1, None), (6, 1)])
def test_every_score_of_the_search_mixes_the_halves_as_the_pixel_loop(bins, spread):
    rng = np.random.default_rng(30 + bins)
    h, w = 16, 24
    db = (rng.random((3, bins, h, w)) < 0.05).astype(np.uint8)
    q = (rng.random((bins, h, w)) < 0.05).astype(np.uint8)
    weights = row_weights(h, polar_deg=60.0, polar_weight=1.0, solid_angle=True)
    prows = precision_rows(h, 75.0)
    plain = spread is None
    spectra = chamfer_spectra(db[:, 0] if plain else db, tau_px=3.0, weights=weights, spread=spread)
    queries = q if plain else q[None]
    shifts = np.array([[0, 5, 23], [1, 2, 3], [20, 21, 22]])
    for weight in (0.2, 0.4, 0.75):
        ref = _chamfer_reference(db, q, tau=3.0, weights=weights, prows=prows, spread=0 if plain else spread,
                                 recall_weight=weight)
        table = chamfer_table(spectra, queries, tau_px=3.0, weights=weights, chance="none", precision_rows=prows,
                              spread=spread, recall_weight=weight)[0]
        assert np.abs(table - ref).max() < 1e-5, weight
        at = chamfer_at_shifts(db[:, 0] if plain else db, q[0] if plain else q, shifts, tau_px=3.0, weights=weights,
                               chance="none", precision_rows=prows, spread=spread, recall_weight=weight)
        assert np.abs(at - np.take_along_axis(ref, shifts, axis=1)).max() < 1e-6, weight
        tolerant = _chamfer_reference(db, q, tau=3.0, recall_tau=6.0, blur=1, weights=weights, prows=prows,
                                      spread=0 if plain else spread, recall_weight=weight)
        got = tolerant_chamfer_table(spectra, queries, recall_tau_px=6.0, blur_px=1, weights=weights,
                                     precision_rows=prows, spread=spread, recall_weight=weight)[0]
        assert np.abs(got - tolerant).max() < 1e-5, weight


def test_chance_corrected_halves_are_mixed_after_their_correction():
    # area and yaw: each half corrected for chance, then mixed; the table and the local
    # scores agree, and with all weight on one half the score is that half alone
    rng = np.random.default_rng(12)
    h, w = 12, 20
    db = (rng.random((4, h, w)) < 0.05).astype(np.uint8)
    q = (rng.random((h, w)) < 0.06).astype(np.uint8)
    wts = row_weights(h, polar_deg=60.0, polar_weight=0.3, solid_angle=False)
    sp = chamfer_spectra(db, tau_px=3.0, weights=wts)
    shifts = rng.integers(0, w, size=(4, 3))
    for chance in ("area", "yaw"):
        def table(weight: float, chance: str = chance) -> np.ndarray:
            return chamfer_table(sp, q[None], tau_px=3.0, weights=wts, chance=chance, recall_weight=weight)[0]

        recall, precision = table(1.0), table(0.0)
        assert np.abs(table(0.3) - halves_mixed(recall, precision, 0.3)).max() < 1e-5, chance
        assert np.abs(table(0.5) - 0.5 * (recall + precision)).max() < 1e-5, chance
        at = chamfer_at_shifts(db, q, shifts, tau_px=3.0, weights=wts, chance=chance, recall_weight=0.3)
        assert np.abs(at - np.take_along_axis(table(0.3), shifts, axis=1)).max() < 1e-4, chance
    assert not np.allclose(recall, precision)       # the halves differ, so the mix is tested



def test_the_weight_is_chosen_by_the_homes_rule():
    from placeloc.experiments.umap_halves import MEAN
    from placeloc.experiments.umap_setting import choose

    def choose_weight(got, origins):
        return choose(got, origins, MEAN)

    # two homes at two origins each: one panorama of one home is 1 / 40 of the mean of the
    # homes' worst origins
    def got(shares, moved=()):
        answers = {(0, "still.png"): [(1.0, 1.0), (1.0, 1.0)]}
        answers.update({(0, f): [(0.0, 0.0), (0.0, d)] for f, d in moved})
        return {"shares": shares, "wrong": 0, "answers": answers}

    best = got([1.0, 1.0, 0.95, 1.0])                 # worst origins 1.0 and 0.95: mean 0.975
    one_less = got([1.0, 0.95, 0.95, 0.95])           # 0.95: within one panorama of one home
    far = got([0.9, 0.9, 0.9, 0.9])
    assert choose_weight({0.3: far, 0.4: best, 0.5: one_less}, origins=2) == 0.5   # the halves' mean
    assert choose_weight({0.3: far, 0.4: best, 0.5: far}, origins=2) == 0.4
    # within the band, fewer answers moving with the origin first, then the nearer to 0.5
    moving = got([1.0, 1.0, 0.95, 1.0], moved=[("a.png", 0.2)])
    assert choose_weight({0.4: moving, 0.6: one_less}, origins=2) == 0.6
    assert choose_weight({0.4: best, 0.6: one_less}, origins=2) == 0.4
    assert choose_weight({0.45: best, 0.6: best}, origins=2) == 0.45


def test_the_default_changes_only_where_the_chosen_weight_holds_on_the_test_homes():
    from placeloc.experiments.umap_halves import HALVES
    from placeloc.experiments.umap_setting import verdict as setting_verdict

    def verdict(chosen, test, origins):
        return setting_verdict(HALVES, chosen, test, origins)

    def got(shares):
        return {"shares": shares, "wrong": 0, "answers": {}}

    # the full run's test homes (five homes, five origins): 0.4 worst origins 95 / 95 / 100 /
    # 100 / 90 %, the mean 100 / 95 / 100 / 100 / 100 %
    four = got([.95, 1, 1, 1, 1] + [.95] * 5 + [1] * 5 + [1] * 5 + [.95, .95, .95, .9, .95])
    mean = got([1] * 5 + [.95] * 5 + [1] * 15)
    assert verdict(0.4, {0.4: four, 0.5: mean}, origins=5).endswith("worse than the halves' mean by the same "
                                                                        "measure: the default stays 0.5.")
    assert verdict(0.4, {0.4: mean, 0.5: four}, origins=5).endswith("the default is 0.4.")
    assert verdict(0.4, {0.4: mean, 0.5: mean}, origins=5).endswith("the default is 0.4.")     # a tie holds
    assert verdict(0.5, {0.5: mean}, origins=5) == "The rule chose the halves' mean itself: the default stays 0.5."


def test_each_setting_experiment_sweeps_from_the_parameters_default():
    # umap-halves, umap-lines and umap-contrast compare against the default a user gets:
    # their Setting's default is the parameter's, and the sweeps (full and quick) include it
    from placeloc.experiments.umap_contrast import CONTRAST
    from placeloc.experiments.umap_halves import HALVES
    from placeloc.experiments.umap_lines import LINES
    from placeloc.umap.params import PanoramaParams

    for setting in (HALVES, LINES, CONTRAST):
        assert getattr(PanoramaParams(), setting.key) == setting.default, setting.key
        assert setting.default in setting.values and set(setting.quick) <= set(setting.values), setting.key
