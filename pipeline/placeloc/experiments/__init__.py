"""Experiment drivers (``placeloc experiment NAME``), one per method, plus shared helpers.

An experiment runs several configs into ``runs/experiment-<name>/<run>/`` and leaves
``summary.json`` there: one object per run, keyed by run name, holding that run's
metrics.json figures.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path
from typing import Any

from placeloc.core.artifacts import atomic_open
from placeloc.core.shared_data import shared_data_dir  # noqa: F401 - the one lookup, re-exported for experiments


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend, for the figures some experiments draw for the
    docs. matplotlib is an optional dependency (no stage or sweep needs it): without it
    this says how to install it, and an experiment that draws calls this before its runs so
    that it stops at once rather than after them."""
    try:
        import matplotlib
    except ImportError as exc:
        raise RuntimeError("this experiment draws its figures with matplotlib, which is not installed: "
                           "pip install 'placeloc[experiments]' (or pip install matplotlib)") from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _discover() -> dict[str, str]:
    """Experiment name -> module: every module of this package that defines
    ``main(out_dir, quick=, quiet=)`` at top level (found by reading the files, nothing
    imported); ``pirf_large.py`` is the experiment ``pirf-large``. Adding a file adds
    the experiment."""
    here = Path(__file__).resolve().parent
    found = {}
    for f in sorted(here.glob("*.py")):
        if f.stem != "__init__" and "\ndef main(" in f.read_text(encoding="utf-8"):
            found[f.stem.replace("_", "-")] = f"placeloc.experiments.{f.stem}"
    return found


EXPERIMENTS: dict[str, str] = _discover()


def say(experiment: str, quiet: bool, msg: str) -> None:
    """A timestamped progress line of an experiment (nothing when ``quiet``)."""
    if not quiet:
        import time

        print(f"[experiment-{experiment} {time.strftime('%H:%M:%S')}] {msg}", flush=True)


def run_experiment(name: str, out_dir: str | Path | None = None, quick: bool = False, quiet: bool = False) -> Path:
    if name not in EXPERIMENTS:
        raise KeyError(f"unknown experiment {name!r}; choose one of {', '.join(EXPERIMENTS)}")
    out = Path(out_dir or f"runs/experiment-{name}")
    out.mkdir(parents=True, exist_ok=True)
    module = importlib.import_module(EXPERIMENTS[name])
    return module.main(out, quick=quick, quiet=quiet)



def write_summary(out_dir: Path, runs: dict[str, dict[str, Any]]) -> Path:
    """Write ``summary.json`` atomically (run name -> metrics)."""
    path = out_dir / "summary.json"
    with atomic_open(path) as fh:
        fh.write(json.dumps(runs, indent=2, sort_keys=True, default=float))
    return path


