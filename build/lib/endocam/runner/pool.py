"""The one local worker pool of the runner: a process pool, or inline calls for one worker.

``experiment tracking`` and ``endocam sweep --backend local`` both submit their episodes here.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import multiprocessing
from collections.abc import Iterator
from typing import Any

DEFAULT_WORKERS = 2  # processes: the machine this was measured on has two cores


class InlineExecutor(concurrent.futures.Executor):
    """Runs submitted calls at once, in this process (``workers=1``)."""

    def submit(self, fn: Any, /, *args: Any, **kwargs: Any) -> concurrent.futures.Future[Any]:
        """Call ``fn(*args, **kwargs)`` now; its result or exception is in the future."""
        fut: concurrent.futures.Future[Any] = concurrent.futures.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # handed to the caller through the future
            fut.set_exception(exc)
        return fut


@contextlib.contextmanager
def executor(
    workers: int, start_method: str | None = None
) -> Iterator[concurrent.futures.Executor]:
    """A process pool of ``workers`` processes, or an :class:`InlineExecutor` for one.

    ``start_method`` (``"spawn"``, ``"forkserver"``, ``"fork"``; None: the platform's default)
    is how the workers start. Jobs that render need ``"spawn"``: a worker forked from a process
    that has rendered inherits its EGL state and hangs in its first render (measured: the study's
    extra seeds never finished).

    A context manager: on leaving normally it waits for every job; on an exception (an
    interrupt, a failed job) it cancels the jobs not started and terminates the workers, so no
    process outlives the command and the caller's clean-up (a temporary folder) runs at once.

    Raises
    ------
    ValueError
        For ``workers`` < 1.
    """
    if workers < 1:
        raise ValueError(f"workers must be ≥ 1, got {workers}")
    if workers == 1:
        yield InlineExecutor()
        return
    context = None if start_method is None else multiprocessing.get_context(start_method)
    pool = concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=context)
    try:
        yield pool
    except BaseException:
        # the pool's own shutdown would wait for the running jobs (minutes for a render); the
        # executor has no public way to stop them before Python 3.14's terminate_workers()
        processes = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in processes:
            proc.terminate()
        for proc in processes:
            proc.join(timeout=5.0)
        raise
    pool.shutdown(wait=True)
