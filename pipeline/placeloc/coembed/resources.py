"""Co-embedding: what its stages need of memory and disk, checked before any stage runs
(:mod:`placeloc.limits` asks the method through ``Method(resources=...)``).

``BASE_MEMORY``: what a stage's process holds beyond what it had before the stage,
whatever the data's size (libraries loaded and kernels compiled while it runs), measured
with tests/resource_probe.py (figures and command in docs/reliability.md), rounded up.
"""

from __future__ import annotations

import math  # noqa: F401 - used by some estimators
from typing import Any, Sequence

from placeloc.limits import Need, count_images, decode_need  # noqa: F401
from placeloc.limits import workers as n_workers  # noqa: F401

BASE_MEMORY: dict[str, int] = {"extract": 16 << 20, "build-dictionary": 16 << 20, "index": 16 << 20, "localize": 40 << 20,
                "evaluate": 64 << 20}


def needs(config: dict[str, Any], images: dict[str, Any], stages: Sequence[str]) -> list[Need]:
    p = config["coembed"]
    needs = []
    if p.get("source", "csv") == "csv" and p.get("observations"):
        n_obs = _count_lines(p["observations"])
        # extract: the parsed observation table (about 110 bytes an observation, measured
        # 84 MB for 964,000), stored compressed (measured 8 bytes an observation);
        # localize: the sparse system and its factorisation (measured 193 MB for 964,000:
        # 200 bytes an observation), the path and map CSVs.
        needs.append(Need(f"{n_obs:,} observations ({p['observations']})", "the observation file's size", stage="extract",
                          memory=110 * n_obs, disk=14 * n_obs + (1 << 19)))
        needs.append(Need(f"the co-embedding system of {n_obs:,} observations", "the observation file's size",
                          stage="localize", memory=200 * n_obs, disk=3 * n_obs + (1 << 18)))
    return [x for x in needs if x.stage in stages] + \
        decode_need(config, images, 240, "feature extraction (about 240 bytes a pixel)", stages)


def _count_lines(path: Any) -> int:
    """Rows of a text file (a fast count of newlines; 0 when it cannot be read)."""
    try:
        with open(path, "rb") as fh:
            return sum(chunk.count(b"\n") for chunk in iter(lambda: fh.read(1 << 20), b""))
    except (OSError, TypeError):
        return 0
