"""Run stages in order, skip the ones whose artifact is up to date, write atomically.

``run_stage(config, run_dir, "localize")`` first brings every earlier stage up to date
(running only those whose stamp changed), then runs ``localize`` if its own stamp changed
or ``force`` is set. Each stage's function gets a :class:`StageContext`.
"""

from __future__ import annotations

import json
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator

import h5py
from placeloc import __version__
from placeloc.artifacts import TMP_MARK, atomic_h5, provenance_attrs, read_stamp, remove_stale_tmp
from placeloc.config import config_hash, to_yaml
from placeloc.executor import Executor, make_executor
from placeloc.images import ImageSet, list_images
from placeloc.methods import BASE_SECTIONS, STAGES, Method, get_method
from tqdm import tqdm

log = logging.getLogger("placeloc")

# Files in a run directory that belong to no stage (written by the runner itself).
RUN_FILES = ("config.yaml", "log.txt")


class StageError(RuntimeError):
    """A stage cannot run (missing parent, bad input); the message says what to do."""


@dataclass
class StageContext:
    """What a stage function sees. It writes its results into ``out`` (an HDF5 group)."""

    stage: str
    method: Method
    config: dict[str, Any]
    run_dir: Path
    out: h5py.Group
    executor: Executor
    quiet: bool = False
    images: dict[str, ImageSet] = field(default_factory=dict)
    _open: list[h5py.File] = field(default_factory=list)

    # The method's parameter object (see placeloc.params), built once per run.
    params: Any = None

    def artifact(self, stage: str) -> h5py.File:
        """Open the artifact of an earlier stage read-only (closed by the runner)."""
        path = self.run_dir / f"{stage}.h5"
        if not path.is_file():
            raise StageError(f"{path} is missing: run `placeloc {stage}` first")
        f = h5py.File(path, "r")
        self._open.append(f)
        return f

    def progress(self, iterable: Iterable[Any], total: int | None = None, desc: str = "") -> Iterator[Any]:
        return iter(tqdm(iterable, total=total, desc=desc or self.stage, disable=self.quiet,
                         file=sys.stderr, dynamic_ncols=True, leave=False))

    def close(self) -> None:
        for f in self._open:
            f.close()
        self._open.clear()


def normalise_stage(name: str) -> str:
    if name not in STAGES:
        raise StageError(f"unknown stage {name!r}; stages are {', '.join(STAGES)}")
    return name


def image_sets(config: dict[str, Any]) -> dict[str, ImageSet]:
    sets = {}
    for role in ("reference", "query"):
        section = config.get(role)
        if section and section.get("images"):
            sets[role] = list_images(section["images"], section.get("on_error", "stop"))
    return sets


def stage_inputs(config: dict[str, Any], method: Method, stage: str, images: dict[str, ImageSet],
                 parent_stamp: str | None) -> dict[str, Any]:
    """Everything a stage's result depends on, as JSON-able fingerprints: the parameters
    and sections it declares, images and files named by path parameters (first stage), the
    ground-truth file (if it reads that section) and the parent's stamp."""
    declared = method.stages.get(stage)
    keys = declared.keys if declared is not None else ()
    sections = declared.sections if declared is not None else ()
    section = config.get(method.name, {})
    method_part = {k: _lookup(section, k) for k in keys}
    common = {k: config.get(k) for k in BASE_SECTIONS + tuple(sections)}
    inputs: dict[str, Any] = {"config": config_hash({"common": common, "method": method_part})}
    if stage == STAGES[0]:
        for role, s in images.items():
            inputs[f"images.{role}"] = s.fingerprint()
        # Files named by the method's own path keys (models, observation CSVs, ...): a change
        # re-runs the first stage and so, through the parent stamps, everything after it.
        for key in method.path_keys:
            node: Any = section
            for part in key.split("."):
                node = node.get(part) if isinstance(node, dict) else None
            if node:
                inputs[f"file.{key}"] = _path_fingerprint(Path(str(node)))
    gt_path = (config.get("ground_truth") or {}).get("path")
    if "ground_truth" in sections and gt_path and Path(gt_path).is_file():
        inputs["ground_truth_file"] = _path_fingerprint(Path(gt_path))
    if parent_stamp is not None:
        inputs["parent"] = parent_stamp
    return inputs


def _lookup(section: dict[str, Any], dotted: str) -> Any:
    node: Any = section
    for part in dotted.split("."):
        node = node.get(part) if isinstance(node, dict) else None
    return node


