"""Build the executor a config's ``executor:`` section asks for.

Kept apart from :mod:`placeloc.core.executor` (the base class, the in-process and the
process-pool executors) and :mod:`placeloc.core.dask_executor` (which builds on that base), so
neither of those two imports the other: this is the one module that knows both.
"""

from __future__ import annotations

from placeloc.core.common_params import ExecutorParams
from placeloc.core.errors import ConfigError
from placeloc.core.executor import Executor, InlineExecutor, LocalExecutor


def make_executor(params: ExecutorParams) -> Executor:
    """``kind: local`` with one worker runs in this process; more workers, a process pool;
    ``kind: dask``, a Dask client (the optional extra)."""
    if params.kind == "dask":
        try:
            from placeloc.core.dask_executor import DaskExecutor  # optional extra
        except ImportError as exc:
            raise ConfigError(f"executor.kind: dask is not available ({exc}); "
                              "install it with pip install 'placeloc[dask]' or use executor.kind: local") from exc

        return DaskExecutor(params)
    workers = int(params.workers)
    return InlineExecutor() if workers <= 1 else LocalExecutor(workers)
