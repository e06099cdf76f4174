"""``placeloc experiment umap-halves``: the weight of the chamfer score's two halves
(``umap.panorama.recall_weight``), chosen on development homes and checked on test homes.

The whole-panorama score mixes a recall half (the map's drawn lines near the photo's) and a
precision half (the photo's lines near the map's), by default their mean (0.5). A sparse
view earns recall easily (few drawn lines, each near something), a busy one precision (many
drawn lines for clutter to fall near), so the mean is one choice among many. This
experiment asks whether another weight places more photos, and whether that holds on homes
it was not chosen on:

1. Development homes (``placeloc synth home``, seeds 0-12, 20 panoramas each; more than the
   three of ``placeloc experiment umap-homes``, where the defaults already place all but one
   panorama and one panorama decides), each at the five grid origins of that experiment:
   every weight of :data:`WEIGHTS`, the rest the defaults. The rule of ``umap-homes``
   chooses: the highest mean over the homes of each home's worst origin; among weights
   within one panorama of one home of it, the one whose answers move least with the grid's
   origin, then the one nearest 0.5 (the halves' mean, the plainer).
2. Test homes (seeds 20-24, those of ``umap-homes``) at the same origins: the chosen weight
   and 0.5. The default changes only where the chosen weight does at least as well there
   (a change must hold where it was not chosen); the table says which.

Every weight of a home and origin shares one run folder (the weight is a localize key), so
the map is drawn and indexed once. Writes ``OUT/table.md`` and ``OUT/summary.json``.
"""

from __future__ import annotations

import csv
import logging
from pathlib import Path
from typing import Any

import numpy as np

from placeloc.core.safe_io import read_run_table
from placeloc.experiments import write_summary
from placeloc.experiments.umap_homes import (
    ORIGINS,
    PANORAMAS,
    TEST_SEEDS,
    _drop_index,
    _home,
    _run,
    answer_moves,
    near_the_best,
    within_goal,
    worst_origin_mean,
)

log = logging.getLogger("placeloc")

DEV_SEEDS = tuple(range(13))
WEIGHTS = (0.3, 0.4, 0.45, 0.5, 0.6)
MEAN = 0.5                      # the halves' mean: the score before the weight, and its default


def _right(run_dir: Path) -> dict[str, tuple[bool, tuple[float, float]]]:
    """frame -> (within 1 m and 30 degrees, the answered plan position), from a run's
    per_query.csv."""
    return {r["frame"]: (within_goal(r), (float(r["x"]), float(r["y"])))
            for r in csv.DictReader(read_run_table(run_dir, "per_query.csv"))}


def _sweep(out_dir: Path, seeds: tuple[int, ...], origins: tuple[float, ...], weights: tuple[float, ...], group: str,
           quiet: bool, runs: dict[str, dict[str, Any]]) -> dict[float, dict[str, Any]]:
    """Each weight on each home and origin: weight -> shares (home by home, each origin),
    wrong answers, and the answers' positions per (home, frame) over the origins."""
    got: dict[float, dict[str, Any]] = {w: {"shares": [], "wrong": 0, "answers": {}} for w in weights}
    for seed in seeds:
        data = _home(out_dir, seed)
        for i, frac in enumerate(origins):
            folder = f"{group}-home{seed}-origin{i}"
            for w in weights:
                m = _run(out_dir, folder, data, {"recall_weight": w}, frac, quiet)
                runs[f"{folder}-recall{w:g}"] = m
                got[w]["shares"].append(float(m["within_1m_30deg"]))
                for frame, (right, xy) in _right(out_dir / folder).items():
                    got[w]["wrong"] += not right
                    got[w]["answers"].setdefault((seed, frame), []).append(xy)
            _drop_index(out_dir / folder)
    return got


def choose_weight(got: dict[float, dict[str, Any]], origins: int) -> float:
    """The rule of the module docstring over :func:`_sweep`'s results (``origins`` runs a home)."""
    near = near_the_best({w: g["shares"] for w, g in got.items()}, origins)
    return min(near, key=lambda w: (answer_moves(got[w]["answers"]), abs(w - MEAN), w))


def _row(label: str, g: dict[str, Any], origins: int) -> str:
    shares = np.asarray(g["shares"], float).reshape(-1, origins)
    perfect = int((shares.min(axis=1) == 1.0).sum())
    moves = answer_moves(g["answers"])
    return (f"| {label} | {shares.mean():.2%} | {shares.min():.0%} | {worst_origin_mean(g['shares'], origins):.2%} | "
            f"{perfect} of {len(shares)} | {g['wrong']} | {moves[0]} / {moves[1]} |")


def verdict(chosen: float, test: dict[float, dict[str, Any]], origins: int) -> str:
    """The table's last line: the default the test homes leave (module docstring, 2): the
    chosen weight where its mean of each home's worst origin there is at least the halves'
    mean's, else the mean."""
    if chosen == MEAN:
        return f"The rule chose the halves' mean itself: the default stays {MEAN:g}."
    holds = worst_origin_mean(test[chosen]["shares"], origins) >= worst_origin_mean(test[MEAN]["shares"], origins) - 1e-12
    return (f"On the test homes the chosen weight does {'at least as well as' if holds else 'worse than'} the halves' "
            f"mean by the same measure: the default " + (f"is {chosen:g}." if holds else f"stays {MEAN:g}."))


HEAD = ["| recall weight | mean share | worst run | mean of each home's worst origin | homes right at every origin "
        "| wrong answers | answers moving > 0.1 / 0.05 m |", "|---|---|---|---|---|---|---|"]


def main(out_dir: Path, quick: bool = False, quiet: bool = False) -> Path:
    out_dir = Path(out_dir).resolve()
    dev_seeds, test_seeds = (DEV_SEEDS[:2], TEST_SEEDS[:1]) if quick else (DEV_SEEDS, TEST_SEEDS)
    origins = ORIGINS[:2] if quick else ORIGINS
    weights = (0.4, MEAN) if quick else WEIGHTS
    runs: dict[str, dict[str, Any]] = {}
    dev = _sweep(out_dir, dev_seeds, origins, weights, "dev", quiet, runs)
    chosen = choose_weight(dev, len(origins))
    test = _sweep(out_dir, test_seeds, origins, tuple(sorted({chosen, MEAN})), "test", quiet, runs)
    write_summary(out_dir, runs)
    per = len(dev_seeds) * len(origins) * PANORAMAS
    lines = [f"Development homes (seeds {dev_seeds[0]}-{dev_seeds[-1]}, {PANORAMAS} panoramas each), grid origins "
             + ", ".join(f"{f:.2f}" for f in origins) + f" of a step ({per} answers a weight); the rest the defaults:",
             "", *HEAD]
    lines += [_row(f"{w:g}" + (" (the halves' mean)" if w == MEAN else ""), dev[w], len(origins)) for w in weights]
    lines += ["", f"Chosen by the rule (the highest mean of each home's worst origin; within one panorama of one home of "
              f"it, the fewest answers moving with the origin, then the nearest to {MEAN:g}): **{chosen:g}**.", "",
              f"Test homes (seeds {', '.join(map(str, test_seeds))}), the same origins:", "", *HEAD]
    lines += [_row(f"{w:g}" + (" (chosen)" if w == chosen else "") + (" (the halves' mean)" if w == MEAN else ""),
                   test[w], len(origins)) for w in sorted(test)]
    lines += ["", verdict(chosen, test, len(origins))]
    (out_dir / "table.md").write_text("\n".join(lines) + "\n")
    if not quiet:
        print("\n".join(lines))
    return out_dir / "summary.json"