def _path_fingerprint(path: Path) -> str:
    """Size and modification time of a file, or of every file below a folder."""
    if path.is_file():
        st = path.stat()
        return f"{st.st_size}:{st.st_mtime_ns}"
    if path.is_dir():
        files = sorted(p for p in path.rglob("*") if p.is_file())
        return config_hash([f"{p.relative_to(path)}:{p.stat().st_size}:{p.stat().st_mtime_ns}" for p in files])
    return "missing"


def run_stage(config: dict[str, Any], run_dir: str | Path, stage: str, force: bool = False,
              quiet: bool = False, force_all: bool = False) -> Path:
    """Bring ``stage`` (and every stage before it) up to date; return its artifact path.

    ``force`` re-runs ``stage`` even when up to date; ``force_all`` every stage up to it.
    """
    stage = normalise_stage(stage)
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    remove_stale_tmp(run_dir)
    method = get_method(config["method"])
    (run_dir / "config.yaml").write_text(to_yaml(config))
    images = image_sets(config) if method.uses_images else {}
    parent_stamp: str | None = None
    executor: Executor | None = None
    try:
        for name in STAGES[: STAGES.index(stage) + 1]:
            path = run_dir / f"{name}.h5"
            inputs = stage_inputs(config, method, name, images, parent_stamp)
            stamp = config_hash({"version": __version__, "stage": name, "inputs": inputs})
            forced = force_all or (force and name == stage)
            if read_stamp(path) == stamp and side_outputs_intact(path) and not forced:
                log.info("%s: up to date (%s), skipped", name, path)
                parent_stamp = stamp
                continue
            if executor is None:
                executor = make_executor(config["executor"])
            _execute(method, config, run_dir, name, path, inputs, stamp, images, executor, quiet)
            parent_stamp = stamp
    finally:
        if executor is not None:
            executor.close()
    return run_dir / f"{stage}.h5"


def _execute(method: Method, config: dict[str, Any], run_dir: Path, name: str, path: Path,
             inputs: dict[str, Any], stamp: str, images: dict[str, ImageSet], executor: Executor,
             quiet: bool) -> None:
    declared = method.stages.get(name)
    fn = declared.run if declared is not None else None
    note = "" if fn is not None else f"{method.name} has no work in {name}: input passed through"
    attrs = provenance_attrs(name, method.name, __version__, to_yaml(config),
                             config_hash(config), inputs, stamp, passthrough=fn is None, note=note)
    t0 = time.perf_counter()
    with atomic_h5(path, attrs) as f:
        if fn is None:
            log.info("%s: %s", name, note)
            return
        log.info("%s: running %s", name, method.name)
        ctx = StageContext(stage=name, method=method, config=config, run_dir=run_dir, out=f,
                           executor=executor, quiet=quiet, images=images, params=method.build_params(config))
        before = _run_files(run_dir)
        try:
            fn(ctx)
        finally:
            ctx.close()
        f.attrs["seconds"] = time.perf_counter() - t0
        # Side outputs (CSV, JSON, PNG) are whatever the stage created or changed in the run
        # directory; their fingerprints make deleting or editing one re-run the stage.
        after = _run_files(run_dir)
        f.attrs["side_outputs"] = json.dumps({k: v for k, v in after.items() if before.get(k) != v}, sort_keys=True)
    log.info("%s: wrote %s in %.2f s", name, path, time.perf_counter() - t0)


def _run_files(run_dir: Path) -> dict[str, str]:
    """Fingerprints of the files in a run directory that are not artifacts, temporary
    files or the runner's own files."""
    out = {}
    for p in run_dir.rglob("*"):
        rel = p.relative_to(run_dir)
        if not p.is_file() or TMP_MARK in p.name or (len(rel.parts) == 1 and (p.suffix == ".h5" or p.name in RUN_FILES)):
            continue
        out[str(rel)] = _path_fingerprint(p)
    return out


def side_outputs_intact(path: Path) -> bool:
    """True when every side output recorded in the artifact at ``path`` is still there,
    unchanged (same size and modification time)."""
    try:
        with h5py.File(path, "r") as f:
            recorded = json.loads(f.attrs.get("side_outputs", "{}"))
    except (OSError, ValueError):
        return False
    return all(_path_fingerprint(path.parent / name) == fp for name, fp in recorded.items())


def run_all(config: dict[str, Any], run_dir: str | Path, force: bool = False, quiet: bool = False) -> Path:
    """All stages in order (each skipped when up to date); returns the evaluate artifact."""
    return run_stage(config, run_dir, STAGES[-1], quiet=quiet, force_all=force)


def read_metrics(run_dir: str | Path) -> dict[str, Any]:
    return json.loads((Path(run_dir) / "metrics.json").read_text())
