"""UMap's memory and disk needs per stage (the contract with :mod:`placeloc.core.limits`)."""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from placeloc.core.limits import Need, decode_need
from placeloc.core.limits import workers as n_workers
from placeloc.umap.params import PanoramaParams

BASE_MEMORY: dict[str, int] = {
    "extract": 100 << 20,
    "build-dictionary": 64 << 20,
    "index": 100 << 20,
    "localize": 100 << 20,
    "evaluate": 100 << 20,
}


# positions whose spectra are made at a time (and the index stage writes at a time). Why so
# few: a position's temporaries are about 2.5 MB at 144 x 72 with 6 direction bins (5.1
# times its 0.5 MB of spectra: its oriented channels, their closeness and both spectra), and
# blocks of 512-1024 positions allocated over a gigabyte afresh each time, which the kernel
# zeroes page by page. The index of generated home 21 (1,494 positions; three runs
# alternating with the tree before) took 2.69-4.30 s of its own, 1.55-3.18 s of system time
# and a 1.69 GB peak, against 2.07-2.13 s, 0.91-0.97 s and 0.41 GB with 64 (128: the same
# time, 0.49 GB; 32: 2.2 s). Every position's spectra are its own, the same to the bit in
# any block (tested). Since each block's halves are written into one buffer and conjugated
# straight into place (panorama._spectra_rows), a block's temporaries are 3.5 times its
# spectra, not 5.1, and the index 1.61-1.73 s of its own (three runs alternating with the
# tree before, 2.33-2.59 s there), peak 0.33 GB
SPECTRA_BLOCK = 64


def _plan_grid_size(p: dict[str, Any], step: float) -> tuple[int, int, float] | None:
    """(x points, y points, share inside the plan) of the grid over ``umap.model``'s plan
    bounds at ``step`` (None when the model cannot be read)."""
    from placeloc.geometry.floorplan import load_model, model_bounds

    try:
        model = load_model(p["model"], p.get("floor"))
        lo, hi = model_bounds(model)
    except Exception:  # noqa: BLE001 - any unreadable model: its own check names the problem
        return None
    nx, ny = (math.floor(float(hi[k] - lo[k]) / step + 1e-9) + 1 for k in (0, 1))
    # the share inside, on a grid of at most 200 x 200 over the same box
    sx, sy = np.linspace(lo[0], hi[0], min(nx, 200)), np.linspace(lo[1], hi[1], min(ny, 200))
    xy = np.stack(np.meshgrid(sx, sy, indexing="ij"), -1).reshape(-1, 2)
    return nx, ny, float(np.mean(model.inside(xy)))


def needs(config: dict[str, Any], images: dict[str, Any], stages: Sequence[str]) -> list[Need]:
    p = config["umap"]
    g = p["grid"]
    axes = []
    inside_share = 1.0
    for name in ("x", "y"):
        if g.get(name) is None:
            # the grid covers the model's plan at grid.step_m: its bounding box at that step,
            # of which the positions inside the plan are kept (doorways add a few: +10 %)
            plan = _plan_grid_size(p, float(g.get("step_m") or 0.25))
            if plan is None:  # the model's own check reports an unreadable model
                return decode_need(config, images, 16, "decoding", stages)
            axes, inside_share = [plan[0], plan[1]], (min(1.0, 1.1 * plan[2]) if g.get("inside_only", True) else 1.0)
            break
        start, stop, step = (float(v) for v in g[name])
        if step <= 0 or stop < start:
            return []  # pose_grid reports these with its own message
        axes.append(math.floor((stop - start) / step + 1e-9) + 1)
    panorama = p.get("query_kind") == "panorama"
    positions = max(1, math.ceil(axes[0] * axes[1] * inside_share))
    # panoramas: a layer of the grid per camera height and ceiling height searched
    # (umap.grid.heights, umap.grid.ceilings)
    layers = max(1, len(g.get("heights") or [])) * max(1, len(g.get("ceilings") or [])) if panorama else 1
    views = positions * layers if panorama else positions * max(1, len(g["headings"]))
    size = p.get("panorama" if panorama else "camera") or {}
    w, h = int(size.get("width", 160)), int(size.get("height", 120))
    words = (w * h + 63) // 64
    pano = p.get("panorama") or {}
    chamfer = panorama and pano.get("score", "chamfer") == "chamfer"
    # the oriented chamfer score keeps each view's line image once per direction bin
    bins = max(1, int(pano.get("orientation_bins", PanoramaParams.orientation_bins))) if chamfer else 1
    words *= bins
    db = views * words * 8  # one bit per pixel per view (and direction bin)
    pooled = 0 if panorama else views * (((w // 8) * (h // 8) + 63) // 64) * 8
    block = min(int(p.get("block", 2048)), views)
    # the chamfer score's index: per position both map images' row spectra, (w // 2 + 1)
    # frequencies x 2h rows of complex64 (x the direction bins), made and written
    # SPECTRA_BLOCK positions at a time (that block and its temporaries: 107 MB for 64
    # positions of 144 x 72 with 6 direction bins, 3.5 blocks of spectra, tracemalloc; counted
    # as 4). Localize maps them rather
    # than copying (core.artifacts.read_mapped), but every batch of panoramas reads them all:
    # where they do not fit in memory with the rest, each batch would read them from disk, so
    # they still count whole
    spectra = views * (w // 2 + 1) * 2 * bins * h * 8 if chamfer else 0
    what = f"UMap database of {views:,} views of {w}x{h} (x {g['x'] or 'the plan'}, y {g['y'] or 'the plan'}" + \
        ("" if panorama else f", {len(g['headings'])} headings") + (f", {layers} layers of heights and ceilings" if layers > 1 else "") + ")"
    key = "umap.grid (a larger step or a smaller range" + (", fewer heights or ceilings" if layers > 1 else "") + \
        ") or the camera size"
    # build-dictionary: the grid (poses, the free-space test) and what HDF5 and the
    # renderer hold of the database as it is written: measured 80, 85 and 199 MB for 46,000
    # and 182,000 views of 160x120 and 182,000 of 40x30, i.e. 40 MB + 204 bytes a view +
    # 0.28 of the database (estimated: 256 bytes and 0.4), and with a pool each worker's
    # block of uint8 views; writes the database, its pooled cells, the poses and the plan.
    # index: per-view counts (and, for panoramas, a dilated copy of the database).
    # localize: the whole database, the pooled cells, poses and per-view scores (about
    # 160 bytes a view; measured 176 and 525 MB for 46,000 and 182,000 views of 160x120).
    pool = block * w * h * n_workers(config) if n_workers(config) > 1 else 0
    needs = [Need(what, key, stage="build-dictionary", memory=256 * views + db * 2 // 5 + pool,
                  disk=db + pooled + 48 * views + (1 << 20)),
             Need(what, key, stage="index", memory=(2 * db if panorama else 0) + 24 * views
                  + 4 * min(spectra, SPECTRA_BLOCK * (w // 2 + 1) * 2 * bins * h * 8),
                  disk=(db if panorama else 0) + 48 * views + spectra),
             # each height's layer is searched alone: its rows of the spectra at a time
             Need(what, key, stage="localize", memory=db + pooled + 160 * views + spectra // layers, disk=1 << 20)]
    return [n for n in needs if n.stage in stages] + decode_need(config, images, 16, "decoding", stages)
