"""The one guard of every cache placeloc loads code from (docs/reliability.md, "Caches").

Compiled code is loaded only from a folder no one but this user can write:
``$XDG_CACHE_HOME/placeloc/<name>`` created 0700 whatever the umask, and refused (with one
warning; the code is compiled afresh) when it is a link, not the user's, or writable by
group or others. Imports nothing heavy: ``import placeloc`` calls
:func:`private_numba_cache` before any module imports numba.
"""

from __future__ import annotations

import contextlib
import os
import stat
from pathlib import Path


def cache_root() -> Path:
    """``$XDG_CACHE_HOME/placeloc`` (default ``~/.cache/placeloc``)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "placeloc"


def is_private(st: os.stat_result) -> bool:
    """Owned by this user and writable by no one else."""
    return st.st_uid == os.geteuid() and not st.st_mode & 0o022


_WARNED: set[str] = set()


def private_cache_dir(name: str) -> Path | None:
    """``cache_root()/name``, the one guard of every cache placeloc loads code from: each of
    ``placeloc/`` and ``name/`` is created mode 0700 whatever the umask, and the folder is
    returned only when both are real folders (not links) owned by this user and writable by
    no one else; otherwise None, with one warning naming the folder and the fix."""
    import logging

    folder = cache_root() / name
    with contextlib.suppress(OSError):
        os.makedirs(folder.parent.parent, 0o700, exist_ok=True)  # $XDG_CACHE_HOME itself (~/.cache)
    for level in (folder.parent, folder):
        try:
            os.mkdir(level, 0o700)
            os.chmod(level, 0o700)  # mkdir's mode is masked by the umask; the cache is private
        except FileExistsError:
            pass
        except OSError:  # a read-only home, no such parent: no cache, nothing to say
            return None
        try:
            st = os.lstat(level)
        except OSError:
            return None
        if stat.S_ISLNK(st.st_mode) or not stat.S_ISDIR(st.st_mode) or not is_private(st):
            if str(level) not in _WARNED:
                _WARNED.add(str(level))
                logging.getLogger("placeloc").warning(
                    "cache %s not used: it is a link, not a folder, not yours or writable by others (chmod 700 %s, "
                    "or remove it); compiled code is made afresh in memory instead", level, level)
            return None
    return folder


def private_numba_cache() -> None:
    """Point numba's cache (``cache=True`` kernels: machine code and pickled indexes, which
    numba loads without any check) at a private folder before numba is imported, instead
    of ``__pycache__`` beside the sources or a shared user-wide folder. A
    ``NUMBA_CACHE_DIR`` the user set is kept. Without a private folder: a fresh private
    temporary one (compiled afresh, nothing foreign loaded)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    folder = private_cache_dir("numba")
    if folder is None:
        import atexit
        import shutil
        import tempfile

        folder = Path(tempfile.mkdtemp(prefix="placeloc-numba-"))
        atexit.register(shutil.rmtree, folder, True)  # this process made it; its children are gone by exit
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
