"""The guards every read of a file placeloc did not write, and every write into a run
folder, goes through (docs/reliability.md, "Paths", "Sizes").

- :func:`name_inside`: a name taken from data (a ZInD floor key, ...) as one path
  component strictly inside a folder; ``..``, absolute paths, separators and links that
  lead out are refused.
- :func:`open_run_file`: a file of the run folder (lock, log, report inputs) opened
  without following a symbolic link, refused unless it is a regular file, with a size cap
  for reading.
- :func:`input_file` / :func:`read_input_bytes`: an input file must be a regular file
  (``/dev/zero``, a FIFO or a folder is refused before it is opened for reading, so
  nothing hangs or grows without end), of a bounded size.
- :func:`open_h5_input`: the one HDF5 opener for input files: a dataset stored in
  another file (external link, virtual dataset, external raw storage) is refused before
  any data is read, so a result never silently depends on a file no fingerprint covers.
- :func:`load_arrays`: ``.npy``/``.npz``/``.mat``/``.h5`` arrays whose shape and type are
  read from the header and checked against a byte budget before anything is allocated.
- :func:`load_yaml` is the one YAML parser (aliases refused, depth and size capped).

Code caches have their own guard, :mod:`placeloc.core.caches`.

Every refusal is an :class:`UnsafeInputError` (a ``ValueError`` raised by placeloc: one
line, exit code 2) naming the file and the fix.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import stat
import time
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator, Sequence

import yaml

if TYPE_CHECKING:  # numpy is imported where arrays are read: loading a config needs none of it
    import numpy as np

# A text input (CSV, YAML, JSON) larger than this is not a hand-written or exported table
# of a few hundred thousand rows: refuse it before reading.
MAX_TEXT_BYTES = 256 << 20
# YAML placeloc parses (configs, sweep files, floor plans) holds settings, not data.
MAX_YAML_BYTES = 1 << 20
# Objects walked in an input HDF5 file before it is refused as unreasonable.
MAX_H5_OBJECTS = 100_000


class UnsafeInputError(ValueError):
    """An input or run-folder file placeloc refuses to read or write; the message names it and the fix."""


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    return "not a regular file"


# ----------------------------------------------------------------- YAML

# Levels of nested mappings and lists a config may hold: a config holds a handful; the
# parser recurses once per level, so thousands of ``[`` would exhaust Python's stack.
MAX_YAML_DEPTH = 64


class DuplicateKeyError(yaml.YAMLError):
    """A key given twice in one YAML mapping (the message names both lines)."""


class _BoundedLoader(yaml.SafeLoader):
    """SafeLoader that refuses aliases (a tiny file could expand without bound: the
    "billion laughs"), nesting deeper than :data:`MAX_YAML_DEPTH` and a key given twice in
    one mapping (YAML forbids it, but PyYAML keeps the last in silence: a second
    ``seqslam:`` section would drop every setting of the first)."""

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue  # "<<" merges on purpose
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.setdefault(key, key_node)
                except TypeError:
                    continue  # an unhashable key: SafeLoader's own error names it
                if first is not key_node:
                    raise DuplicateKeyError(
                        f"line {key_node.start_mark.line + 1}: the key {key!r} is given twice (first on line "
                        f"{first.start_mark.line + 1}); YAML keeps only the last, so the first one's settings would "
                        "be lost: merge them into one")
        return super().construct_mapping(node, deep=deep)

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.composer.ComposerError(
                None, None, f"found alias *{event.anchor}: aliases are not allowed in placeloc's YAML "
                "(write the value out instead)", event.start_mark)
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise yaml.composer.ComposerError(
                    None, None, f"nested too deeply (more than {MAX_YAML_DEPTH} levels of [ or {{ or indented "
                    "keys); placeloc's YAML holds a few levels: close the brackets", self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def load_yaml(text: str, what: str = "YAML", max_bytes: int = MAX_YAML_BYTES) -> Any:
    """The one YAML parser of placeloc (run configs, ``--set`` and ``--grid`` values, sweep
    files, floor plans, the ``config_yaml`` stamped in artifacts): safe tags only, no
    aliases, at most :data:`MAX_YAML_DEPTH` levels and ``max_bytes`` bytes, checked before
    parsing. Raises ``yaml.YAMLError`` (with ``what`` for the size)."""
    if len(text) > max_bytes:
        raise yaml.YAMLError(f"{what} is {len(text.encode('utf-8', 'replace')) / 1e6:.1f} MB of YAML; the limit is "
                             f"{max_bytes / 1e6:.0f} MB (settings, not data: put data in files and name them)")
    try:
        return yaml.load(text, Loader=_BoundedLoader)  # noqa: S506 (a SafeLoader subclass)
    except (ValueError, TypeError, AttributeError, OverflowError) as exc:
        # a safe tag's constructor meeting a value it cannot build: an integer of thousands of
        # digits (Python's int limit), a malformed !!timestamp, ...
        raise yaml.YAMLError(f"{what}: a value cannot be read ({' '.join(str(exc).split())[:160]}); "
                             "write a plain number or string") from None
    except RecursionError:  # a deep flow collection inside one scalar token; the depth cap catches the rest
        raise yaml.YAMLError(f"{what}: nested too deeply (hundreds of levels of [ or {{); close the brackets") from None


# ----------------------------------------------------------------- memory

# MemAvailable read at most this often (seconds): every image read and decode asks for the
# budget, and reading /proc/meminfo twice an image was a fifth of SeqSLAM's extract of
# 7152 thumbnails (0.22 of 1.1 s CPU). A budget a second old is as good a guard.
MEM_AVAILABLE_TTL = 1.0
_mem_cache: list[float] = [float("-inf"), 0.0]  # [when read (monotonic), bytes]


def mem_available() -> int:
    """Bytes of memory available now (``/proc/meminfo`` MemAvailable, read at most once
    every :data:`MEM_AVAILABLE_TTL` seconds; unknown: no limit)."""
    now = time.monotonic()
    when, value = _mem_cache
    if now - when < MEM_AVAILABLE_TTL:
        return int(value)
    found = 1 << 62
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    found = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError):
        pass
    _mem_cache[:] = [now, float(found)]
    return found


# The largest size limit taken from the environment: 2**40 MB (an exbibyte), far beyond any
# machine; a larger figure is a typo (1e308), and turned into bytes it overflows.
ENV_MEGABYTES_MAX = 2**40


_PARSED_LIMITS: dict[str, float] = {}  # PLACELOC_MEMORY_LIMIT_MB's text -> its number (nan: none)


def memory_budget() -> int:
    """Bytes of memory a run, a decode or a read may take: ``PLACELOC_MEMORY_LIMIT_MB`` when
    it is a number of megabytes from 0 to :data:`ENV_MEGABYTES_MAX`, else MemAvailable.
    Never raises: :func:`placeloc.core.limits.memory_limit` refuses a bad value, naming the
    variable, before any stage runs (a worker decoding an image only needs the figure)."""
    raw = os.environ.get("PLACELOC_MEMORY_LIMIT_MB", "")
    value = _PARSED_LIMITS.get(raw)
    if value is None:  # parsed once per text: every image read and decode asks
        try:
            value = float(raw.strip() or "nan")
        except ValueError:
            value = float("nan")
        if len(_PARSED_LIMITS) < 64:
            _PARSED_LIMITS[raw] = value
    if math.isfinite(value) and 0 <= value <= ENV_MEGABYTES_MAX:
        return int(value * 2**20)
    return mem_available()


def separator_hint(header: Sequence[str]) -> str:
    """What to say of a CSV header that came out as one column holding another separator: a
    spreadsheet's export in a comma-decimal locale separates by ';', another by tabs. ``''``
    where the header is not such."""
    cells = [str(c) for c in header]
    if len(cells) != 1:
        return ""
    other = next((name for sep, name in ((";", "semicolons"), ("\t", "tabs"), ("|", "'|'")) if sep in cells[0]), None)
    return f" (this file separates its columns by {other}: save it comma-separated)" if other else ""


def load_json(text: str, what: str) -> Any:
    """``json.loads`` that words nesting deeper than Python's stack as one line (a
    ``ValueError``, like a syntax error) instead of a RecursionError."""
    import json

    try:
        return json.loads(text)
    except RecursionError:
        raise UnsafeInputError(f"{what}: nested too deeply (thousands of levels of [ or {{); close the brackets") from None


# ----------------------------------------------------------------- names from data

def name_inside(folder: str | Path, name: str, what: str) -> Path:
    """``folder / name`` for a ``name`` read from data, refused unless it is one plain path
    component (no separator, not ``.``/``..``, not absolute, no NUL) and the result,
    links resolved, lies strictly inside ``folder``."""
    text = _plain_name(name, what)
    base = Path(folder)
    path = base / text
    resolved_base = base.resolve()
    resolved = path.resolve()
    if resolved.parent != resolved_base and resolved_base not in resolved.parents:
        raise UnsafeInputError(f"{what} {text!r}: {path} leads outside {base} (a symbolic link there?); remove the "
                               "link or choose another output folder")
    return path


def _plain_name(name: str, what: str) -> str:
    text = str(name)
    bad = (not text or text in (".", "..") or "/" in text or "\\" in text or "\0" in text
           or os.path.isabs(text) or text.strip() != text)
    if bad:
        raise UnsafeInputError(f"{what} {text!r} cannot name a folder: it must be one plain name (no '/', '\\', "
                               "'..', or absolute path); rename it in the input file")
    return text


# ----------------------------------------------------------------- run-folder files

def open_run_file(run_dir: str | Path, name: str, flags: int, mode: int = 0o644, max_bytes: int | None = None) -> int:
    """A raw descriptor on ``run_dir/name`` (one component), opened without following a
    symbolic link (``O_NOFOLLOW``; a FIFO does not block the open), refused unless it is a
    regular file; with ``max_bytes``, refused when larger. The caller closes it."""
    path = Path(run_dir) / _plain_name(name, "run-folder file")
    nofollow = getattr(os, "O_NOFOLLOW", 0)
    try:
        fd = os.open(path, flags | nofollow | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0), mode)
    except OSError as exc:
        try:
            st = os.lstat(path)
        except OSError:
            raise exc from None
        if stat.S_ISLNK(st.st_mode):
            raise UnsafeInputError(f"{path} is a symbolic link; placeloc does not read or write through links in "
                                   f"a run folder: remove it (rm {path}) and re-run") from None
        if not stat.S_ISREG(st.st_mode):  # a FIFO without a reader (ENXIO), a device, ...
            raise UnsafeInputError(f"{path} is {_kind(st.st_mode)}, not a file placeloc wrote; remove it and "
                                   "re-run") from None
        raise
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise UnsafeInputError(f"{path} is {_kind(st.st_mode)}, not a file placeloc wrote; remove it and re-run")
        if max_bytes is not None and st.st_size > max_bytes:
            raise UnsafeInputError(f"{path} is {st.st_size / 2**20:.0f} MB, more than the {max_bytes / 2**20:.0f} MB "
                                   "placeloc reads from such a file; remove it and re-run")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def read_run_file(run_dir: str | Path, name: str, max_bytes: int) -> bytes:
    """The bytes of a regular, non-link file of the run folder, at most ``max_bytes``."""
    fd = open_run_file(run_dir, name, os.O_RDONLY, max_bytes=max_bytes)
    with os.fdopen(fd, "rb") as fh:
        data = fh.read(max_bytes + 1)
    if len(data) > max_bytes:  # grew while being read
        raise UnsafeInputError(f"{Path(run_dir) / name} grew past {max_bytes / 2**20:.0f} MB while being read; "
                               "remove it and re-run")
    return data


# A run folder's tables (per_query.csv: one short row per query) stay far below this.
MAX_RUN_TABLE_BYTES = 1 << 30


def read_run_table(run_dir: str | Path, name: str) -> io.StringIO:
    """A CSV of the run folder (``per_query.csv``, ...) through :func:`read_run_file`,
    ready for ``csv.reader``/``csv.DictReader``."""
    data = read_run_file(run_dir, name, MAX_RUN_TABLE_BYTES)
    return io.StringIO(data.decode("utf-8", "replace"), newline="")


# ----------------------------------------------------------------- input files

def input_file(path: str | Path, what: str, max_bytes: int | None = None) -> os.stat_result:
    """Check that ``path`` (links followed) is a regular file no larger than ``max_bytes``
    before it is opened for reading: a device (``/dev/zero``), a FIFO or a folder is refused."""
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise UnsafeInputError(f"{what}: {p} does not exist; fix the path") from None
    if not stat.S_ISREG(st.st_mode):
        raise UnsafeInputError(f"{what}: {p} is {_kind(st.st_mode)}, not a regular file; give the path of a file")
    if max_bytes is not None and st.st_size > max_bytes:
        raise UnsafeInputError(f"{what}: {p} is {st.st_size / 2**20:.0f} MB, more than the {max_bytes / 2**20:.0f} MB "
                               "placeloc reads from such a file; give a smaller file")
    return st


def read_input_bytes(path: str | Path, what: str, max_bytes: int = MAX_TEXT_BYTES) -> bytes:
    """The bytes of a regular input file of at most ``max_bytes`` (checked on the open
    descriptor too, so a file swapped for a FIFO after the check cannot block the read)."""
    input_file(path, what, max_bytes)
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise UnsafeInputError(f"{what}: {path} is {_kind(st.st_mode)}, not a regular file; give the path of a file")
        os.set_blocking(fd, True)
        data = fh.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise UnsafeInputError(f"{what}: {path} is larger than the {max_bytes / 2**20:.0f} MB placeloc reads from "
                               "such a file; give a smaller file")
    return data


def read_input_text(path: str | Path, what: str, max_bytes: int = MAX_TEXT_BYTES, encoding: str = "utf-8-sig") -> str:
    """A regular input file of at most ``max_bytes`` as text (not UTF-8: one line naming the byte)."""
    data = read_input_bytes(path, what, max_bytes)
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as exc:
        raise UnsafeInputError(f"{what}: {path} is not UTF-8 text (byte 0x{data[exc.start]:02x} at offset "
                               f"{exc.start}); save it as UTF-8") from None


# ----------------------------------------------------------------- HDF5

def foreign_storage(f: Any) -> list[str]:
    """Where an open HDF5 file takes data from another file: external links, virtual
    datasets and datasets with external raw storage (empty when there is none)."""
    import h5py

    found: list[str] = []
    seen: set[Any] = set()
    count = 0

    def walk(group: Any, prefix: str) -> None:
        nonlocal count
        for key in group:
            count += 1
            if count > MAX_H5_OBJECTS:
                raise UnsafeInputError(f"{f.filename}: more than {MAX_H5_OBJECTS:,} objects; not an input placeloc reads")
            name = f"{prefix}/{key}"
            link = group.get(key, getlink=True)
            if isinstance(link, h5py.ExternalLink):
                found.append(f"{name} is an external link to {link.filename}:{link.path}")
                continue
            if isinstance(link, h5py.SoftLink):
                continue  # names an object of this file, which the walk meets under its own name
            obj = group.get(key)
            if isinstance(obj, h5py.Dataset):
                if obj.is_virtual:
                    found.append(f"{name} is a virtual dataset (its data lies in other files)")
                elif obj.external:
                    found.append(f"{name} stores its data in the external file {obj.external[0][0]!r}")
            elif isinstance(obj, h5py.Group):
                token = obj.id.__hash__()
                if token in seen:
                    continue
                seen.add(token)
                walk(obj, name)

    walk(f, "")
    return found


@contextlib.contextmanager
def open_h5_input(path: str | Path, what: str) -> Iterator[Any]:
    """The one way an input HDF5 file is opened: a regular file, read-only, refused when any
    dataset takes its data from another file (what reads it could not fingerprint that
    file, and a link to a FIFO would hang the read)."""
    import h5py

    input_file(path, what)
    if not h5py.is_hdf5(str(path)):
        raise UnsafeInputError(f"{what}: {path} is not an HDF5 file; give an .h5 file")
    with h5py.File(path, "r") as f:
        foreign = foreign_storage(f)
        if foreign:
            raise UnsafeInputError(f"{what}: {path}: {foreign[0]}; placeloc reads only data stored in the file itself "
                                   "(copy the data in, e.g. with h5copy, or h5repack the file)")
        yield f


def check_array_bytes(shape: tuple[int, ...], dtype: np.dtype, path: str | Path, name: str, max_bytes: int) -> None:
    """Refuse an array whose header says it needs more than ``max_bytes`` (or holds objects)."""
    import numpy as np

    dtype = np.dtype(dtype)
    if dtype.hasobject:
        raise UnsafeInputError(f"{path}: {name!r} holds Python objects ({dtype}); store numbers")
    need = math.prod(int(s) for s in shape) * max(dtype.itemsize, 1)
    if need > max_bytes:
        raise UnsafeInputError(f"{path}: {name!r} is {' x '.join(map(str, shape))} {dtype} ({need / 2**20:,.0f} MB), "
                               f"more than the {max_bytes / 2**20:,.0f} MB this input may take; give the array of "
                               "these images")


def h5_dataset(ds: Any, max_bytes: int) -> np.ndarray:
    """Read an HDF5 dataset after its shape and type passed :func:`check_array_bytes`."""
    check_array_bytes(ds.shape or (), ds.dtype, ds.file.filename, ds.name.lstrip("/"), max_bytes)
    return ds[()]


def _npy_header(fh: Any) -> tuple[tuple[int, ...], np.dtype]:
    import numpy as np

    fmt = np.lib.format
    version = fmt.read_magic(fh)
    if version == (1, 0):
        shape, _, dtype = fmt.read_array_header_1_0(fh, max_header_size=10000)
    elif version == (2, 0):
        shape, _, dtype = fmt.read_array_header_2_0(fh, max_header_size=10000)
    else:  # 3.0 differs from 2.0 only in the header's text encoding (UTF-8), which numbers never need
        raise ValueError(f"npy format version {version[0]}.{version[1]} is not read; save with numpy.save")
    return tuple(shape), dtype


def load_arrays(path: str | Path, what: str, max_bytes: int, kind: str | None = None) -> dict[str, np.ndarray]:
    """Every array of a ``.npy`` (key ``"array"``), ``.npz``, ``.mat`` or ``.h5``/``.hdf5``
    file (``kind``, e.g. ``".h5"``, overrides the file's suffix), each checked from its
    header against ``max_bytes`` before it is read. MATLAB v7.3 files are HDF5 (arrays
    transposed back)."""
    import numpy as np

    p = Path(path)
    suffix = kind or p.suffix.lower()
    input_file(p, what)
    try:
        if suffix == ".npy":
            with p.open("rb") as fh:
                shape, dtype = _npy_header(fh)
                check_array_bytes(shape, dtype, p, "array", max_bytes)
                fh.seek(0)
                return {"array": np.load(fh, allow_pickle=False)}
        if suffix == ".npz":
            checked = []
            with zipfile.ZipFile(p) as zf:
                for info in zf.infolist():
                    if not info.filename.endswith(".npy"):
                        continue  # not an array: never decompressed (a zip bomb would expand here)
                    with zf.open(info) as member:
                        shape, dtype = _npy_header(member)
                    check_array_bytes(shape, dtype, p, info.filename[:-4], max_bytes)
                    checked.append(info.filename[:-4])
            with np.load(p, allow_pickle=False) as z:
                return {k: z[k] for k in checked}
        if suffix == ".mat":
            from scipy.io import loadmat, whosmat

            try:
                listed = whosmat(str(p))
            except NotImplementedError:  # v7.3: HDF5
                with open_h5_input(p, what) as f:
                    return {k: np.asarray(h5_dataset(f[k], max_bytes)).T for k in f if _is_dataset(f.get(k))}
            for name, shape, cls in listed:
                check_array_bytes(tuple(shape), np.dtype(_MAT_TYPES.get(cls, "float64")), p, name, max_bytes)
            return {k: v for k, v in loadmat(str(p)).items() if not k.startswith("__")}
        if suffix in (".h5", ".hdf5"):
            with open_h5_input(p, what) as f:
                return {k: h5_dataset(f[k], max_bytes) for k in f if _is_dataset(f.get(k))}
    except UnsafeInputError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, NotImplementedError) as exc:
        raise UnsafeInputError(f"{what}: {p} cannot be read as a {suffix} array file ({' '.join(str(exc).split())})") from None
    raise UnsafeInputError(f"{what}: {p} is not an array file; give .npy, .npz, .mat or .h5")


# MATLAB classes (scipy.io.whosmat) -> the type loadmat gives; others (double, sparse, cell,
# struct) are counted at 8 bytes per element.
_MAT_TYPES = {"single": "float32", "int8": "int8", "uint8": "uint8", "logical": "uint8", "int16": "int16",
              "uint16": "uint16", "char": "uint16", "int32": "int32", "uint32": "uint32"}


def _is_dataset(obj: Any) -> bool:
    import h5py

    return isinstance(obj, h5py.Dataset)
