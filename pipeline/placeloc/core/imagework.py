"""Per-image work, done by the engine for every method.

A method says what one image gives; the engine does everything else once: it reads the
images of a traverse (:class:`placeloc.core.images.ImageSet`) in their listed order,
applies the traverse's ``on_error`` policy, cuts the list into chunks mapped over
``ctx.executor`` (threads inside each chunk, since decoding and OpenCV release the GIL),
shows a progress bar, stores the arrays in HDF5 and records names, original indices and
skipped files. Modelled on hloc's ``extract_features`` (a model's ``_forward``: an image
in, a dict of named arrays out, possibly ragged, written per image).

What a method supplies, an :class:`ImageWork`:

- ``fn(image, **settings) -> {name: array}``: a module-level function (the executor sends
  it to worker processes by reference), thread-safe (it runs in threads of one worker), of
  one image (``read`` decides what that is: 8-bit greyscale by default) and explicit
  keyword arguments. An array is **fixed-size** (the same shape for every image: a feature
  row, a thumbnail) or **ragged** (listed in ``ragged``: its first axis varies per image,
  e.g. keypoints and their descriptors; all ragged arrays of one image have the same
  number of rows). Raising :class:`ImageError` rejects the image (skipped or fatal, by
  ``on_error``).
- optionally ``batch(arrays, **settings) -> arrays``: a vectorised step over the stacked
  fixed-size arrays of one chunk (SeqSLAM normalises all thumbnails of a chunk at once),
  run in the worker; it must treat the rows independently (a chunk's cut never changes a
  result);
- optionally ``same_size=True``: every image must have the first kept image's size (the
  check obeys ``on_error``); ``with_path=True``: ``fn`` also gets ``path=`` (to name the
  file in its own messages); ``offsets``: the name of the offsets dataset.

Storage (:func:`write_images`), in one HDF5 group per traverse:

=================  ==================================================================
``names``          (n) str, the kept images' file names
``index``          (n) int64, their positions in the listed folder (natural order from
                   0): images skipped with ``on_error: skip`` never shift an index
``skipped``        (s) str, one message per image left out (file and reason)
``<fixed>``        (n, ...) one row per kept image
``<ragged>``       (total, ...) the rows of all kept images, concatenated in order
``offsets``        (n + 1) int64: image ``i``'s ragged rows are ``offsets[i]:offsets[i+1]``
attributes         ``source`` (the folder or glob), ``n_listed`` (images listed)
=================  ==================================================================

Incremental extract: a run whose images changed only in part (a few added, edited or
removed) takes every other image's rows from the stage's previous artifact instead of
describing it again (``ctx.previous``: the runner keeps the old file under a temporary name
while the stage writes the new one), and stores exactly what a full run would. To tell
which rows may be taken, every group also holds

=================  ==================================================================
``image_keys``     (n) str, each kept image's :meth:`ImageSet.image_keys` key (name, size
                   and modification time; name and content hash with ``fingerprint:
                   content``)
``image_shapes``   (n, 2) int64, each kept image's (height, width), so ``same_size`` and
                   ``first_shape`` come out as in a full run
attributes         ``imagework_work`` (what the :class:`ImageWork` is: :func:`work_identity`),
                   ``imagework_arrays`` (the fixed-size arrays' names, JSON)
=================  ==================================================================

A row is taken only where the old artifact was written by this very code (its
``placeloc_code``), the work identity is equal and the image's key is equal; never with a
``fold`` (its rows depend on the images before). An artifact without these keys is not
used. Why exactness holds: a row depends only on its image and the work (``batch`` must
treat rows independently), and the merged stream is cut into the chunks a full run would
use, so ``skipped`` lists its messages in the same order.

Local and original indices: the arrays are in *local* order (row ``i`` is the ``i``-th
kept image); ``index[i]`` is its *original* position. Numerics and contracts work on local
rows; :func:`local_to_original` maps an answer back (``-1`` stays ``-1``).
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import json
import logging
import math
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator, Mapping

import numpy as np

from placeloc.core.errors import StageError
from placeloc.core.executor import usable_cores
from placeloc.core.images import ImageError, ImageSet, image_size, read_gray
from placeloc.core.source import code_fingerprint

if TYPE_CHECKING:  # the writer's side only: pool workers never import h5py for this module
    import h5py

log = logging.getLogger("placeloc")

Arrays = dict[str, np.ndarray]
# Chunks hold at most this many images unless the method asks otherwise: enough to amortise
# a process-pool task, few enough that every worker gets several.
MAX_IMAGES_PER_TASK = 64
# HDF5 chunks of about this many bytes (rows of a dataset per chunk follow from it).
H5_CHUNK_BYTES = 1 << 20


@dataclass(frozen=True)
class ImageWork:
    """What one image gives: see the module's documentation."""

    fn: Callable[..., Arrays]
    settings: Mapping[str, Any] = field(default_factory=dict)
    read: Callable[[str], np.ndarray] = read_gray
    ragged: tuple[str, ...] = ()
    batch: Callable[..., Arrays] | None = None
    same_size: bool = False
    # Pass the image's path to ``fn`` as ``path=`` (for messages that name the file).
    with_path: bool = False
    # Name of the ragged arrays' offsets dataset.
    offsets: str = "offsets"
    # Images per executor task; None: chosen from the number of images and workers.
    images_per_task: int | None = None


