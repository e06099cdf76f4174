"""``placeloc experiment umap-lines``: the shortest line a panorama keeps
(``umap.panorama.lsd_min_length_px``, in pixels of the cube faces LSD runs on), chosen on
development homes and checked on test homes.

Why: short LSD segments are mostly clutter's (the edges of furniture, planks and tiles,
blinds, what stands on a counter), while a room's own lines (wall junctions, door frames)
run long, so a longer shortest line leaves the photo's lines nearer to the map's. But a
white room's faint junctions break into short pieces, and those go too (the real home's
bonus room, with few detected edges, was lost to its clutter). On the real home, at the
code of the time, 16 and 24 px each fixed one panorama and lost another. This experiment
measures the trade on generated homes rather than assuming it: the lengths of
:data:`LENGTHS` on development homes 0-12 at five grid origins, the one the ``umap-homes``
rule chooses and the default (8 px) on test homes 20-24
(:mod:`placeloc.experiments.umap_setting`, which says how). The length is an extract key:
each length of a home and origin re-runs extract and localize in one run folder, so the
map is drawn and indexed once. Writes ``OUT/table.md`` and ``OUT/summary.json``.
"""

from __future__ import annotations

from pathlib import Path

from placeloc.experiments.umap_setting import Setting, run

LENGTHS = (8.0, 12.0, 16.0, 24.0)
DEFAULT = 8.0                   # umap.panorama.lsd_min_length_px's default
LINES = Setting(key="lsd_min_length_px", values=LENGTHS, quick=(DEFAULT, 16.0), default=DEFAULT,
                column="shortest line kept (face px)", noun="length", default_name="the default")


def main(out_dir: Path, quick: bool = False, quiet: bool = False) -> Path:
    return run(LINES, out_dir, quick=quick, quiet=quiet)
