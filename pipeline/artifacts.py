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
import json
import os
import time
import uuid
from pathlib import Path
from typing import Any, Iterator

import h5py
import numpy as np

TMP_MARK = ".tmp-"


class DiskFullError(OSError):
    """Writing failed because the file system is full; the message names it and the file."""


def tmp_path_for(path: Path) -> Path:
    return path.with_name(f".{path.name}{TMP_MARK}{os.getpid()}")


def is_disk_full(exc: BaseException) -> bool:
    """True for ENOSPC/EDQUOT, also when HDF5 reports it only in its message text."""
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    text = str(exc)
    return "No space left on device" in text or "errno = 28" in text or "Disk quota exceeded" in text


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


def disk_full_error(path: Path, written: int, exc: BaseException | None = None) -> DiskFullError:
    need = max(written, 1 << 20)
    err = DiskFullError(errno.ENOSPC, f"no space left on {mount_point(path)} while writing {path} "
                        f"(needs about {need / 2**20:.0f} MB); free space there or choose another --run-dir")
    return err


@contextlib.contextmanager
def atomic_h5(path: str | Path, attrs: dict[str, Any] | None = None) -> Iterator[h5py.File]:
    """Open a temporary HDF5 file for writing; rename it to ``path`` only on success.

    ``attrs`` are written last, just before the rename, so a file that has a ``stamp``
    attribute is always complete. A unique ``write_id`` attribute is added, so a child
    stage can tell that its parent was rewritten even when the parent's stamp is the same.
    A full disk raises :class:`DiskFullError` and leaves no temporary file behind.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_path_for(path)
    f = None
    try:
        f = h5py.File(tmp, "w")
        yield f
        for key, value in (attrs or {}).items():
            f.attrs[key] = value
        f.attrs["write_id"] = uuid.uuid4().hex
        f.flush()
        f.close()
        os.replace(tmp, path)
    except BaseException as exc:
        written = tmp.stat().st_size if tmp.exists() else 0
        if f is not None:
            with contextlib.suppress(Exception):
                f.close()
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        if isinstance(exc, Exception) and is_disk_full(exc):
            raise disk_full_error(path, written, exc) from exc
        raise


@contextlib.contextmanager
def atomic_open(path: str | Path, newline: str | None = None, mode: str = "w") -> Iterator[Any]:
    """Open a text file for writing under a temporary name in the same folder; rename it to
    ``path`` only when the block finishes, so readers never see half a CSV or JSON file."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}{TMP_MARK}{os.getpid()}")
    try:
        with tmp.open(mode, newline=newline) as fh:
            yield fh
        os.replace(tmp, path)
    except BaseException as exc:
        written = tmp.stat().st_size if tmp.exists() else 0
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        if isinstance(exc, Exception) and is_disk_full(exc):
            raise disk_full_error(path, written, exc) from exc
        raise


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
        if pid.isdigit() and _pid_alive(int(pid)) and int(pid) != os.getpid():
            continue
        with contextlib.suppress(FileNotFoundError):
            p.unlink()
            removed.append(p)
    return removed


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except OSError:
        return False
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
    """The stamp of a complete artifact, or None if it is missing or unreadable."""
    if not path.is_file():
        return None
    try:
        with h5py.File(path, "r") as f:
            stamp = f.attrs.get("stamp")
    except OSError:
        return None
    return str(stamp) if stamp is not None else None


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


def read_strings(ds: h5py.Dataset) -> list[str]:
    return [s.decode() if isinstance(s, bytes) else str(s) for s in ds[()]]


def describe(path: str | Path) -> str:
    """Human-readable account of an artifact: provenance, then every group and dataset."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path} is a folder, not an artifact: give one of its .h5 files, e.g. {path / 'extract.h5'}")
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist")
    if not h5py.is_hdf5(path):
        raise ValueError(f"{path} is not an HDF5 file (not a placeloc artifact); give a RUN_DIR/<stage>.h5 file")
    lines: list[str] = []
    with h5py.File(path, "r") as f:
        a = dict(f.attrs)
        lines.append(f"{path}")
        if "stamp" not in a:
            lines.append("  (no provenance: not written by placeloc, or incomplete)")
        for key in ("stage", "method", "placeloc_version", "created", "stamp", "config_hash", "write_id"):
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
        if "config_yaml" in a:
            lines.append("  config:")
            lines.extend("    " + ln for ln in str(a["config_yaml"]).splitlines())
    return "\n".join(lines)


def _short(v: Any) -> str:
    s = str(v)
    return s if len(s) <= 100 else s[:97] + "..."
