"""placeloc's Python API: what the command line does, callable from a notebook or script.

>>> import placeloc
>>> cfg = placeloc.load_config("configs/demo.yaml", overrides=["seqslam.ds=20"])
>>> placeloc.run(cfg, "runs/demo-ds20")                       # every stage, resumable
>>> placeloc.run(cfg, "runs/demo-ds20", stages="localize")    # up to and including localize
>>> placeloc.read_metrics("runs/demo-ds20")["recall_at_1"]

Each method's array-level functions are importable without the pipeline, e.g.
:func:`placeloc.seqslam.search.sequence_search` on a difference matrix.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

from placeloc.core.artifacts import describe
from placeloc.core.config import load_config
from placeloc.core.methods import STAGES
from placeloc.core.runner import read_metrics, run_stage

__all__ = ["STAGES", "describe", "load_config", "read_metrics", "run"]


def run(config: dict[str, Any] | str | Path, run_dir: str | Path, stages: str | None = None, force: bool = False,
        quiet: bool = True, reuse: Sequence[str | Path] = ()) -> Path:
    """Bring a run directory up to date and return the last stage's artifact path.

    ``config`` is a validated config (from :func:`load_config`) or the path of a YAML file;
    ``stages`` names the last stage to run (default: all of them, or up to localize when
    there is no ground truth to score against, see :func:`last_stage`). Stages already up
    to date are skipped; ``force`` re-runs every stage up to ``stages``. ``reuse`` names
    other run directories whose artifacts with exactly the stamp a stage would have (same
    inputs, parameters and parents) and no side outputs are hard-linked instead of computed,
    as ``placeloc sweep`` does between its points.
    """
    cfg = load_config(config) if isinstance(config, (str, Path)) else config
    return run_stage(cfg, run_dir, stages or last_stage(cfg), quiet=quiet, force_all=force, reuse=reuse)


def last_stage(config: dict[str, Any]) -> str:
    """The last stage a whole run brings up to date: evaluate, or localize when the config
    gives no ground truth for the method's result (nothing to score; ``placeloc show``
    draws the matches)."""
    from placeloc.core.methods import get_method
    from placeloc.evaluation.contracts import truth_given

    return STAGES[-1] if truth_given(config, get_method(config["method"])) else "localize"
