"""One executor interface for a campaign's runs: in process, local processes, or a Dask cluster.

Every backend is a :class:`concurrent.futures.Executor`, so the campaign submits runs and
collects them with :func:`concurrent.futures.as_completed` whatever runs them:

- ``jobs=1``, no scheduler: :class:`SerialExecutor`, each run in this process when submitted
  (no process start-up; what the tests and a debugger want);
- ``jobs=J``: :class:`concurrent.futures.ProcessPoolExecutor` with ``J`` workers, started with
  ``spawn`` (a clean interpreter each: JSBSim and numba hold no state across a fork);
- ``scheduler="tcp://HOST:8786"``: Dask's distributed executor
  (``distributed.Client(address).get_executor()``), from the optional ``cluster`` extra. Start
  each worker with one thread (``dask worker tcp://HOST:8786 --nthreads 1 --nworkers N``): a
  run is single-threaded Python, and JSBSim is not known to be thread-safe.

This is the only module that imports Dask.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from contextlib import contextmanager
from typing import Any

from immukf_sitl.errors import UserError


class SerialExecutor(Executor):
    """Runs each submitted call at once, in this process; its future is already done."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        """Run ``fn(*args, **kwargs)`` now; the future holds its result or exception."""
        future: Future = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - the future carries it, as a pool's does
            future.set_exception(exc)
        return future


def _dask_executor(address: str) -> tuple[Executor, Callable[[], None]]:
    """Dask's executor on the scheduler at ``address`` and how to close the client."""
    try:
        from distributed import Client
    except ImportError:
        raise UserError(
            "--scheduler needs Dask: pip install 'immukf-sitl[cluster]' (dask[distributed])"
        ) from None
    try:
        client = Client(address, timeout="20s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise UserError(f"--scheduler {address}: cannot connect ({exc})") from None
    return client.get_executor(pure=False), client.close


@contextmanager
def open_executor(jobs: int = 1, scheduler: str | None = None) -> Iterator[Executor]:
    """The executor for ``jobs`` local workers, or for the Dask scheduler at ``scheduler``.

    Parameters
    ----------
    jobs : int, optional
        Local worker processes (ignored with a scheduler); 1 runs in this process.
    scheduler : str, optional
        A Dask scheduler address, e.g. ``tcp://10.0.0.5:8786``.

    Yields
    ------
    concurrent.futures.Executor
    """
    if jobs < 1:
        raise UserError(f"--jobs: expected at least 1, got {jobs}")
    if scheduler is not None:
        executor, close = _dask_executor(scheduler)
        try:
            yield executor
        finally:
            executor.shutdown(wait=False)
            close()
        return
    if jobs == 1:
        yield SerialExecutor()
        return
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=jobs, mp_context=context) as pool:
        yield pool
