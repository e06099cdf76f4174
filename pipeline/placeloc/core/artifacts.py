"""HDF5 artifacts: atomic writes, provenance stamps and the "is it up to date?" test.

Every stage writes exactly one file ``<run_dir>/<stage>.h5``. It is first written under a
temporary name in the same folder and renamed into place only after the stage finished,
so a crash or Ctrl-C never leaves a file a later run would trust. The root attributes
carry the provenance:

- ``placeloc_version``, ``stage``, ``method``, ``created``
- ``config_yaml`` (the full resolved config) and ``config_hash``
- ``inputs`` (JSON: fingerprints of image lists, ground-truth files and parent stamps)
- ``stamp``: SHA-256 over version, stage, the config keys the stage depends on and its
  inputs. A stage is up to date when the file exists and its stamp equals the stamp the
  runner computes now. Children record their parent's stamp, so a change cascades.
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import os
import shutil
import time
import uuid
from pathlib import Path
from typing import Any, Callable, Iterator

import h5py
import numpy as np

TMP_MARK = ".tmp-"


class DiskFullError(OSError):
    """Writing failed because the file system is full; the message names it and the file."""

    def __str__(self) -> str:  # the message alone, without OSError's "[Errno 28]" prefix
        return str(self.strerror)


def tmp_path_for(path: Path) -> Path:
    return path.with_name(f".{path.name}{TMP_MARK}{os.getpid()}")


def create_tmp(path: Path) -> int:
    """Create the temporary file ``path`` afresh and return its descriptor: whatever is at
    that (predictable) name is removed first, and the file is created exclusively without
    following a link, so a link planted there cannot send the write elsewhere."""
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)
    return os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0),
                   0o666)


def is_disk_full(exc: BaseException | None, depth: int = 0) -> bool:
    """True for ENOSPC/EDQUOT, also when HDF5 reports it only in its message text or the
    error was wrapped by another exception."""
    if exc is None or depth > 5:
        return False
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    text = str(exc)
    if "No space left on device" in text or "errno = 28" in text or "Disk quota exceeded" in text:
        return True
    return is_disk_full(exc.__cause__ or exc.__context__, depth + 1)


def mount_point(path: Path) -> str:
    """The mount point (and file system type) holding ``path``, for messages."""
    p = Path(os.path.abspath(path))
    while not p.exists() and p != p.parent:
        p = p.parent
    while not os.path.ismount(p) and p != p.parent:
        p = p.parent
    kind = ""
    with contextlib.suppress(OSError):
        for line in Path("/proc/mounts").read_text().splitlines():
            parts = line.split()
            if len(parts) > 2 and parts[1] == str(p):
                kind = f" ({parts[2]})"
    return f"{p}{kind}"


def disk_full_error(path: Path, written: int) -> DiskFullError:
    """The one-line error for a full disk; ``written`` is what the write had reached (the
    need is at least that), 0 when unknown."""
    need = f"needs about {max(written, 1 << 20) / 2**20:.0f} MB" if written > 0 else "needs more than is free"
    return DiskFullError(errno.ENOSPC, f"no space left on {mount_point(path)} while writing {path} "
                         f"({need}); free space there or choose another --run-dir")


class _GuardedFile(io.RawIOBase):
    """The file HDF5 writes an artifact through (h5py's file-object driver).

    HDF5 defers many writes (chunk caches, metadata) to the moment an object is released;
    when such a write meets a full disk, the error cannot propagate, HDF5 is left
    inconsistent and the interpreter may crash at exit (segfault). Here a write that meets
    ENOSPC/EDQUOT never fails: from then on, written pages are kept in memory (reads see
    them), ``full`` holds the error, and the writer stops at its next check
    (:func:`raise_if_disk_full`, called by ``ctx.progress``) or when the block ends. HDF5 so
    always sees a consistent file, and the temporary file is deleted.
    """

    PAGE = 1 << 16

    def __init__(self, path: Path) -> None:
        super().__init__()
        self.path = path
        self._fh = open(create_tmp(path), "w+b", buffering=0)  # noqa: SIM115 (closed in close())
        self._pos = 0
        self._pages: dict[int, bytearray] = {}
        self.full: OSError | None = None

    # -- io.RawIOBase protocol used by h5py
    def readable(self) -> bool:
        return True

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = 0) -> int:
        if whence == 0:
            self._pos = offset
        elif whence == 1:
            self._pos += offset
        else:
            self._pos = self._size() + offset
        return self._pos

    def tell(self) -> int:
        return self._pos

    def _size(self) -> int:
        disk = os.fstat(self._fh.fileno()).st_size
        mem = (max(self._pages) + 1) * self.PAGE if self._pages else 0
        return max(disk, mem, getattr(self, "_logical", 0))

    def _disk_read(self, offset: int, n: int) -> bytes:
        return os.pread(self._fh.fileno(), n, offset)

    def readinto(self, buf: Any) -> int:
        view = memoryview(buf).cast("B")
        n = len(view)
        if not self._pages:
            data = self._disk_read(self._pos, n)
        else:
            out = bytearray(self._disk_read(self._pos, n).ljust(n, b"\0"))
            for page, content in self._pages.items():
                lo, hi = page * self.PAGE, (page + 1) * self.PAGE
                a, b = max(lo, self._pos), min(hi, self._pos + n)
                if a < b:
                    out[a - self._pos:b - self._pos] = content[a - lo:b - lo]
            data = bytes(out[: max(0, min(n, self._size() - self._pos))])
        view[: len(data)] = data
        self._pos += len(data)
        return len(data)

    def write(self, data: Any) -> int:
        mv = memoryview(data).cast("B")
        n, done = len(mv), 0
        while done < n and self.full is None:
            try:
                done += os.pwrite(self._fh.fileno(), mv[done:], self._pos + done)
            except OSError as exc:
                if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
                    raise
                self.full = exc
        if done < n:
            self._to_memory(self._pos + done, mv[done:])
        self._pos += n
        self._logical = max(getattr(self, "_logical", 0), self._pos)
        return n

    def _to_memory(self, offset: int, mv: memoryview) -> None:
        i = 0
        while i < len(mv):
            page, within = divmod(offset + i, self.PAGE)
            if page not in self._pages:
                self._pages[page] = bytearray(self._disk_read(page * self.PAGE, self.PAGE).ljust(self.PAGE, b"\0"))
            take = min(self.PAGE - within, len(mv) - i)
            self._pages[page][within:within + take] = mv[i:i + take]
            i += take

    def truncate(self, size: int | None = None) -> int:
        size = self._pos if size is None else size
        if self.full is None:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fh.fileno(), size)
        self._logical = size
        return size

    def flush(self) -> None:
        pass

    def close(self) -> None:
        if not self.closed:
            self._fh.close()
            self._pages.clear()
        super().close()


_GUARDS: dict[int, _GuardedFile] = {}


def raise_if_disk_full(f: h5py.File) -> None:
    """Stop a writer whose artifact met a full disk (a cheap check; call it per chunk)."""
    guard = _GUARDS.get(id(f))
    if guard is not None and guard.full is not None:
        raise guard.full


@contextlib.contextmanager
def atomic_h5(path: str | Path, attrs: dict[str, Any] | None = None,
              before_rename: Callable[[], None] | None = None) -> Iterator[h5py.File]:
    """Open a temporary HDF5 file for writing; rename it to ``path`` only on success.

    ``attrs`` are written last, just before the rename, so a file that has a ``stamp``
    attribute is always complete. A unique ``write_id`` attribute is added, so a child
    stage can tell that its parent was rewritten even when the parent's stamp is the same.
    A full disk raises :class:`DiskFullError` and leaves no temporary file behind.
    ``before_rename`` runs once the file is complete on disk, just before the rename (the
    runner moves the stage's side outputs into place there); if it raises, no file appears.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_path_for(path)
    guard: _GuardedFile | None = None
    f = None
    try:
        guard = _GuardedFile(tmp)
        f = h5py.File(guard, "w")
        _GUARDS[id(f)] = guard
        yield f
        for key, value in (attrs or {}).items():
            f.attrs[key] = value
        f.attrs["write_id"] = uuid.uuid4().hex
        f.flush()
        _GUARDS.pop(id(f), None)
        f.close()
        if guard.full is not None:
            raise guard.full
        guard.close()
        if before_rename is not None:
            before_rename()
        os.replace(tmp, path)
    except BaseException as exc:
        written = tmp.stat().st_size if tmp.exists() else 0
        if f is not None:
            _GUARDS.pop(id(f), None)
            with contextlib.suppress(Exception):
                f.close()
        if guard is not None:
            guard.close()
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        if isinstance(exc, DiskFullError) and (guard is None or guard.full is None):
            raise  # a side output met the full disk: its message already names that file
        full = (guard is not None and guard.full is not None) or (isinstance(exc, Exception) and is_disk_full(exc))
        if full:
            pending = sum(len(p) for p in guard._pages.values()) if guard is not None else 0
            raise disk_full_error(path, written + pending) from None
        raise


@contextlib.contextmanager
def atomic_open(path: str | Path, newline: str | None = None, mode: str = "w") -> Iterator[Any]:
    """Open a text file for writing under a temporary name in the same folder; rename it to
    ``path`` only when the block finishes, so readers never see half a CSV or JSON file."""
    path = Path(path)
    tmp = tmp_path_for(path)
    try:
        encoding = None if "b" in mode else "utf-8"
        with open(create_tmp(tmp), mode, newline=newline, encoding=encoding) as fh:
            yield fh
        os.replace(tmp, path)
    except BaseException as exc:
        written = tmp.stat().st_size if tmp.exists() else 0
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        if isinstance(exc, Exception) and is_disk_full(exc):
            raise disk_full_error(path, written) from None
        raise


def stamp_token(stamp: str, write_id: Any) -> str:
    """What a child stage records of a parent artifact (its ``inputs``): the parent's stamp
    and the id of the write that produced it, so rewriting the parent (even with the same
    stamp) re-runs the child. The runner records it, the report's chain of stamps checks it."""
    return stamp if write_id is None else f"{stamp}:{write_id}"


def read_write_id(path: Path) -> str | None:
    """The unique id of the write that produced the artifact at ``path`` (None if absent)."""
    try:
        with h5py.File(path, "r") as f:
            value = f.attrs.get("write_id")
    except OSError:
        return None
    return str(value) if value is not None else None


def remove_stale_tmp(run_dir: Path) -> list[Path]:
    """Delete temporary files (artifacts and text side outputs) left by a killed process
    (never trusted, only clutter); those of a process still running are kept."""
    removed = []
    for p in run_dir.rglob(f".*{TMP_MARK}*"):
        pid = p.name.rsplit(TMP_MARK, 1)[-1]
        if pid.isdigit() and pid_alive(int(pid)) and int(pid) != os.getpid():
            continue
        if p.is_dir() and not p.is_symlink():  # a stage's staged side outputs
            shutil.rmtree(p, ignore_errors=True)
            removed.append(p)
            continue
        with contextlib.suppress(FileNotFoundError):
            p.unlink()
            removed.append(p)
    return removed


def pid_alive(pid: int) -> bool:
    """True when process ``pid`` exists (one owned by another user counts as alive)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def provenance_attrs(stage: str, method: str, version: str, config_yaml: str, config_hash: str,
                     inputs: dict[str, Any], stamp: str, **extra: Any) -> dict[str, Any]:
    attrs = {
        "placeloc_version": version,
        "stage": stage,
        "method": method,
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "config_yaml": config_yaml,
        "config_hash": config_hash,
        "inputs": json.dumps(inputs, sort_keys=True),
        "stamp": stamp,
    }
    attrs.update(extra)
    return attrs


def read_stamp(path: Path) -> str | None:
    """The stamp of a complete artifact, or None if it is missing or unreadable, or is not
    what placeloc writes: a symbolic link (placeloc renames its artifacts into place, so a
    link was put there by someone else), or a file with data stored in other files. Such an
    artifact is never up to date: its stage re-runs and replaces it."""
    return stamp_and_reason(path)[0]


def unusable_reason(path: Path) -> str | None:
    """Why an artifact that is there has no stamp :func:`read_stamp` accepts, in a few words
    (None where it is missing or usable)."""
    return stamp_and_reason(path)[1]


def stamp_and_reason(path: Path) -> tuple[str | None, str | None]:
    """(the stamp of a usable artifact, None) or (None, why it cannot be used, in a few
    words; None where it is missing): one look at the file for both, so that the runner
    says why a stage that was there runs again (an hour of extract, say) without opening
    the file twice. The rules are :func:`read_stamp`'s."""
    from placeloc.core.safe_io import UnsafeInputError, foreign_storage

    if path.is_symlink():
        return None, "a symbolic link, which placeloc never writes"
    if not path.exists():
        return None, None
    if not path.is_file():
        return None, "not a regular file"
    try:
        with h5py.File(path, "r") as f:
            if foreign_storage(f):
                return None, "its data are stored in other files"
            stamp = f.attrs.get("stamp")
    except UnsafeInputError as exc:
        return None, str(exc)
    except OSError as exc:
        return None, _unreadable_h5(exc)
    return (str(stamp), None) if stamp is not None else (None, "it has no placeloc stamp")


def _unreadable_h5(exc: OSError) -> str:
    """h5py's OSError on opening a file, in words: a truncated file with its byte counts."""
    import re

    text = " ".join(str(exc).split())
    if "truncated file" in text:  # h5py: "... eof = 3000, sblock->base_addr = 0, stored_eof = 1679552"
        eof, stored = re.search(r"\beof = (\d+)", text), re.search(r"stored_eof = (\d+)", text)
        if eof and stored:
            return (f"truncated, {int(eof.group(1)):,} of its {int(stored.group(1)):,} bytes (a copy that did not "
                    "finish, or a full disk)")
        return "truncated (a copy that did not finish, or a full disk)"
    # h5py: "Unable to synchronously open file (file signature not found)": the part in brackets
    inner = re.search(r"\(([^()]*)\)\s*$", text)
    return f"not a readable HDF5 file: {(inner.group(1) if inner else text)[:160]}"


def write_tree(group: h5py.Group, data: dict[str, Any], compress_over: int = 1 << 16) -> None:
    """Store a nested dict of arrays/scalars/strings; big arrays are chunked + compressed."""
    for key, value in data.items():
        if isinstance(value, dict):
            write_tree(group.require_group(key), value, compress_over)
        elif isinstance(value, str):
            group.attrs[key] = value
        elif isinstance(value, (list, tuple)) and value and isinstance(value[0], str):
            group.create_dataset(key, data=np.array(value, dtype=h5py.string_dtype()))
        else:
            arr = np.asarray(value)
            if arr.dtype.kind == "U":
                group.create_dataset(key, data=arr.astype(h5py.string_dtype()))
            elif arr.size >= compress_over:
                group.create_dataset(key, data=arr, chunks=True, compression="gzip", compression_opts=1)
            else:
                group.create_dataset(key, data=arr)


def read_mapped(ds: h5py.Dataset) -> np.ndarray:
    """A large dataset for reading, without copying it into memory where HDF5 stores it as
    one plain block (contiguous, no filter): a read-only memory map of those bytes, so the
    operating system's page cache serves it in place. Else (chunked, compressed, or a type
    whose bytes are not NumPy's) it is read as ``ds[()]``.

    Why: UMap's chamfer index is about 0.75-1 GB at 2,000 positions, and copying it out of
    the page cache cost localize 0.7-2.0 s (measured on a generated home of 1,494
    positions, 2026-11-26), more than a tenth of a second a panorama for a home's 20. The
    map shares the cached pages; the kernel reading it faults them in as it goes.

    The map stays valid after the HDF5 file is closed, and after the file is replaced by
    a new artifact (a rename keeps the old bytes until the map is gone). Artifacts are never
    rewritten in place (:func:`atomic_h5`)."""
    offset = ds.id.get_offset() if ds.chunks is None and not ds.compression and ds.size else None
    dtype = ds.dtype
    if offset is None or dtype.hasobject or dtype.fields is not None or dtype.subdtype is not None:
        return ds[()]
    try:
        mapped = np.memmap(ds.file.filename, dtype=dtype, mode="r", offset=offset, shape=ds.shape)
    except (OSError, ValueError):  # a file system that cannot map files (some FUSE mounts): read it
        return ds[()]
    # the bytes are what HDF5 would give (byte order, padding): a few values at both ends checked
    n = ds.shape[-1]
    first = (0,) * (ds.ndim - 1) + (slice(0, min(n, 64)),)
    last = tuple(k - 1 for k in ds.shape[:-1]) + (slice(max(0, n - 64), n),)
    if not (np.array_equal(mapped[first], ds[first]) and np.array_equal(mapped[last], ds[last])):
        del mapped
        return ds[()]
    return np.asarray(mapped)  # a plain array (numba wants one) over the same pages, which it keeps alive


def read_strings(ds: h5py.Dataset) -> list[str]:
    return [s.decode() if isinstance(s, bytes) else str(s) for s in ds[()]]


def describe(path: str | Path) -> str:
    """Human-readable account of an artifact: provenance, then every group and dataset."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path} is a folder, not an artifact: give one of its .h5 files, e.g. {path / 'extract.h5'}")
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist")
    from placeloc.core.safe_io import foreign_storage, input_file

    input_file(path, "placeloc inspect")  # a FIFO or device is refused, not opened (is_hdf5 would wait on a FIFO)
    if not h5py.is_hdf5(path):
        raise ValueError(f"{path} is not an HDF5 file (not a placeloc artifact); give a RUN_DIR/<stage>.h5 file")
    lines: list[str] = []
    with h5py.File(path, "r") as f:
        a = dict(f.attrs)
        lines.append(f"{path}")
        if "stamp" not in a:
            lines.append("  (no provenance: not written by placeloc, or incomplete)")
        for key in ("stage", "method", "placeloc_version", "placeloc_code", "created", "stamp", "config_hash", "write_id"):
            if key in a:
                lines.append(f"  {key}: {a[key]}")
        if "note" in a:
            lines.append(f"  note: {a['note']}")
        if "inputs" in a:
            lines.append("  inputs:")
            for k, v in json.loads(a["inputs"]).items():
                lines.append(f"    {k}: {v}")
        lines.append("  contents:")

        def visit(name: str, obj: Any) -> None:
            depth = name.count("/") + 2
            pad = "  " * depth
            if isinstance(obj, h5py.Dataset):
                chunks = f" chunks={obj.chunks}" if obj.chunks else ""
                lines.append(f"{pad}{name.split('/')[-1]}: {obj.dtype} {obj.shape}{chunks}")
            else:
                lines.append(f"{pad}{name.split('/')[-1]}/")
            for k, v in obj.attrs.items():
                lines.append(f"{pad}  @{k} = {_short(v)}")

        f.visititems(visit)
        foreign = foreign_storage(f)
        if foreign:
            lines.append("  data stored outside this file (placeloc refuses such a file as input):")
            lines.extend(f"    {line}" for line in foreign)
        if "config_yaml" in a:
            lines.append("  config:")
            lines.extend("    " + ln for ln in str(a["config_yaml"]).splitlines())
    return "\n".join(lines)


def _short(v: Any) -> str:
    s = str(v)
    return s if len(s) <= 100 else s[:97] + "..."
