"""The config sections every method shares: the one home of their defaults, ranges and help.

They are parameter dataclasses like the methods' (:mod:`placeloc.core.params`); the config
layer derives the YAML defaults, choices, ranges, path keys and types from
:class:`CommonParams` exactly as it does from a method's class, and the rest of the code
reads the validated config as a nested dict with these keys (``config["ground_truth"]
["radius"]``). Code that needs a shared default outside a config (a library function's
keyword default, a test) reads it from here, e.g. ``GroundTruthParams().radius``.

This module imports nothing of placeloc but :mod:`placeloc.core.params`, so any layer can read
it without an import cycle.
"""

from __future__ import annotations

from dataclasses import dataclass

from placeloc.core.params import Params, param, section

GROUND_TRUTH_KINDS = ("none", "synchronous", "csv", "hdf5", "poses", "matrix")


@dataclass(frozen=True)
class ImagesParams(Params):
    """``reference`` and ``query``: one traverse's images. ``query`` omitted means loop
    closure within the reference traverse."""

    images: str | None = param(None, path=True, help="folder (natural order) or glob of the images")
    on_error: str = param("stop", choices=("stop", "skip"),
                          help="an unreadable image: stop the run, or skip it (indices stay those of the folder)")
    fingerprint: str = param("stat", choices=("stat", "content"),
                             help="what marks an image changed: stat (name, size, mtime; cheap) or content (a hash "
                                  "of its bytes)")


@dataclass(frozen=True)
class GroundTruthParams(Params):
    """``ground_truth``: which references are right for each query (docs/evaluation.md)."""

    kind: str = param("none", choices=GROUND_TRUTH_KINDS,
                      help="none | synchronous (query i is reference i) | csv (pairs or ranges) | hdf5 (a matrix) | "
                           "poses (positions within radius) | matrix (loop closures: a binary N x N file, .npy .npz "
                           ".mat .txt .csv .h5)")
    # One tolerance for every kind that uses it: a pairs CSV is exact unless one is set.
    tolerance: int = param(0, min=0, help="frames either side of the true reference that also count (synchronous "
                                          "and csv pairs; not added to csv ranges); 0: exact")
    path: str | None = param(None, path=True, help="the ground-truth file (csv, hdf5, poses) or folder (poses)")
    # 25 m is the VPR-Bench / Berton et al. VPR-methods-evaluation convention for street-level data.
    radius: float = param(25.0, min=0, min_exclusive=True,
                          help="poses: metres within which a reference (or loop closure) is correct")
    recall_at: tuple[int, ...] = param([1, 5, 10, 20], min=1, min_len=1, help="the N of Recall@N in metrics.json and the "
                                                                   "Recall@N curve")
    # The evaluation kit of the public loop-closure sets (City Centre, New College, Lip6) uses
    # frame rate x 40 s; without a frame rate, LOOP_EXCLUSION_FRAMES, cut on short sequences
    # (loop_exclusion below).
    exclude_recent: int | None = param(None, min=0, help="loop closures: a frame is never a loop candidate for the next "
                                       "this many frames, in the method's search (SeqSLAM, retrieval) and in the scoring "
                                       "alike; null: 50, or a fifth of the frames on sequences shorter than 250 (the run "
                                       "says which)")


# ground_truth.exclude_recent when not set: this many frames, but never more than a fifth of
# the sequence, so that at least four fifths of its frames can still close a loop (on an
# 84-frame sequence 50 would leave 34 frames that can, 16 leaves 68).
LOOP_EXCLUSION_FRAMES = 50
LOOP_EXCLUSION_SHARE = 5


def loop_exclusion(setting: int | None, n_frames: int) -> tuple[int, str]:
    """The exclusion in frames for a sequence of ``n_frames``, and how it was chosen (one
    clause for the log and metrics.json)."""
    if setting is not None:
        return int(setting), "as set (ground_truth.exclude_recent)"
    adapted = n_frames // LOOP_EXCLUSION_SHARE
    if adapted >= LOOP_EXCLUSION_FRAMES:
        return LOOP_EXCLUSION_FRAMES, f"the default {LOOP_EXCLUSION_FRAMES} frames (ground_truth.exclude_recent: null)"
    return adapted, (f"a fifth of the {n_frames} frames, as the sequence is shorter than "
                     f"{LOOP_EXCLUSION_FRAMES * LOOP_EXCLUSION_SHARE} (the default {LOOP_EXCLUSION_FRAMES} would leave "
                     f"{max(n_frames - LOOP_EXCLUSION_FRAMES, 0)} frames that can close a loop); set "
                     "ground_truth.exclude_recent to choose")


@dataclass(frozen=True)
class ExecutorParams(Params):
    """``executor``: where the parallel work items run (docs/dask.md)."""

    kind: str = param("local", choices=("local", "dask"), help="local (processes on this machine) or dask")
    workers: int = param(1, min=1, help="parallel workers")
    scheduler: str = param("local-cluster", help="dask: local-cluster, or the address of a running scheduler "
                                                 "(tcp://host:8786)")
    retries: int = param(2, min=0, help="dask: retries of a failed work item")


@dataclass(frozen=True)
class CommonParams(Params):
    """The top level of every config besides the method's own section."""

    method: str | None = param(None, help="the method, e.g. seqslam (placeloc --help lists them)")
    seed: int = param(0, help="seed of every random choice")
    reference: ImagesParams = section(ImagesParams)
    query: ImagesParams = section(ImagesParams)
    ground_truth: GroundTruthParams = section(GroundTruthParams)
    executor: ExecutorParams = section(ExecutorParams)
    plots: bool = param(True, help="write the PNG figures")
