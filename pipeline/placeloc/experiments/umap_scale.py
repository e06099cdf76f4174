"""``placeloc experiment umap-scale``: a floor plan drawn at the wrong scale, on the test homes.

A plan drawn from a listing's drawing, or traced from a picture scaled by one measured wall,
is easily a few per cent too large or too small. This experiment gives the method each
test home's plan (seeds 20-24, 20 panoramas, ``placeloc synth home``) with every plan
position multiplied by a scale of :data:`SCALES` and the heights as drawn
(:func:`placeloc.geometry.floorplan.scaled_plan`); the truth is scaled with it, so an answer
is right where it lies within 1 m and 30 deg of the photo's place *on the plan given* (what
the user reads off it). Two runs at each home and scale, grid origin 0:

- ``as drawn``: the defaults;
- ``ceilings 2.3-3.0 searched``: ``umap.grid.ceilings`` as ``placeloc experiment umap-plan``
  searches them. Why it should help: a plan ``s`` too large is the true home with its
  heights ``s`` too small (a world scaled in x, y and z looks the same from the scaled
  camera), and the ceiling's lines, seen from a camera at ``z``, fall back where they were
  at a ceiling of ``z + s (c - z)``; the floor's lines stay ``s`` off. The table gives the
  ceilings found beside that figure.

Nothing here chooses a default. One grid origin: the answers' independence of it is
measured by ``placeloc experiment umap-contrast`` and ``umap-homes``. Writes
``OUT/table.md`` (shares per home and over every run, the ceilings found) and
``OUT/summary.json``.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from placeloc.core.artifacts import atomic_open
from placeloc.experiments import write_summary
from placeloc.experiments.umap_homes import _drop_index, _home, _run, homes_scope
from placeloc.experiments.umap_plan import SEARCHED_M, ceiling_found
from placeloc.geometry.floorplan import scaled_plan

SCALES = (0.9, 0.95, 1.0, 1.05, 1.1)
QUICK_SCALES = (0.9, 1.1)
# (label, umap.grid overrides); the ceiling search is not run at scale 1 (umap-plan measures it)
SETTINGS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("as drawn", {}),
    ("ceilings 2.3-3.0 searched", {"ceilings": SEARCHED_M}),
)


def scaled_home(data: Path, scale: float) -> Path:
    """``data/scale<s>/``: the home of ``data`` with its plan and its truth (``poses.csv``'s x
    and y) ``scale`` times as large, the photos and line statistics linked, not copied."""
    out = data / f"scale{scale:g}"
    if (out / "poses.csv").is_file():
        return out
    out.mkdir(parents=True, exist_ok=True)
    plan = scaled_plan(yaml.safe_load((data / "floor_plan.yaml").read_text()), scale)
    (out / "floor_plan.yaml").write_text(yaml.safe_dump(plan, sort_keys=False))
    for name in ("panoramas", "line_stats.json"):
        if not (out / name).exists():
            os.symlink(data / name, out / name)
    with open(data / "poses.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    with atomic_open(out / "poses.csv", newline="") as f:   # last: its presence says the folder is whole
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows({**r, "x": f"{float(r['x']) * scale:.4f}", "y": f"{float(r['y']) * scale:.4f}"} for r in rows)
    return out


def main(out_dir: Path, quick: bool = False, quiet: bool = False) -> Path:
    out_dir, seeds, _ = homes_scope(out_dir, quick, (0.0,))
    scales = QUICK_SCALES if quick else SCALES
    runs: dict[str, dict[str, Any]] = {}
    for seed in seeds:
        data = _home(out_dir, seed)
        fp = yaml.safe_load((data / "floor_plan.yaml").read_text())
        camera, ceiling = float(fp["camera_z"]), float(fp["ceiling_z"])
        for scale in scales:
            home = scaled_home(data, scale)
            for label, grid in SETTINGS:
                if grid and scale == 1.0:
                    continue
                folder = f"home{seed}-scale{scale:g}" + ("-ceilings" if grid else "")
                m = _run(out_dir, folder, home, {}, 0.0, quiet, grid=grid)
                runs[folder] = {**m, "seed": seed, "setting": label, "scale": scale,
                                "ceiling_found_m": ceiling_found(out_dir / folder) if grid else None,
                                "ceiling_derived_m": camera + scale * (ceiling - camera)}
                _drop_index(out_dir / folder)
    write_summary(out_dir, runs)
    lines = table(runs)
    (out_dir / "table.md").write_text("\n".join(lines) + "\n")
    if not quiet:
        print("\n".join(lines))
    return out_dir / "summary.json"


def table(runs: dict[str, dict[str, Any]]) -> list[str]:
    """``table.md``'s lines from the runs of :func:`main` (each with its ``seed``, ``scale``,
    ``setting``, share, median error and, searched, the ceiling found and the ceiling
    ``z + s (c - z)`` derived from the plan): a row per scale and setting, the homes in
    columns, then the share over them and the range of their median errors; then the
    ceilings found against those derived."""
    seeds = sorted({int(m["seed"]) for m in runs.values()})
    rows: dict[tuple[float, str], dict[int, dict[str, Any]]] = {}
    for m in runs.values():
        rows.setdefault((float(m["scale"]), str(m["setting"])), {})[int(m["seed"])] = m
    lines = [f"Test homes (seeds {', '.join(map(str, seeds))}, 20 panoramas each), every plan position times the "
             "scale, heights as drawn, the truth scaled with the plan; grid origin 0; share within 1 m and 30 deg:", "",
             "| plan's scale | plan | " + " | ".join(f"home {s}" for s in seeds) + " | all | median error, range over "
             "the homes |", "|---|---|" + "---|" * (len(seeds) + 2)]
    for (scale, label), per in sorted(rows.items(), key=lambda kv: (kv[0][0], kv[0][1] != SETTINGS[0][0])):
        errors = [float(m["median_error_m"]) for m in per.values()]
        lines.append(f"| {scale:g} | {label} | " + " | ".join(f"{per[s]['within_1m_30deg']:.0%}" if s in per else ""
                                                              for s in seeds)
                     + f" | {np.mean([m['within_1m_30deg'] for m in per.values()]):.1%} | "
                     f"{min(errors):.3f}-{max(errors):.3f} m |")
    found = [(scale, [per[s] for s in seeds if s in per]) for (scale, label), per in sorted(rows.items())
             if label != SETTINGS[0][0]]
    lines += ["", "Ceilings found by the search (homes in order), against z + s (c - z) of each home's plan: " + "; ".join(
        f"scale {scale:g}: " + ", ".join(f"{m['ceiling_found_m']:.2f} ({m['ceiling_derived_m']:.2f})" for m in ms)
        for scale, ms in found) + "."]
    return lines
