"""Where the shared real data sets are (``nordland-dev/``, ``corridor/``, ``tears-of-steel/``).

They are never part of a checkout. A preset names them as ``shared:nordland-dev/summer``
(any path parameter), resolved here: ``$PLACELOC_SHARED_DATA`` when set, else
``../shared/data`` beside the checkout, else ``../shared/data`` beside the working folder.
So a preset runs from any clone, placed anywhere, once the variable is set.
"""

from __future__ import annotations

import os
from pathlib import Path

from placeloc.core.errors import ConfigError

# The prefix of a path that lives in the shared data folder.
SHARED_PREFIX = "shared:"


def shared_data_dir() -> Path | None:
    """``$PLACELOC_SHARED_DATA`` when set, else ``../shared/data`` beside the checkout or the
    working folder (the first that is a folder), else None. A variable that is set but names
    no folder is an error naming it: falling back in silence would run on other data (or
    skip it) while the user believes their folder is used."""
    env = os.environ.get("PLACELOC_SHARED_DATA")
    if env is not None and env.strip():
        given = Path(env).expanduser()
        if not given.is_dir():
            what = "is a file, not a folder" if given.exists() else "does not exist"
            raise ConfigError(f"PLACELOC_SHARED_DATA={env!r} {what}; point it at the shared data folder (the one "
                              "holding corridor/, nordland-dev/, tears-of-steel/) or unset it (unset PLACELOC_SHARED_DATA)")
        return given
    here = Path(__file__).resolve().parents[3]  # the checkout: pipeline/placeloc/core/ -> ./
    for c in (here.parent / "shared" / "data", Path.cwd().parent / "shared" / "data"):
        if c.is_dir():
            return c
    return None


def resolve_shared(value: str, key: str) -> Path:
    """``shared:REL`` -> the shared data folder / REL; a ConfigError naming ``key`` and the
    fix when there is no shared data folder or it lacks REL."""
    rel = value[len(SHARED_PREFIX):].lstrip("/")
    try:
        root = shared_data_dir()
    except ConfigError as exc:  # the variable names no folder: say which key needed it
        raise ConfigError(f"{key}: {value} names the shared data folder, but {exc}") from None
    if root is None:
        where = "PLACELOC_SHARED_DATA is not set and no ../shared/data lies beside the checkout or the working folder"
        raise ConfigError(f"{key}: {value} names the shared data folder, but {where}; set PLACELOC_SHARED_DATA to the "
                          f"folder that holds {rel.split('/')[0]}/, or give {key} a path")
    path = root / rel
    if not path.exists():
        raise ConfigError(f"{key}: {value} -> {path} does not exist; the shared data folder {root} lacks it "
                          f"(set PLACELOC_SHARED_DATA to the folder that holds {rel.split('/')[0]}/)")
    return path