@dataclass
class ImageResult:
    """One kept image: its local row, original position, path, size and arrays."""

    local: int
    original: int
    path: str
    shape: tuple[int, int]
    arrays: Arrays


@dataclass
class ChunkResult:
    """What a worker returns for one chunk of images (positions relative to the chunk)."""

    kept: list[int]
    shapes: list[tuple[int, int]]
    fixed: Arrays
    ragged: Arrays
    counts: np.ndarray
    errors: list[tuple[int, str]]


def _describe_one(path: str, work: ImageWork) -> tuple[tuple[int, int], Arrays] | ImageError:
    try:
        image = work.read(path)
        settings = {**work.settings, "path": path} if work.with_path else work.settings
        return (int(image.shape[0]), int(image.shape[1])), work.fn(image, **settings)
    except ImageError as exc:
        return exc


_THREAD_POOLS: dict[int, ThreadPoolExecutor] = {}


def _thread_pool(threads: int) -> ThreadPoolExecutor:
    """One pool of ``threads`` threads per process, kept for every chunk: starting threads
    anew for each chunk cost more than describing a chunk of small images on a loaded machine."""
    if threads not in _THREAD_POOLS:
        _THREAD_POOLS[threads] = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="placeloc-images")
    return _THREAD_POOLS[threads]


