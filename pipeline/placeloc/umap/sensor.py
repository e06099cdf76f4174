"""The per-frame sensor CSV of UMap+CA: laser distance to the side wall and camera angle."""

from __future__ import annotations

import csv
from pathlib import Path

from placeloc.core.images import ImageError


def read_sensor_csv(path: str | Path, names: list[str]) -> dict[str, tuple[float, float]]:
    """frame -> (d, theta_deg) from a CSV with columns frame, d, theta_deg; every query frame
    must be present. Errors name the file, the line and the columns it needs."""
    out: dict[str, tuple[float, float]] = {}
    with open(path, newline="", encoding="utf-8-sig") as f:  # a BOM is not part of the header
        reader = csv.DictReader(f)
        need = {"frame", "d", "theta_deg"}
        if reader.fieldnames is None or not need <= set(reader.fieldnames):
            raise ImageError(f"{path}: sensor CSV needs the columns frame, d, theta_deg (has {reader.fieldnames})")
        for i, row in enumerate(reader, 2):
            try:
                out[row["frame"]] = (float(row["d"]), float(row["theta_deg"]))
            except (TypeError, ValueError) as exc:
                raise ImageError(f"{path}:{i}: d and theta_deg must be numbers ({exc})") from exc
    missing = [n for n in names if n not in out]
    if missing:
        raise ImageError(f"{path}: no sensor row for {len(missing)} query frame(s), e.g. {missing[0]}; add them")
    return out
