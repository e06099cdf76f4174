"""Run stages in order, skip the ones whose artifact is up to date, write atomically.

``run_stage(config, run_dir, "localize")`` first brings every earlier stage up to date
(running only those whose stamp changed), then runs ``localize`` if its own stamp changed
or ``force`` is set. Each stage's function gets a :class:`StageContext`.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator, Sequence

import h5py

from placeloc import __version__
from placeloc.core.artifacts import (
    TMP_MARK,
    DiskFullError,
    atomic_h5,
    atomic_open,
    disk_full_error,
    is_disk_full,
    provenance_attrs,
    raise_if_disk_full,
    read_stamp,
    read_write_id,
    remove_stale_tmp,
    stamp_and_reason,
    stamp_token,
    tmp_path_for,
)
from placeloc.core.common_params import CommonParams
from placeloc.core.config import MAX_CONFIG_BYTES, config_hash, to_yaml
from placeloc.core.errors import RunDirError, StageError  # noqa: F401 - re-exported for callers of placeloc.core.runner
from placeloc.core.executor import Executor, remove_stale_shared
from placeloc.core.executors import make_executor
from placeloc.core.images import IMAGE_EXTENSIONS, ImageSet, list_images
from placeloc.core.interrupts import raise_if_interrupted
from placeloc.core.limits import check_inputs, check_resources
from placeloc.core.methods import BASE_SECTIONS, STAGES, Method, get_method
from placeloc.core.params import from_section
from placeloc.core.safe_io import UnsafeInputError, open_run_file, read_run_file
from placeloc.core.source import code_fingerprint  # noqa: F401 - re-exported: placeloc.core.runner.code_fingerprint

try:
    import fcntl
except ImportError:  # not POSIX: runs are not locked (documented in docs/reliability.md)
    fcntl = None  # type: ignore[assignment]

log = logging.getLogger("placeloc")

# Files in a run directory that belong to no stage (written by the runner itself).
RUN_FILES = ("config.yaml", "log.txt", ".lock")
# First line of every config.yaml the runner writes: a config.yaml without it is the
# user's own file, which a run never overwrites.
CONFIG_HEADER = "# placeloc run config: written by placeloc after the last run that finished without error\n"
# Non-image files in an image folder that a stage may read implicitly (poses, timestamps).
SIDECAR_SUFFIXES = (".csv", ".txt", ".json", ".yaml", ".yml")


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
    # The earlier stages whose artifacts this one may open (Method.stage_ancestors); None: any
    reads: frozenset[str] | None = None

    # The method's parameter object (see placeloc.core.params), built once per run.
    params: Any = None
    # The common sections (reference, query, ground_truth, executor, plots, seed) as the
    # typed parameter object of placeloc.core.common_params: ctx.common.ground_truth.radius.
    common: CommonParams | None = None
    # Where side outputs are written while the stage runs (a hidden folder in the run
    # directory); the runner moves them into the run directory together with the artifact,
    # and only when the stage succeeded. None: straight into the run directory.
    staging: Path | None = None
    # This stage's previous artifact, kept under a temporary name while the stage runs (the
    # runner removes RUN_DIR/<stage>.h5 before a re-run on other inputs): the per-image
    # engine takes the rows of unchanged images from it where the same code wrote them
    # (placeloc.core.imagework). None: none, damaged, or the run forced.
    previous: Path | None = None

    @property
    def output_dir(self) -> Path:
        """The folder :meth:`output` paths lie in (for writers that take a folder)."""
        return self.staging if self.staging is not None else self.run_dir

    def output(self, name: str) -> Path:
        """Where this stage writes the side output ``name`` (CSV, JSON, PNG, HTML).

        Stages write side outputs only through this path: it lies in a staging folder, and
        the runner moves every file there into ``run_dir`` together with the artifact when
        the stage finished without error (none of them appear when it fails).
        """
        path = self.output_dir / name
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def public_path(self, path: Path) -> Path:
        """Where a staged file will appear (for messages): RUN_DIR/name, not the staging folder."""
        path = Path(path)
        if path.name.startswith(".") and TMP_MARK in path.name:  # a writer's temporary file
            path = path.with_name(path.name[1:].rsplit(TMP_MARK, 1)[0])
        if self.staging is not None and self.staging in path.parents:
            return self.run_dir / path.relative_to(self.staging)
        return path

    def artifact(self, stage: str) -> h5py.File:
        """Open the artifact of an earlier stage read-only (closed by the runner)."""
        if self.reads is not None and stage not in self.reads:
            # its stamp does not cover that artifact: a re-run of it would not re-run this stage
            raise RuntimeError(f"{self.method.name}.{self.stage} reads {stage}.h5, which is not among its parents "
                               f"or theirs ({', '.join(sorted(self.reads)) or 'none'}): add it to the stage's "
                               "Stage.parents")
        path = self.run_dir / f"{stage}.h5"
        if not path.is_file():
            raise StageError(f"{path} is missing: run `placeloc {stage}` first")
        try:
            f = h5py.File(path, "r")
        except OSError as exc:
            raise StageError(f"{path} cannot be read as HDF5 ({' '.join(str(exc).split())}); "
                             f"re-run that stage: placeloc {stage} --force") from exc
        self._open.append(f)
        return f

    def progress(self, iterable: Iterable[Any], total: int | None = None, desc: str = "") -> Iterator[Any]:
        bar = iterable
        if not self.quiet:
            from tqdm import tqdm  # here: importing tqdm costs a quiet run 30-100 ms

            bar = tqdm(iterable, total=total, desc=desc or self.stage, file=sys.stderr, dynamic_ncols=True, leave=False)
        for item in bar:
            # A full disk, or a Ctrl-C whose exception was swallowed, stops the stage at the
            # next step instead of at its end.
            raise_if_disk_full(self.out)
            raise_if_interrupted()
            yield item

    def close(self) -> None:
        for f in self._open:
            f.close()
        self._open.clear()


def common_params(config: dict[str, Any]) -> CommonParams:
    """The common sections of a validated config as their typed parameter object."""
    return from_section(CommonParams, {k: v for k, v in config.items() if v is not None})


def normalise_stage(name: str) -> str:
    if name not in STAGES:
        raise StageError(f"unknown stage {name!r}; stages are {', '.join(STAGES)}")
    return name


def image_sets(config: dict[str, Any]) -> dict[str, ImageSet]:
    sets = {}
    for role in ("reference", "query"):
        section = config.get(role)
        if section and section.get("images"):
            sets[role] = list_images(section["images"], section.get("on_error", "stop"),
                                     fingerprint=section.get("fingerprint", "stat"))
            for message in sets[role].skipped:  # link loops found while listing (on_error: skip)
                log.warning("skipped: %s", message)
    return sets


def _sidecar_fingerprint(images: dict[str, ImageSet]) -> str:
    """Fingerprint of the non-image files (CSV, TXT, JSON, YAML) in the image folders: a
    stage that reads ground truth may read them implicitly (e.g. poses.csv beside frames)."""
    rows = []
    for role, s in sorted(images.items()):
        folder = Path(s.source) if Path(s.source).is_dir() else (s.paths[0].parent if s.paths else None)
        if folder is None:
            continue
        # names first, by suffix, then a Path for the few kept: a folder holds thousands of images
        with os.scandir(folder) as entries:
            names = sorted(e.name for e in entries if os.path.splitext(e.name)[1].lower() in SIDECAR_SUFFIXES)
        for name in names:
            p = folder / name
            if p.is_file():
                rows.append(f"{role}/{p.name}:{_path_fingerprint(p)}")
    return config_hash(rows)


# the config sections that name the image traverses
IMAGE_SECTIONS = ("reference", "query")


def sees_images(method: Method, stage: str) -> bool:
    """Whether ``stage`` depends on the images: the first stage does, and every stage that
    has it among its ancestors (:meth:`Method.stage_ancestors`); the others get no images
    (``ctx.images`` empty) and their stamps leave the image sections out."""
    return stage == STAGES[0] or STAGES[0] in method.stage_ancestors(stage)


def stage_inputs(config: dict[str, Any], method: Method, stage: str, images: dict[str, ImageSet],
                 parent_tokens: dict[str, str]) -> dict[str, Any]:
    """Everything a stage's result depends on, as JSON-able fingerprints: the parameters
    and sections it declares, images and files named by path parameters (first stage), the
    ground-truth file (if it reads that section) and its parents' tokens (``parent_tokens``,
    stage -> :func:`_parent_token`): as ``parent``, the one token, where its parent is the
    stage before it (:meth:`Method.stage_parents`), else as ``parents``, by stage."""
    declared = method.stages.get(stage)
    keys = declared.keys if declared is not None else ()
    sections = declared.sections if declared is not None else ()
    section = config.get(method.name, {})
    method_part = {k: _lookup(section, k) for k in keys}
    # the image traverses' sections (their folders, on_error) only where it sees the images:
    # UMap's map, drawn from the plan alone, is the same for any folder of photos
    base = BASE_SECTIONS if sees_images(method, stage) else tuple(k for k in BASE_SECTIONS if k not in IMAGE_SECTIONS)
    common = {k: _lookup(config, k) for k in base + tuple(sections)}  # a section, or one key of it (dotted)
    inputs: dict[str, Any] = {"config": config_hash({"common": common, "method": method_part})}
    if stage == STAGES[0]:
        for role, s in images.items():
            inputs[f"images.{role}"] = s.fingerprint()
    # Files named by the method's own path keys (models, observation CSVs, ...): a change
    # re-runs the first stage and so, through the parent stamps, everything after it; or,
    # for a file only a later stage reads (Method.file_stages), that stage on.
    for key in method.path_keys:
        if method.file_stages.get(key, STAGES[0]) != stage:
            continue
        node: Any = section
        for part in key.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        if node:
            inputs[f"file.{key}"] = _path_fingerprint(Path(str(node)))
    gt_path = (config.get("ground_truth") or {}).get("path")
    if "ground_truth" in sections and gt_path and Path(gt_path).is_file():
        inputs["ground_truth_file"] = _path_fingerprint(Path(gt_path))
    if "ground_truth" in sections and images:
        inputs["sidecar_files"] = _sidecar_fingerprint(images)
    declared_parents = declared.parents if declared is not None else None
    if declared_parents is not None:
        inputs["parents"] = {name: parent_tokens[name] for name in declared_parents}
    elif parent_tokens:
        (inputs["parent"],) = parent_tokens.values()
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
              quiet: bool = False, force_all: bool = False, wait: bool = False,
              reuse: Sequence[str | Path] = ()) -> Path:
    """Bring ``stage`` (and every stage before it) up to date; return its artifact path.

    ``force`` re-runs ``stage`` even when up to date; ``force_all`` every stage up to it.
    The run directory is locked for the whole call: a second run on it stops at once
    (``wait=False``, naming the holder) or waits for the first to finish.

    ``reuse``: other run directories (a sweep's other points) whose artifacts this run may
    take instead of computing them, where one has exactly the stamp this stage would have
    (so the same inputs, parameters and parents) and no side outputs (:func:`_reuse`).
    """
    stage = normalise_stage(stage)
    run_dir = Path(run_dir)
    check_run_dir(config, run_dir)
    make_run_dir(run_dir)
    with lock_run_dir(run_dir, wait=wait), run_log(run_dir):
        log.info("run: %s up to %s in %s (placeloc %s, pid %d)", config["method"], stage, run_dir, __version__, os.getpid())
        try:
            path = _run_locked(config, run_dir, stage, force, quiet, force_all, [Path(d) for d in reuse])
        except BaseException as exc:
            log.debug("failed: %s: %s", type(exc).__name__, exc)
            _log_to_file_only(run_dir, f"failed: {type(exc).__name__}: {' '.join(str(exc).split())}")
            raise
        write_run_config(run_dir, config)
        return path


def _run_locked(config: dict[str, Any], run_dir: Path, stage: str, force: bool, quiet: bool, force_all: bool,
                reuse: Sequence[Path] = ()) -> Path:
    remove_stale_tmp(run_dir)
    remove_stale_shared()
    method = get_method(config["method"])
    # the stage and those it depends on (every one before it, unless stages name fewer parents:
    # `placeloc index` of UMap draws the map without reading a photo)
    ancestors = method.stage_ancestors(stage)
    needed = [n for n in STAGES[: STAGES.index(stage) + 1] if n == stage or n in ancestors]
    images = image_sets(config) if method.uses_images and any(sees_images(method, n) for n in needed) else {}
    check_inputs(config, images)
    tokens: dict[str, str] = {}   # each stage brought up to date: what its children record of it
    executor: Executor | None = None
    try:
        for name in needed:
            raise_if_interrupted()
            path = run_dir / f"{name}.h5"
            inputs = stage_inputs(config, method, name, images, {p: tokens[p] for p in method.stage_parents(name)})
            stamp = config_hash({"version": __version__, "code": code_fingerprint(), "stage": name, "inputs": inputs})
            forced = force_all or (force and name == stage)
            found, why = stamp_and_reason(path)
            if found == stamp and side_outputs_intact(path) and not forced:
                log.info("%s: up to date (%s), skipped", name, path)
                tokens[name] = _parent_token(stamp, path)
                continue
            if why is not None:
                log.warning("%s: %s cannot be used: %s; the stage runs again", name, path, why)
            elif found is not None and found != stamp:
                other = _written_by_other_code(path)
                if other:
                    log.info("%s: %s was written by other placeloc code (source fingerprint %s, now %s); the stage "
                             "runs again", name, path, other[:12], code_fingerprint()[:12])
            # kept before _remove_previous_outputs deletes it: the rows of unchanged images are
            # taken from it (a forced run describes every image again, as asked)
            previous = _keep_previous(path) if why is None and not forced and sees_images(method, name) else None
            try:
                if reuse and not forced:
                    _remove_previous_outputs(path, stamp)
                    donor = _reuse(path, stamp, reuse)
                    if donor is not None:
                        log.info("%s: the same as %s (linked, not computed again)", name, donor)
                        tokens[name] = _parent_token(stamp, path)
                        continue
                if executor is None:
                    # Before the first stage that does work: will it fit in memory and on disk?
                    check_resources(config, images, run_dir, needed[needed.index(name):])
                    executor = make_executor(common_params(config).executor)
                _remove_previous_outputs(path, stamp)
                _execute(method, config, run_dir, name, path, inputs, stamp, images, executor, quiet, previous)
            finally:
                if previous is not None:
                    with contextlib.suppress(OSError):
                        previous.unlink()
            tokens[name] = _parent_token(stamp, path)
    finally:
        if executor is not None:
            executor.close()
    return run_dir / f"{stage}.h5"


def _keep_previous(path: Path) -> Path | None:
    """A second name (a hard link, hidden, temporary) for the artifact at ``path`` while its
    stage runs again; None where there is none.

    Why: a stage re-run on other inputs first deletes its previous artifact (so a failure
    leaves no stale result), yet its rows for the images that did not change are still
    right; the link keeps them readable for the engine until the stage ends, then goes.
    Whether they may be taken (the same code, work and image) the engine alone decides
    (:func:`placeloc.core.imagework.previous_rows`). Left behind by a killed run, it is
    removed as any temporary file (remove_stale_tmp)."""
    if not path.is_file():
        return None
    keep = path.with_name(f".{path.name}.previous{TMP_MARK}{os.getpid()}")
    try:
        with contextlib.suppress(FileNotFoundError):
            keep.unlink()
        os.link(path, keep)
    except OSError as exc:  # no hard links here: every image is described, as before
        log.debug("%s: not kept for its rows (%s)", path, exc)
        return None
    return keep


def _reuse(path: Path, stamp: str, donors: Sequence[Path]) -> Path | None:
    """Hard-link the artifact of the first donor run directory whose ``path.name`` has
    exactly ``stamp`` and records no side outputs into ``path``; return it, or None.

    Why: the points of a sweep differ in a few keys, so most share their first stages
    (SeqSLAM's extract; UMap's build-dictionary and its index, 0.75-1 GB and seconds of
    renders at a home's size). The stamp covers everything a stage depends on, parents
    included (their write ids too, which a link keeps), so an equal stamp is the same
    result. A link, not a copy: no time, no second copy on disk, and safe because an
    artifact is never changed in place (a re-run renames a new file over its own name,
    which leaves the other directory's link as it was). Artifacts with side outputs (CSV,
    PNG) are not shared: those files could be edited in place. Where links cannot be made
    (another file system), the stage is computed as usual."""
    for donor in donors:
        src = donor / path.name
        try:
            # a link is not a run's own artifact (the run-folder guard reads none): never linked on
            if src.is_symlink() or src.resolve() == path.resolve() or not src.is_file():
                continue
        except OSError:
            continue
        if read_stamp(src) != stamp or _recorded_side_outputs(src) != {}:
            continue
        tmp = tmp_path_for(path)
        try:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            os.link(src, tmp)
            os.replace(tmp, path)
        except OSError as exc:
            log.debug("%s: not linked from %s (%s)", path.name, src, exc)
            with contextlib.suppress(OSError):
                tmp.unlink()
            continue
        if read_stamp(path) != stamp:  # the donor's file was replaced in between: compute it
            with contextlib.suppress(OSError):
                path.unlink()
            continue
        return src
    return None


def _written_by_other_code(path: Path) -> str | None:
    """The source fingerprint an artifact records where it is not this code's
    (:func:`code_fingerprint`), else None (the same code, or an artifact from before
    fingerprints were recorded)."""
    try:
        with h5py.File(path, "r") as f:
            code = f.attrs.get("placeloc_code")
    except OSError:
        return None
    code = code.decode() if isinstance(code, bytes) else code
    return code if code and code != code_fingerprint() else None


def _parent_token(stamp: str, path: Path) -> str:
    """What a child records of its parent at ``path`` (:func:`stamp_token`)."""
    return stamp_token(stamp, read_write_id(path))


def _remove_previous_outputs(path: Path, stamp: str) -> None:
    """Before a stage re-runs on other inputs, delete its previous artifact and the side
    outputs that run recorded, together: they describe inputs that are gone, and a failure
    must not leave e.g. an old metrics.json beside a new localize.h5. A forced re-run on the
    same inputs keeps them until the new ones replace them all at once (so a failed
    ``--force`` leaves the previous complete set as it was)."""
    if not path.is_file():
        return
    old_stamp = read_stamp(path)
    if old_stamp is not None and str(old_stamp) == stamp:
        return
    _remove_side_outputs(path.parent, _recorded_side_outputs(path) or {})
    with contextlib.suppress(FileNotFoundError):
        path.unlink()


def _remove_side_outputs(run_dir: Path, names: Iterable[str]) -> None:
    root = run_dir.resolve()
    for name in names:
        target = (run_dir / name).resolve()
        if root in target.parents:  # never outside the run directory
            with contextlib.suppress(FileNotFoundError, IsADirectoryError, NotADirectoryError):
                target.unlink()


# ----------------------------------------------------------------- the run directory

def check_run_dir(config: dict[str, Any], run_dir: Path) -> None:
    """Refuse a run directory that is (or lies inside) an input image folder, that holds
    images but no placeloc run, or whose config.yaml placeloc did not write."""
    rd = run_dir.resolve()
    for role in ("reference", "query"):
        section = config.get(role) or {}
        spec = section.get("images")
        if not spec:
            continue
        folder = Path(spec) if Path(spec).is_dir() else Path(spec).parent
        folder = folder.resolve()
        if rd == folder or folder in rd.parents:
            raise RunDirError(f"--run-dir {run_dir} is the {role} image folder ({role}.images) or inside it: "
                              "its PNG plots would be read as images next time; choose another --run-dir, e.g. runs/NAME")
    if not rd.is_dir():
        return
    cfg = rd / "config.yaml"
    if cfg.is_file() or cfg.is_symlink():
        # through the run-folder guard: a link (to /dev/zero, to a huge file) is refused, not read
        try:
            text = read_run_file(rd, "config.yaml", MAX_CONFIG_BYTES + len(CONFIG_HEADER)).decode("utf-8", "replace")
        except OSError:
            text = ""
        if not text.startswith(CONFIG_HEADER) and not _written_by_older_placeloc(cfg, text):
            raise RunDirError(f"{cfg} was not written by placeloc; refusing to overwrite it: "
                              "choose another --run-dir (a run directory holds only placeloc's outputs)")
    elif not any(rd.glob("*.h5")):
        for p in rd.iterdir():
            if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS:
                raise RunDirError(f"--run-dir {run_dir} holds images ({p.name}) but no placeloc run: it looks like an "
                                  "image folder; choose another --run-dir, e.g. runs/NAME")


def make_run_dir(run_dir: Path) -> None:
    """Create the run directory, or say why it cannot be one (a file, not writable)."""
    if run_dir.exists() and not run_dir.is_dir():
        raise RunDirError(f"--run-dir {run_dir} is a file, not a folder; give a folder for the run's results "
                          f"(e.g. {run_dir.with_suffix('')}-run) or move the file away")
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except FileExistsError as exc:  # a part of the path is a file
        raise RunDirError(f"--run-dir {run_dir}: a part of the path is a file ({exc.filename}); choose another --run-dir") from None
    except NotADirectoryError:
        raise RunDirError(f"--run-dir {run_dir}: a part of the path is a file, not a folder; choose another --run-dir") from None
    except OSError as exc:
        raise _unwritable(run_dir, exc) from None
    if not os.access(run_dir, os.W_OK | os.X_OK):
        raise _unwritable(run_dir, PermissionError(13, "Permission denied"))


def _unwritable(run_dir: Path, exc: OSError) -> RunDirError:
    import errno

    why = "is on a read-only file system" if exc.errno == errno.EROFS else (
        "is not writable for you (permission denied)" if exc.errno in (errno.EACCES, errno.EPERM)
        else f"cannot be written ({exc.strerror or exc})")
    return RunDirError(f"--run-dir {run_dir} {why}: placeloc writes its lock, log and results there, even when every "
                       "stage is up to date; make it writable (chmod u+w) or choose another --run-dir")


def _written_by_older_placeloc(cfg: Path, text: str) -> bool:
    """Run directories from before the header: config.yaml (``text``) is ours when an
    artifact beside it carries the same config text."""
    for artifact in cfg.parent.glob("*.h5"):
        try:
            with h5py.File(artifact, "r") as f:
                if str(f.attrs.get("config_yaml", "")) == text:
                    return True
        except OSError:
            continue
    return False


def write_run_config(run_dir: Path, config: dict[str, Any]) -> None:
    with atomic_open(run_dir / "config.yaml") as fh:
        fh.write(CONFIG_HEADER + to_yaml(config))


# flock's errors where a file system has no locks (not: another process holds the lock)
_NO_LOCKS = frozenset(getattr(errno, name) for name in ("ENOLCK", "EOPNOTSUPP", "ENOTSUP", "ENOSYS", "EINVAL")
                      if hasattr(errno, name))


@contextlib.contextmanager
def lock_run_dir(run_dir: Path, wait: bool = False) -> Iterator[None]:
    """Hold an exclusive lock on RUN_DIR/.lock (released by the OS if the process dies)."""
    if fcntl is None:
        yield
        return
    try:
        fd = open_run_file(run_dir, ".lock", os.O_RDWR | os.O_CREAT)  # a link at .lock is refused, not followed
    except OSError as exc:  # read-only file system, or a folder (or .lock) we may not write
        raise _unwritable(run_dir, exc) from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "unknown"
            if not wait:
                raise RunDirError(f"{run_dir} is in use by another placeloc run (pid {holder}); wait for it to finish, "
                                  "or pass --wait to queue behind it, or choose another --run-dir") from None
            log.info("waiting for placeloc pid %s to finish with %s", holder, run_dir)
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError as exc:
            if exc.errno not in _NO_LOCKS:
                raise
            # Some network and FUSE file systems (older NFS without lockd, SMB mounts, sshfs)
            # have no locks at all: the run goes on unguarded rather than not at all.
            log.warning("%s: its file system has no file locks (%s), so nothing stops a second placeloc run "
                        "from writing into this folder at the same time: start one at a time", run_dir,
                        os.strerror(exc.errno))
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)  # closing drops the lock


class _BestEffortFileHandler(logging.FileHandler):
    """log.txt is a record, not a result: a full disk must not turn each log line into a
    "Logging error" traceback (the write that matters reports the full disk itself)."""

    def handleError(self, record: logging.LogRecord) -> None:
        pass

    def _open(self) -> Any:
        # through the run-folder guard: a symbolic link or FIFO at log.txt is refused, not followed
        path = Path(self.baseFilename)
        fd = open_run_file(path.parent, path.name, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
        return os.fdopen(fd, "a", encoding=self.encoding, errors=self.errors)


@contextlib.contextmanager
def run_log(run_dir: Path) -> Iterator[None]:
    """Append this run's log lines (with times) to RUN_DIR/log.txt."""
    handler = _BestEffortFileHandler(run_dir / "log.txt", mode="a", encoding="utf-8")  # opened now: a bad log.txt stops the run
    handler.setFormatter(logging.Formatter("%(asctime)s %(message)s", "%Y-%m-%dT%H:%M:%S"))
    handler.setLevel(logging.INFO)
    old_level = log.level
    if log.getEffectiveLevel() > logging.INFO:
        log.setLevel(logging.INFO)  # the file gets INFO lines even when the terminal is quiet
        for h in logging.getLogger().handlers:
            if h.level == logging.NOTSET:
                h.setLevel(logging.getLogger().level)
    log.addHandler(handler)
    try:
        yield
    finally:
        log.removeHandler(handler)
        handler.close()
        log.setLevel(old_level)


def _log_to_file_only(run_dir: Path, line: str) -> None:
    with contextlib.suppress(OSError, UnsafeInputError), \
            os.fdopen(open_run_file(run_dir, "log.txt", os.O_WRONLY | os.O_APPEND | os.O_CREAT), "a", encoding="utf-8") as fh:
        fh.write(f"{time.strftime('%Y-%m-%dT%H:%M:%S')} {line}\n")


def _execute(method: Method, config: dict[str, Any], run_dir: Path, name: str, path: Path,
             inputs: dict[str, Any], stamp: str, images: dict[str, ImageSet], executor: Executor,
             quiet: bool, previous_artifact: Path | None = None) -> None:
    declared = method.stages.get(name)
    fn = declared.run if declared is not None else None
    note = "" if fn is not None else f"{method.name} has no work in {name}: input passed through"
    attrs = provenance_attrs(name, method.name, __version__, to_yaml(config),
                             config_hash(config), inputs, stamp, passthrough=fn is None, note=note,
                             placeloc_code=code_fingerprint())
    t0 = time.perf_counter()
    staging = run_dir / f".{name}.outputs{TMP_MARK}{os.getpid()}"
    previous = (_recorded_side_outputs(path) or {}) if path.is_file() else {}
    staged: dict[str, str] = {}

    def commit() -> None:
        # Called by atomic_h5 once the artifact is complete on disk, just before its rename:
        # the side outputs move into place first, the artifact last.
        _commit_side_outputs(run_dir, staging, staged, previous)

    try:
        with atomic_h5(path, attrs, before_rename=commit) as f:
            if fn is None:
                log.info("%s: %s", name, note)
                return
            log.info("%s: running %s", name, method.name)
            staging.mkdir()
            # the images only where the first stage is among its ancestors (its stamp covers them)
            ctx = StageContext(stage=name, method=method, config=config, run_dir=run_dir, out=f,
                               executor=executor, quiet=quiet, images=images if sees_images(method, name) else {},
                               params=method.build_params(config), common=common_params(config),
                               staging=staging, reads=method.stage_ancestors(name),
                               previous=previous_artifact)
            before = _run_files(run_dir)
            _run_stage_fn(fn, ctx, run_dir, name)
            f.attrs["seconds"] = time.perf_counter() - t0
            staged.update(_staged_files(staging))
            _check_targets(run_dir, staged)
            # Side outputs (CSV, JSON, PNG): the files the stage staged, and any it wrote into
            # the run directory itself; their fingerprints (kept by the rename) make deleting or
            # editing one re-run the stage.
            after = _run_files(run_dir)
            direct = {k: v for k, v in after.items() if before.get(k) != v}
            f.attrs["side_outputs"] = json.dumps({**direct, **staged}, sort_keys=True)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    log.info("%s: wrote %s in %.2f s", name, path, time.perf_counter() - t0)


def _run_stage_fn(fn: Any, ctx: StageContext, run_dir: Path, name: str) -> None:
    """Call a stage function, turning the failures it cannot word itself into one line."""
    opened: list[str] = []
    try:
        fn(ctx)
    except OSError as exc:
        # A side output (CSV, JSON, PNG) written with plain Python I/O met a full disk:
        # name the place, as atomic_h5 does for artifacts.
        if isinstance(exc, DiskFullError) and ctx.staging is not None:
            # name the file where it would have appeared, not its staging folder
            raise DiskFullError(exc.errno, str(exc).replace(f"{ctx.staging}/", f"{run_dir}/")) from None
        if is_disk_full(exc) and not isinstance(exc, DiskFullError):
            where = Path(exc.filename) if exc.filename else run_dir / f"(a side output of {name})"
            raise disk_full_error(ctx.public_path(where), 0) from None
        raise
    except KeyError as exc:
        # h5py's "Unable to synchronously open object": an artifact lacks a dataset.
        if "open object" not in str(exc) and "doesn't exist" not in str(exc):
            raise
        opened = [f.filename for f in ctx._open]
        which = ", ".join(opened) or "an earlier artifact"
        raise StageError(f"{which}: a dataset the {name} stage needs is missing ({' '.join(str(exc).split())}); "
                         "the artifact is damaged or from another version: re-run the stage that wrote it with --force") from exc
    finally:
        ctx.close()


def _staged_files(staging: Path) -> dict[str, str]:
    """name -> fingerprint of every complete file a stage staged (not temporary files)."""
    out = {}
    for p in staging.rglob("*"):
        if p.is_file() and TMP_MARK not in p.name and not p.name.endswith(".tmp.png"):
            out[str(p.relative_to(staging))] = _path_fingerprint(p)
    return out


def _check_targets(run_dir: Path, staged: dict[str, str]) -> None:
    """Before anything moves: every staged file's place in the run directory must take a
    file (not a folder someone made there; the folder writable)."""
    for name in staged:
        target = run_dir / name
        if target.is_dir() and not target.is_symlink():
            raise RunDirError(f"{target} is a folder, but placeloc writes its {name} there; remove the folder "
                              f"(rmdir {target}) or choose another --run-dir, then re-run")
        folder = target.parent
        folder.mkdir(parents=True, exist_ok=True)
        if not os.access(folder, os.W_OK | os.X_OK):
            raise RunDirError(f"{folder} is not writable, so {name} cannot be written there; make it writable "
                              "(chmod u+w) or choose another --run-dir")


def _commit_side_outputs(run_dir: Path, staging: Path, staged: dict[str, str], previous: dict[str, str]) -> None:
    """Move the staged side outputs into the run directory (renames within one file system)
    and remove the ones the previous run of this stage wrote that this run did not; on a
    failure halfway, the ones already moved are removed again, so none of this run's appear."""
    moved: list[Path] = []
    try:
        for name in sorted(staged):
            target = run_dir / name
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(staging / name, target)
            moved.append(target)
    except BaseException:
        for target in moved:
            with contextlib.suppress(OSError):
                target.unlink()
        raise
    _remove_side_outputs(run_dir, [n for n in previous if n not in staged])


def _run_files(run_dir: Path) -> dict[str, str]:
    """Fingerprints of the files in a run directory that are not artifacts, temporary
    files or the runner's own files."""
    out = {}
    for p in run_dir.rglob("*"):
        rel = p.relative_to(run_dir)
        if not p.is_file() or any(TMP_MARK in part for part in rel.parts) or p.name.endswith(".tmp.png") \
                or (len(rel.parts) == 1 and (p.suffix == ".h5" or p.name in RUN_FILES)):
            continue
        out[str(rel)] = _path_fingerprint(p)
    return out


def _recorded_side_outputs(path: Path) -> dict[str, str] | None:
    """The side outputs (file -> fingerprint) recorded in an artifact; None if unreadable."""
    try:
        with h5py.File(path, "r") as f:
            return json.loads(f.attrs.get("side_outputs", "{}"))
    except (OSError, ValueError):
        return None


def side_outputs_intact(path: Path) -> bool:
    """True when every side output recorded in the artifact at ``path`` is still there,
    unchanged (same size and modification time)."""
    recorded = _recorded_side_outputs(path)
    return recorded is not None and all(_path_fingerprint(path.parent / name) == fp for name, fp in recorded.items())


def run_all(config: dict[str, Any], run_dir: str | Path, force: bool = False, quiet: bool = False) -> Path:
    """All stages in order (each skipped when up to date); returns the evaluate artifact."""
    return run_stage(config, run_dir, STAGES[-1], quiet=quiet, force_all=force)


def read_metrics(run_dir: str | Path) -> dict[str, Any]:
    return json.loads((Path(run_dir) / "metrics.json").read_text())
