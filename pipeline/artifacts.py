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
import json
import os
import time
from pathlib import Path
from typing import Any, Iterator

import h5py
import numpy as np

TMP_MARK = ".tmp-"


def tmp_path_for(path: Path) -> Path:
    return path.with_name(f".{path.name}{TMP_MARK}{os.getpid()}")


@contextlib.contextmanager
def atomic_h5(path: str | Path, attrs: dict[str, Any] | None = None) -> Iterator[h5py.File]:
    """Open a temporary HDF5 file for writing; rename it to ``path`` only on success.

    ``attrs`` are written last, just before the rename, so a file that has a ``stamp``
    attribute is always complete.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_path_for(path)
    f = h5py.File(tmp, "w")
    try:
        yield f
        for key, value in (attrs or {}).items():
            f.attrs[key] = value
        f.flush()
        f.close()
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(Exception):
            f.close()
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


@contextlib.contextmanager
def atomic_open(path: str | Path, newline: str | None = None) -> Iterator[Any]:
    """Open a text file for writing under a temporary name in the same folder; rename it to
    ``path`` only when the block finishes, so readers never see half a CSV or JSON file."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}{TMP_MARK}{os.getpid()}")
    try:
        with tmp.open("w", newline=newline) as fh:
            yield fh
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


def remove_stale_tmp(run_dir: Path) -> list[Path]:
    """Delete temporary files left by a killed process (never trusted, only clutter)."""
    removed = []
    for p in run_dir.glob(f".*.h5{TMP_MARK}*"):
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
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist")
    lines: list[str] = []
    with h5py.File(path, "r") as f:
        a = dict(f.attrs)
        lines.append(f"{path}")
        if "stamp" not in a:
            lines.append("  (no provenance: not written by placeloc, or incomplete)")
        for key in ("stage", "method", "placeloc_version", "created", "stamp", "config_hash"):
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
