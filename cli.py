"""placeloc's command line, runnable from a checkout as ``python cli.py ...``.

The commands live in :mod:`placeloc.cli` (``pipeline/cli.py``) so that an installed
placeloc claims no top-level module named ``cli``; the ``placeloc`` console script and this
file run the same Typer app.
"""

from placeloc.cli import app, main

__all__ = ["app", "main"]

if __name__ == "__main__":
    main()