@contextmanager
def opencv_threads(n: int) -> Iterator[None]:
    """OpenCV's own thread pool set to ``n`` threads meanwhile, then back (the engine's
    describing decodes images, so it imports OpenCV anyway). Where the engine describes
    images one after another on one thread (small frames: :data:`SMALL_IMAGE_PIXELS`),
    OpenCV's pool only wakes threads for work smaller than the waking: SeqSLAM's extract of
    7152 frames of 64 x 32 on 16 cores of an H100 host took 0.68-0.78 s of its own with one
    OpenCV thread against 0.84-0.91 s with its default pool (``OPENCV_FOR_THREADS_NUM=1``,
    three alternating runs)."""
    import cv2

    before = cv2.getNumThreads()
    cv2.setNumThreads(n)
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def describe_chunk(task: tuple[list[str], ImageWork, bool, int]) -> ChunkResult:
    """The executor's work item: ``(paths, work, skip, threads)`` -> a :class:`ChunkResult`.

    Images are described in ``threads`` threads, one contiguous part each; an unreadable or
    rejected image raises its :class:`ImageError` unless ``skip``."""
    paths, work, skip, threads = task
    threads = max(1, min(threads, len(paths)))

    def part(k: int) -> list[Any]:
        return [_describe_one(p, work) for p in paths[k * len(paths) // threads:(k + 1) * len(paths) // threads]]

    if threads == 1:
        with opencv_threads(1):
            results = part(0)
    else:
        results = [r for chunk in _thread_pool(threads).map(part, range(threads)) for r in chunk]
    kept, shapes, per_image, errors = [], [], [], []
    for i, res in enumerate(results):
        if isinstance(res, ImageError):
            if not skip:
                raise res
            errors.append((i, str(res)))
            continue
        kept.append(i)
        shapes.append(res[0])
        per_image.append(res[1])
    fixed, ragged, counts = _stack(per_image, work.ragged, [paths[i] for i in kept])
    if work.batch is not None and kept:
        fixed = {**fixed, **work.batch(fixed, **work.settings)}
    return ChunkResult(kept, shapes, fixed, ragged, counts, errors)


def _stack(per_image: list[Arrays], ragged_names: tuple[str, ...], paths: list[str]) -> tuple[Arrays, Arrays, np.ndarray]:
    """Stack the fixed-size arrays of several images and concatenate the ragged ones."""
    if not per_image:
        return {}, {}, np.zeros(0, np.int64)
    first = per_image[0]
    fixed: Arrays = {}
    ragged: Arrays = {}
    counts = np.array([_ragged_rows(a, ragged_names, p) for a, p in zip(per_image, paths)], np.int64)
    for name in first:
        values = [np.asarray(a[name]) for a in per_image]
        if name in ragged_names:
            ragged[name] = np.concatenate(values) if len(values) > 1 else values[0]
            continue
        for v, p in zip(values, paths):
            if v.shape != values[0].shape:
                raise StageError(f"{p}: the per-image output {name!r} has shape {v.shape}, the first image's {values[0].shape}; "
                                 "a fixed-size output must have one shape (declare it ragged if its length varies)")
        fixed[name] = np.stack(values)
    return fixed, ragged, counts


def _ragged_rows(arrays: Arrays, ragged_names: tuple[str, ...], path: str) -> int:
    rows = {name: len(arrays[name]) for name in ragged_names}
    if len(set(rows.values())) > 1:
        raise StageError(f"{path}: the ragged outputs of one image must have one row count, got {rows}")
    return next(iter(rows.values()), 0)


# Images smaller than this (pixels) are described on one thread per task: decoding them
# costs less than the Python work around each image, which holds the GIL, so a second
# thread only contends for it. Measured with SeqSLAM's extract on 2 cores (PNG, one thread
# against two): 64 x 32, 7152 images, 0.93 s against 1.25 s; 128 x 64, 3000 images, 0.68 s
# against 0.59 s; 256 x 128, 1.35 s against 0.92 s.
SMALL_IMAGE_PIXELS = 4096


def threads_per_task(workers: int, pixels: int | None = None) -> int:
    """Threads each of ``workers`` tasks describes images with: the usable cores shared among
    the workers (at most 8); one for images of fewer than :data:`SMALL_IMAGE_PIXELS`."""
    if pixels is not None and pixels < SMALL_IMAGE_PIXELS:
        return 1
    return max(1, min(8, usable_cores() // max(1, workers)))


def worker_threads(executor: Any, first_image: str | None = None) -> int:
    """:func:`threads_per_task` for ``executor``'s workers and ``first_image`` (a
    traverse's first file; its header gives the size)."""
    size = image_size(first_image) if first_image is not None else None
    return threads_per_task(int(getattr(executor, "workers", 1)), size[0] * size[1] if size is not None else None)


def images_per_task(n_images: int, workers: int) -> int:
    """Images per chunk when the method does not say: about four chunks per worker."""
    return max(1, min(MAX_IMAGES_PER_TASK, math.ceil(n_images / (4 * max(1, workers)))))


class ImageStream:
    """The described images of one traverse, in listed order; skipped ones left out.

    Iterating yields :class:`ImageResult` per kept image (:meth:`chunks`: per chunk);
    afterwards ``skipped`` holds the messages of the images left out (also logged)."""

    def __init__(self, ctx: Any, images: ImageSet, work: ImageWork, desc: str = "") -> None:
        self.ctx, self.images, self.work = ctx, images, work
        self.desc = desc or f"{ctx.stage} {images.source}"
        self.skipped: list[str] = list(images.skipped)
        self.first_shape: tuple[int, int] | None = None
        self.first_path: str | None = None
        # Rows of a previous artifact to take instead of describing (set by write_images).
        self.previous: PreviousRows | None = None

    def chunks(self) -> Iterator[tuple[list[int], ChunkResult]]:
        """(original positions of the kept images, chunk result) per chunk, in order."""
        paths = [str(p) for p in self.images.paths]
        workers = int(getattr(self.ctx.executor, "workers", 1))
        size = int(self.work.images_per_task or images_per_task(len(paths), workers))
        skip = self.images.on_error == "skip"
        if self.previous is not None and self.previous.rows:
            results: Iterable[ChunkResult] = self._merged(paths, size, skip, workers)
        else:
            threads = worker_threads(self.ctx.executor, paths[0] if paths else None)
            tasks = [(paths[i:i + size], self.work, skip, threads) for i in range(0, len(paths), size)]
            results = self.ctx.progress(self.ctx.executor.map(describe_chunk, tasks), total=len(tasks), desc=self.desc)
        for c, res in enumerate(results):
            start = c * size
            for _, message in res.errors:
                self._skip(message)
            if self.work.same_size:
                res = self._keep_same_size(res, paths, start, skip)
            elif self.first_shape is None and res.kept:   # the first kept image's size, for the artifact
                self.first_shape, self.first_path = res.shapes[0], paths[start + res.kept[0]]
            yield [start + i for i in res.kept], res

    def _merged(self, paths: list[str], size: int, skip: bool, workers: int) -> Iterator[ChunkResult]:
        """The chunk results a full run would give (cut every ``size`` images, before the
        ``same_size`` check), made of the previous artifact's rows where ``self.previous``
        has them and of the other images described now, in their own chunks."""
        previous = self.previous
        assert previous is not None
        todo = [i for i in range(len(paths)) if i not in previous.rows]
        per_task = int(self.work.images_per_task or images_per_task(len(todo), workers))
        threads = worker_threads(self.ctx.executor, paths[todo[0]] if todo else None)
        tasks = [([paths[i] for i in todo[k:k + per_task]], self.work, skip, threads)
                 for k in range(0, len(todo), per_task)]
        described: Iterator[_Described] = iter(())
        if tasks:
            results = self.ctx.executor.map(describe_chunk, tasks)
            described = _per_image(self.ctx.progress(results, total=len(tasks), desc=self.desc))
        for start in range(0, len(paths), size):
            positions = range(start, min(start + size, len(paths)))
            taken = previous.read([previous.rows[i] for i in positions if i in previous.rows])
            yield _assemble([taken[previous.rows[i]] if i in previous.rows else next(described) for i in positions])

    def _skip(self, message: str) -> None:
        log.warning("skipped: %s", message)
        self.skipped.append(message)

    def _keep_same_size(self, res: ChunkResult, paths: list[str], start: int, skip: bool) -> ChunkResult:
        keep = []
        for j, (i, shape) in enumerate(zip(res.kept, res.shapes)):
            if self.first_shape is None:
                self.first_shape, self.first_path = shape, paths[start + i]
            if shape == self.first_shape:
                keep.append(j)
                continue
            (h, w), (h0, w0) = shape, self.first_shape
            message = (f"{paths[start + i]}: size {w}x{h} differs from the first image's {w0}x{h0} ({self.first_path}); "
                       "every image of a traverse must have one size: resize them, or set on_error: skip beside images:")
            if not skip:
                raise ImageError(message)
            self._skip(message)
        if len(keep) == len(res.kept):
            return res
        return _select(res, keep)

    def __iter__(self) -> Iterator[ImageResult]:
        local = 0
        for originals, res in self.chunks():
            offsets = np.concatenate([[0], np.cumsum(res.counts)])
            for j, original in enumerate(originals):
                arrays = {k: v[j] for k, v in res.fixed.items()}
                arrays.update({k: v[offsets[j]:offsets[j + 1]] for k, v in res.ragged.items()})
                yield ImageResult(local, original, str(self.images.paths[original]), res.shapes[j], arrays)
                local += 1


def _select(res: ChunkResult, keep: list[int]) -> ChunkResult:
    """The part of a chunk result that keeps the images at positions ``keep`` of ``res.kept``."""
    offsets = np.concatenate([[0], np.cumsum(res.counts)])
    rows = np.concatenate([np.arange(offsets[j], offsets[j + 1]) for j in keep]) if keep else np.zeros(0, np.int64)
    return ChunkResult([res.kept[j] for j in keep], [res.shapes[j] for j in keep],
                       {k: v[keep] for k, v in res.fixed.items()}, {k: v[rows] for k, v in res.ragged.items()},
                       res.counts[keep], res.errors)


@dataclass
class _Described:
    """One image of a chunk: its size and arrays (a fixed row, its ragged rows), or the
    message of its error (``on_error: skip``)."""

    shape: tuple[int, int] = (0, 0)
    fixed: Arrays = field(default_factory=dict)
    ragged: Arrays = field(default_factory=dict)
    count: int = 0
    error: str | None = None


def _per_image(results: Iterable[ChunkResult]) -> Iterator[_Described]:
    """The images of chunk results one by one, in their listed order."""
    for res in results:
        errors = dict(res.errors)
        offsets = np.concatenate([[0], np.cumsum(res.counts)]).astype(np.int64)
        j = 0
        for position in range(len(res.kept) + len(res.errors)):
            if position in errors:
                yield _Described(error=errors[position])
                continue
            a, b = int(offsets[j]), int(offsets[j + 1])
            yield _Described(res.shapes[j], {k: v[j] for k, v in res.fixed.items()},
                             {k: v[a:b] for k, v in res.ragged.items()}, b - a)
            j += 1


def _assemble(parts: list[_Described]) -> ChunkResult:
    """A chunk result of images given one by one (their positions: 0, 1, ...)."""
    kept = [i for i, part in enumerate(parts) if part.error is None]
    errors = [(i, str(part.error)) for i, part in enumerate(parts) if part.error is not None]
    items = [parts[i] for i in kept]
    if not items:
        return ChunkResult([], [], {}, {}, np.zeros(0, np.int64), errors)
    fixed = {name: np.stack([item.fixed[name] for item in items]) for name in items[0].fixed}
    ragged = {name: np.concatenate([item.ragged[name] for item in items]) for name in items[0].ragged}
    return ChunkResult(kept, [item.shape for item in items], fixed, ragged,
                       np.array([item.count for item in items], np.int64), errors)


# What identifies a per-image work and an image in a group (see the module's documentation).
KEYS, SHAPES, WORK_ATTR, ARRAYS_ATTR = "image_keys", "image_shapes", "imagework_work", "imagework_arrays"


class _Unidentified(ValueError):
    """A part of a work that has no exact, lasting identity (a lambda, an object)."""


def _callable_identity(fn: Any) -> Any:
    if isinstance(fn, functools.partial):
        return {"partial": _callable_identity(fn.func), "args": _canonical(fn.args), "keywords": _canonical(fn.keywords)}
    name, module = getattr(fn, "__qualname__", None), getattr(fn, "__module__", None)
    # A lambda, a nested function or a bound method carries state its name does not show.
    if not name or not module or "<" in name or inspect.ismethod(fn):
        raise _Unidentified(repr(fn))
    return f"{module}.{name}"


def _canonical(value: Any) -> Any:
    """A JSON-able value equal for equal settings and different for different ones: types
    are kept apart (a tuple is not a list, 1 is not 1.0), floats by their exact repr, arrays
    by dtype, shape and a hash of their bytes (their repr is shortened)."""
    if value is None or isinstance(value, (bool, str)) or type(value) is int:
        return value
    if type(value) is float:
        return {"float": repr(value)}
    if isinstance(value, np.ndarray) and value.dtype != object:
        return {"ndarray": value.dtype.str, "shape": list(value.shape),
                "sha256": hashlib.sha256(np.ascontiguousarray(value).tobytes()).hexdigest()}
    if isinstance(value, np.generic) and not isinstance(value, np.object_):
        return {"numpy": value.dtype.str, "bytes": value.tobytes().hex()}
    if type(value) in (list, tuple):
        return {type(value).__name__: [_canonical(v) for v in value]}
    if type(value) is dict and all(isinstance(k, str) for k in value):
        return {"dict": [[k, _canonical(value[k])] for k in sorted(value)]}
    if isinstance(value, Path):
        return {"path": str(value)}
    if callable(value):
        return {"callable": _callable_identity(value)}
    raise _Unidentified(repr(value))


def work_identity(work: ImageWork) -> str | None:
    """Everything of ``work`` that can change a stored row, as one exact string; None when a
    part of it has no lasting identity (then no row is ever taken from an earlier run).
    ``images_per_task`` is left out: the cut of the chunks never changes a row."""
    try:
        return json.dumps({"fn": _callable_identity(work.fn), "settings": _canonical(dict(work.settings)),
                           "read": _callable_identity(work.read),
                           "batch": None if work.batch is None else _callable_identity(work.batch),
                           "ragged": list(work.ragged), "same_size": work.same_size, "with_path": work.with_path,
                           "offsets": work.offsets}, sort_keys=True)
    except _Unidentified as exc:
        log.debug("rows of this work are not taken from an earlier run: %s has no lasting identity", exc)
        return None


@dataclass
class PreviousRows:
    """The rows of a previous artifact's group that a run may take: ``rows`` maps a listed
    position of this run to the old local row of the same image."""

    group: h5py.Group
    rows: dict[int, int]
    fixed: list[str]
    ragged: tuple[str, ...]
    offsets: np.ndarray | None
    shapes: np.ndarray

    def read(self, rows: list[int]) -> dict[int, _Described]:
        """Old rows -> their images (one read per array: a chunk's rows lie close together)."""
        if not rows:
            return {}
        lo, hi = min(rows), max(rows) + 1
        fixed = {name: self.group[name][lo:hi] for name in self.fixed}
        off = self.offsets
        a, b = (int(off[lo]), int(off[hi])) if off is not None else (0, 0)
        ragged = {name: self.group[name][a:b] for name in self.ragged}
        out = {}
        for r in rows:
            r0, r1 = (int(off[r]) - a, int(off[r + 1]) - a) if off is not None else (0, 0)
            out[r] = _Described((int(self.shapes[r][0]), int(self.shapes[r][1])), {k: v[r - lo] for k, v in fixed.items()},
                                {k: v[r0:r1] for k, v in ragged.items()}, r1 - r0)
        return out


def previous_rows(previous: h5py.File | None, name: str, work: ImageWork, identity: str | None,
                  keys: list[str | None]) -> PreviousRows | None:
    """The rows of ``previous[name]`` this run may take (see the module's documentation), or
    None: another code or work, an artifact from before the keys, or nothing matches."""

    if previous is None or identity is None:
        return None
    code = previous.attrs.get("placeloc_code")
    code = code.decode() if isinstance(code, bytes) else code
    if code != code_fingerprint() or name not in previous:
        return None
    group = previous[name]
    if group.attrs.get(WORK_ATTR) != identity or ARRAYS_ATTR not in group.attrs:
        return None
    fixed = json.loads(group.attrs[ARRAYS_ATTR])
    needed = [KEYS, SHAPES, *fixed, *work.ragged] + ([work.offsets] if work.ragged else [])
    if not all(n in group for n in needed):
        return None
    old_keys = [k.decode() if isinstance(k, bytes) else str(k) for k in group[KEYS][()]]
    shapes = group[SHAPES][()]
    offsets = group[work.offsets][()] if work.ragged else None
    if len(shapes) != len(old_keys) or (offsets is not None and len(offsets) != len(old_keys) + 1):
        return None
    # a key found twice (a glob over folders with files of one name, size and time) is ambiguous: described
    old_count, new_count = Counter(old_keys), Counter(keys)
    old = {k: r for r, k in enumerate(old_keys) if old_count[k] == 1}
    rows = {i: old[k] for i, k in enumerate(keys) if k is not None and k in old and new_count[k] == 1}
    return PreviousRows(group, rows, fixed, work.ragged, offsets, shapes) if rows else None


def _open_previous(ctx: Any) -> h5py.File | None:
    """The stage's previous artifact (``ctx.previous``, kept by the runner), or None."""
    path = getattr(ctx, "previous", None)
    if path is None:
        return None
    import h5py

    try:
        return h5py.File(path, "r")
    except OSError as exc:  # unreadable: described in full, as without it
        log.debug("%s: not read for rows to take (%s)", path, exc)
        return None


@dataclass
class ImageTable:
    """What :func:`write_images` stored for one traverse."""

    index: np.ndarray
    names: list[str]
    skipped: list[str]
    n_listed: int
    first_shape: tuple[int, int] | None

    def __len__(self) -> int:
        return len(self.index)


class _Appender:
    """Resizable HDF5 datasets grown block by block (the writer holds one block at a time)."""

    def __init__(self, group: h5py.Group, rows_hint: int) -> None:
        self.group, self.rows_hint = group, max(1, rows_hint)
        self.sets: dict[str, h5py.Dataset] = {}

    def append(self, name: str, block: np.ndarray) -> None:
        block = np.asarray(block)
        ds = self.sets.get(name)
        if ds is None:
            row_bytes = max(1, int(np.prod(block.shape[1:], dtype=np.int64)) * block.dtype.itemsize)
            rows = max(1, min(self.rows_hint, H5_CHUNK_BYTES // row_bytes))
            ds = self.group.create_dataset(name, shape=(0, *block.shape[1:]), maxshape=(None, *block.shape[1:]),
                                           dtype=block.dtype, chunks=(rows, *block.shape[1:]))
            self.sets[name] = ds
        elif ds.shape[1:] != block.shape[1:]:
            raise StageError(f"{self.group.file.filename}: per-image output {name!r} changed shape from {ds.shape[1:]} "
                             f"to {block.shape[1:]} between images; a fixed-size output must have one shape")
        n0 = ds.shape[0]
        ds.resize(n0 + len(block), axis=0)
        ds[n0:] = block


def write_images(group: h5py.Group, stream: ImageStream, fold: Callable[[ImageResult], Arrays] | None = None,
                 ragged: tuple[str, ...] | None = None) -> ImageTable:
    """Describe every image of ``stream`` and store the results in ``group`` (layout in the
    module's documentation).

    ``fold`` (optional) turns each kept image's arrays, in order and in this process, into
    the arrays to store: a method's sequential step over the images (PIRF-nav2 chains each
    frame's descriptors with the previous frames'). ``ragged`` names the ragged arrays of
    what is stored (default: the work's)."""
    ragged_names = stream.work.ragged if ragged is None else ragged
    n = len(stream.images.paths)
    out = _Appender(group, n)
    index: list[int] = []
    counts: list[np.ndarray] = []
    if fold is None:
        # keys taken before any image is read: a file replaced meanwhile then has a newer key
        # than the one stored with its rows, and is described again next time
        keys = stream.images.image_keys()
        identity = work_identity(stream.work)
        previous = _open_previous(stream.ctx)
        shapes: list[tuple[int, int]] = []
        fixed_names: dict[str, None] = {}
        try:
            stream.previous = previous_rows(previous, group.name, stream.work, identity, keys)
            for originals, res in stream.chunks():
                index.extend(originals)
                if not originals:
                    continue
                for name, block in {**res.fixed, **res.ragged}.items():
                    out.append(name, block)
                counts.append(res.counts)
                shapes.extend(res.shapes)
                fixed_names.update(dict.fromkeys(res.fixed))
            # rows read from the previous artifact, and of those the kept ones (same_size may drop
            # some: an image of another size than a new first one)
            read = len(stream.previous.rows) if stream.previous is not None else 0
            taken = sum(i in stream.previous.rows for i in index) if stream.previous is not None else 0
        finally:
            stream.previous = None
            if previous is not None:
                previous.close()
        if read:
            stage = getattr(stream.ctx, "stage", "extract")
            # the traverse by its role (a group at the artifact's root, as UMap's, has no name)
            role = next((r for r, s in (getattr(stream.ctx, "images", None) or {}).items() if s.source == stream.images.source),
                        group.name.strip("/") or stream.images.source)
            log.info("%s %s: %d of %d images taken from the previous %s.h5 (unchanged), %d described",
                     stage, role, taken, n, stage, n - read)
        if identity is not None and index and all(keys[i] is not None for i in index):
            import h5py

            group.create_dataset(KEYS, data=np.array([keys[i] for i in index], dtype=object), dtype=h5py.string_dtype())
            group.create_dataset(SHAPES, data=np.asarray(shapes, np.int64).reshape(-1, 2))
            group.attrs[WORK_ATTR] = identity
            group.attrs[ARRAYS_ATTR] = json.dumps(list(fixed_names))
    else:
        for item in stream:
            arrays = fold(item)
            index.append(item.original)
            for name, value in arrays.items():
                value = np.asarray(value)
                out.append(name, value if name in ragged_names else value[None])
            counts.append(np.array([_ragged_rows(arrays, ragged_names, item.path)], np.int64))
    if not index:
        first = stream.skipped[0] if stream.skipped else "none"
        raise ImageError(f"{stream.images.source}: none of the {n} images could be used (first problem: {first}); "
                         "fix or replace them")
    if ragged_names:
        all_counts = np.concatenate(counts) if counts else np.zeros(0, np.int64)
        group.create_dataset(stream.work.offsets, data=np.concatenate([[0], np.cumsum(all_counts)]).astype(np.int64))
    import h5py

    names = [stream.images.paths[i].name for i in index]
    group.create_dataset("names", data=np.array(names, dtype=object), dtype=h5py.string_dtype())
    group.create_dataset("index", data=np.asarray(index, np.int64))
    group.create_dataset("skipped", data=np.array(stream.skipped, dtype=object), dtype=h5py.string_dtype())
    group.attrs["source"] = stream.images.source
    group.attrs["n_listed"] = n
    return ImageTable(np.asarray(index, np.int64), names, list(stream.skipped), n, stream.first_shape)


def extract_images(ctx: Any, work: ImageWork, fold: Callable[[str], Callable[[ImageResult], Arrays]] | None = None,
                   ragged: tuple[str, ...] | None = None) -> dict[str, ImageTable]:
    """The whole extract stage of a per-image method: every traverse of ``ctx.images`` into
    its own group (``reference/``, ``query/``) of ``ctx.out``. ``fold(role)`` (optional)
    gives the sequential step for that traverse (see :func:`write_images`)."""
    tables = {}
    for role, images in ctx.images.items():
        stream = ImageStream(ctx, images, work, desc=f"extract {role}")
        tables[role] = write_images(ctx.out.create_group(role), stream, fold(role) if fold else None, ragged)
    return tables


def read_ragged(group: h5py.Group, name: str, offsets: str = "offsets") -> list[np.ndarray]:
    """The per-image pieces of a ragged array stored by :func:`write_images`."""
    data, off = group[name][()], group[offsets][()]
    return [data[off[i]:off[i + 1]] for i in range(len(off) - 1)]


def local_to_original(index: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Original positions of local rows (``-1``, no answer, stays ``-1``)."""
    local = np.asarray(local)
    return np.where(local >= 0, np.asarray(index)[np.clip(local, 0, None)], -1)


def original_to_local(index: np.ndarray, original: np.ndarray) -> np.ndarray:
    """Local rows of original positions (``-1`` for a position that was skipped)."""
    index = np.asarray(index)
    lookup = np.full(int(index.max()) + 1 if len(index) else 0, -1, np.int64)
    lookup[index] = np.arange(len(index))
    original = np.asarray(original)
    inside = (original >= 0) & (original < len(lookup))
    return np.where(inside, lookup[np.clip(original, 0, max(0, len(lookup) - 1))] if len(lookup) else -1, -1)


__all__ = ["ImageWork", "PreviousRows", "previous_rows", "work_identity",
           "ImageResult", "ImageStream", "ImageTable", "describe_chunk", "extract_images", "write_images",
           "read_ragged", "local_to_original", "original_to_local", "images_per_task", "worker_threads", "threads_per_task"]
