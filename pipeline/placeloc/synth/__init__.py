"""Synthetic data sets with known ground truth (``placeloc synth KIND OUT``).

Each kind is a module-level ``generate(out_dir, seed=..., **params) -> dict`` that writes
images and ground truth under ``out_dir`` and returns a short summary. Registered by name
here and imported lazily.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

SYNTH_KINDS: dict[str, str] = {
    "route": "placeloc.synth.route",
    "corridor": "placeloc.synth.corridor",
    "home": "placeloc.synth.home",
    "coembed": "placeloc.synth.coembed",
    "omni": "placeloc.synth.omni",
}


def generate(kind: str, out_dir: str | Path, seed: int = 0, **params: Any) -> dict[str, Any]:
    if kind not in SYNTH_KINDS:
        raise KeyError(f"unknown synthetic data set {kind!r}; choose one of {', '.join(SYNTH_KINDS)}")
    module = importlib.import_module(SYNTH_KINDS[kind])
    return module.generate(Path(out_dir), seed=seed, **params)
