"""Shared evaluation: ground truth, metrics, plots, and writing metrics.json.

Modules: :mod:`~placeloc.evaluation.ground_truth` (every form of ground truth, checked when
the config is loaded), :mod:`~placeloc.evaluation.poses` (the one pose reader: x/y, UTM,
lat/lon, ``@utm@`` file names), :mod:`~placeloc.evaluation.metrics` (PR, Recall@N),
:mod:`~placeloc.evaluation.matching` (scoring ranked matches, the metric keys and their
denominators, ``per_query.csv``), :mod:`~placeloc.evaluation.plots`,
:mod:`~placeloc.evaluation.show` (match strips) and :mod:`~placeloc.evaluation.report`
(``report.html``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from placeloc.core.artifacts import atomic_open


def _clean(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return None if math.isnan(v) or math.isinf(v) else v
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def write_metrics(run_dir: str | Path, metrics: dict[str, Any], group: Any = None) -> dict[str, Any]:
    """Write ``run_dir/metrics.json`` atomically (NaN/inf become null) and mirror the
    scalar figures as attributes of ``group`` (the evaluate artifact) when given."""
    clean = _clean(metrics)
    with atomic_open(Path(run_dir) / "metrics.json") as fh:
        fh.write(json.dumps(clean, indent=2, sort_keys=False))
    if group is not None:
        g = group.require_group("metrics")
        for k, v in clean.items():
            if isinstance(v, (int, float, str, bool)):
                g.attrs[k] = v
        g.attrs["json"] = json.dumps(clean)
    return clean
