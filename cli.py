"""placeloc's command line, runnable from a checkout as ``python cli.py ...``.

The commands live in :mod:`placeloc.cli` (``pipeline/placeloc/cli.py``) so that an
installed placeloc claims no top-level module named ``cli``; the ``placeloc`` console
script and this file run the same Typer app. In a checkout that is not installed, the
package folder ``pipeline/`` is put on the import path first.
"""

import sys
from pathlib import Path

_PIPELINE = Path(__file__).resolve().parent / "pipeline"
if (_PIPELINE / "placeloc").is_dir() and str(_PIPELINE) not in sys.path:
    sys.path.insert(0, str(_PIPELINE))

from placeloc.cli import app, main  # noqa: E402

__all__ = ["app", "main"]

if __name__ == "__main__":
    main()
