"""``placeloc experiment umap-halves``: the weight of the chamfer score's two halves
(``umap.panorama.recall_weight``), chosen on development homes and checked on test homes.

The whole-panorama score mixes a recall half (the map's drawn lines near the photo's) and a
precision half (the photo's lines near the map's), by default their mean (0.5). A sparse
view earns recall easily (few drawn lines, each near something), a busy one precision (many
drawn lines for clutter to fall near), so the mean is one choice among many. This
experiment asks whether another weight places more photos, and whether that holds on homes
it was not chosen on: the weights of :data:`WEIGHTS` on development homes 0-12 at five grid
origins, the one the ``umap-homes`` rule chooses and 0.5 on test homes 20-24
(:mod:`placeloc.experiments.umap_setting`, which says how). The weight is a localize key:
every weight of a home and origin shares one run folder, so the map is drawn and indexed
once. Writes ``OUT/table.md`` and ``OUT/summary.json``.
"""

from __future__ import annotations

from pathlib import Path

from placeloc.experiments.umap_setting import Setting, run

WEIGHTS = (0.3, 0.4, 0.45, 0.5, 0.6)
MEAN = 0.5                      # the halves' mean: the score before the weight, and its default
HALVES = Setting(key="recall_weight", values=WEIGHTS, quick=(0.4, MEAN), default=MEAN, column="recall weight",
                 noun="weight", default_name="the halves' mean")


def main(out_dir: Path, quick: bool = False, quiet: bool = False) -> Path:
    return run(HALVES, out_dir, quick=quick, quiet=quiet)
