"""``placeloc experiment umap-phone``: 360 degree photos taken by hand, on the test homes.

A phone's or a hand-held camera's 360 degree photo is not always level, and a photo sphere
the user did not close is stored cropped to what it covered. This experiment generates each
test home (seeds 20-24, 20 panoramas, ``placeloc synth home``) four ways from the same seed
(the same plan, poses and scene):

- ``level``: as a tripod takes it (the home of ``placeloc experiment umap-homes``);
- ``tilted``: each camera tilted by 0-8 degrees about a horizontal axis (``tilt_deg`` 8);
- ``sphere``: stored cropped to the elevations -55..+60 degrees with its Photo Sphere
  metadata (``cover_low_deg`` / ``cover_high_deg``: no floor or ceiling cap);
- ``band``: cropped to -40..+40 degrees.

Each runs at grid origins 0 and 0.55 of a step with the defaults, and the level and tilted
photos also with levelling off (``umap.panorama.level_max_deg`` 0), so that the table shows
what levelling buys and what it costs a level photo. Every variant of a home and origin shares
one run folder (the plan is the same file), so the map is drawn and indexed once.

Nothing here chooses a default: levelling's defaults were fixed on development homes 0-2
(docs/umap.md, "A photo that is not level"). Writes ``OUT/table.md`` and
``OUT/summary.json``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from placeloc.experiments import write_summary
from placeloc.experiments.umap_homes import PANORAMAS, _drop_index, _run, homes_scope
from placeloc.synth import generate

log = logging.getLogger("placeloc")

ORIGINS = (0.0, 0.55)
# the four ways a home is taken: generator parameters beyond the seed
VARIANTS: dict[str, dict[str, Any]] = {
    "level": {},
    "tilted": {"tilt_deg": 8.0},
    "sphere": {"cover_low_deg": -55.0, "cover_high_deg": 60.0},
    "band": {"cover_low_deg": -40.0, "cover_high_deg": 40.0},
}
# (variant, label, umap.panorama overrides): what runs on each home and origin
SETTINGS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("level", "level photos, the defaults", {}),
    ("level", "level photos, levelling off", {"level_max_deg": 0.0}),
    ("tilted", "tilted 0-8 deg, levelled (the defaults)", {}),
    ("tilted", "tilted 0-8 deg, levelling off", {"level_max_deg": 0.0}),
    ("sphere", "cropped to -55..+60 deg (the defaults)", {}),
    ("band", "cropped to -40..+40 deg (the defaults)", {}),
)


def _home(root: Path, seed: int, variant: str) -> Path:
    d = root / "data" / f"home-seed{seed}-{variant}"
    if not (d / "poses.csv").is_file():
        log.info("generating the synthetic home (seed %d, %s) in %s", seed, variant, d)
        generate("home", d, seed=seed, panoramas=PANORAMAS, **VARIANTS[variant])
    return d


def main(out_dir: Path, quick: bool = False, quiet: bool = False) -> Path:
    out_dir, seeds, origins = homes_scope(out_dir, quick, ORIGINS)
    runs: dict[str, dict[str, Any]] = {}
    shares: dict[str, dict[int, list[float]]] = {label: {} for _, label, _ in SETTINGS}
    for seed in seeds:
        plan = _home(out_dir, seed, "level") / "floor_plan.yaml"
        for i, frac in enumerate(origins):
            folder = f"home{seed}-origin{i}"
            for variant, label, over in SETTINGS:
                m = _run(out_dir, folder, _home(out_dir, seed, variant), over, frac, quiet, plan=plan)
                runs[f"{folder}-{label}"] = m
                shares[label].setdefault(seed, []).append(m["within_1m_30deg"])
            _drop_index(out_dir / folder)
    write_summary(out_dir, runs)
    lines = [f"Test homes (seeds {', '.join(map(str, seeds))}, {PANORAMAS} panoramas each), grid origins "
             + ", ".join(f"{f:g}" for f in origins) + " of a step; share within 1 m and 30 deg per home "
             "(each origin), and over every run:", "",
             "| photos | " + " | ".join(f"home {s}" for s in seeds) + " | all runs |",
             "|---|" + "---|" * (len(seeds) + 1)]
    for _, label, _ in SETTINGS:
        per = shares[label]
        every = [x for s in seeds for x in per[s]]
        lines.append(f"| {label} | " + " | ".join(" / ".join(f"{x:.0%}" for x in per[s]) for s in seeds)
                     + f" | {np.mean(every):.1%} |")
    (out_dir / "table.md").write_text("\n".join(lines) + "\n")
    if not quiet:
        print("\n".join(lines))
    return out_dir / "summary.json"
