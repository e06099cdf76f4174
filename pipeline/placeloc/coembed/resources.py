"""Co-embedding's memory and disk needs per stage (the contract with :mod:`placeloc.core.limits`)."""

from __future__ import annotations

import os
import stat
from typing import Any, Sequence

from placeloc.core.limits import Need, decode_need

BASE_MEMORY: dict[str, int] = {
    "extract": 16 << 20,
    "build-dictionary": 16 << 20,
    "index": 16 << 20,
    "localize": 40 << 20,
    "evaluate": 64 << 20,
}


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
    """Rows of a text file (a fast count of newlines; 0 when it cannot be read or is not a
    regular file: /dev/zero would never end, a FIFO never open; the reader refuses those)."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return 0
        with open(path, "rb") as fh:
            return sum(chunk.count(b"\n") for chunk in iter(lambda: fh.read(1 << 20), b""))
    except (OSError, TypeError):
        return 0
