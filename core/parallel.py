"""One run's worker processes: made by the run, handed down to the steps that can overlap, shut at its end.

A study's stages hold independent computations (the minimum-time bound beside the PID tuning, the
gain schedule's entries and validations, the Monte Carlo chunks, the report's figures); on a machine
with more than one CPU they overlap. The run that holds them (a study run, a sweep's point, one
``tune``) makes one :class:`Pool` of ``workers`` processes, passes it to each step and shuts it at
its end (``with Pool(n) as pool: ...``); a step submits to it and never starts processes of its
own. ``Pool(1)`` runs each job at once, here, with no process at all. The result is the same either
way (a job gets the same arguments; nothing is shared).

The number of workers is an argument all the way down. The one place the environment is read is
:func:`default_workers`, which an outer entry (the command line, :func:`~piezopreload.pipeline.run_study`
called without ``workers``) calls once: ``PIEZOPRELOAD_WORKERS`` where the user set it, else the
machine's CPU count. Nothing here writes the environment.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
from collections.abc import Callable, Mapping
from typing import Any, Generic, TypeVar

from piezopreload.core.errors import InputError

__all__ = ["Pool", "Beside", "default_workers", "WORKERS_VARIABLE"]

T = TypeVar("T")

#: the environment variable a user may set in their shell to choose the default worker count
WORKERS_VARIABLE = "PIEZOPRELOAD_WORKERS"


def default_workers(environ: Mapping[str, str] | None = None) -> int:
    """The worker count an outer entry uses where none is given: ``PIEZOPRELOAD_WORKERS`` where set, else the CPUs.

    Parameters
    ----------
    environ : mapping, optional
        The environment to read (default: this process's); it is only read.

    Returns
    -------
    int
        The count, >= 1.

    Raises
    ------
    InputError
        Where the variable is set to anything but a whole number >= 1.
    """
    text = (os.environ if environ is None else environ).get(WORKERS_VARIABLE, "").strip()
    if not text:
        return os.cpu_count() or 1
    try:
        workers = int(text)
    except ValueError:
        workers = 0
    if workers < 1:
        raise InputError(f"{WORKERS_VARIABLE}={text!r}: expected a whole number of processes >= 1 (1: no workers)")
    return workers


def _checked(workers: int, where: str) -> int:
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InputError(f"{where}: must be a whole number >= 1, got {workers!r}")
    return workers


class Beside(Generic[T]):
    """A computation started by :meth:`Pool.beside`; :meth:`result` waits for it and returns (or raises) its outcome."""

    def __init__(self, future: cf.Future[T]) -> None:
        self._future: cf.Future[T] | None = future

    def discard(self) -> None:
        """The result is not wanted: return at once (a job not started is cancelled; a running one finishes
        unread)."""
        if self._future is not None:
            self._future.cancel()
        self._future = None

    def result(self) -> T | None:
        """Wait for the job and return its value (raise its error); None once discarded.

        Returns
        -------
        object or None
            The function's value.
        """
        return None if self._future is None else self._future.result()


class Pool(cf.Executor):
    """A run's worker processes, or none: a :class:`concurrent.futures.Executor` that steps submit their jobs to.

    Parameters
    ----------
    workers : int
        Processes (>= 1); 1 runs each job at submission, here (also on a platform without ``fork``).

    Notes
    -----
    The processes are forked when the first job is submitted, so they start with this process's imports, and
    shut down by :meth:`shutdown` (leaving a ``with`` block): a run's steps share them, none starts its own.
    """

    def __init__(self, workers: int = 1) -> None:
        self.workers = _checked(workers, "workers")
        self._pool: cf.ProcessPoolExecutor | None = None
        self._closed = False

    @property
    def parallel(self) -> bool:
        """Whether jobs run in worker processes (more than one worker, and ``fork`` available)."""
        return self.workers > 1 and "fork" in multiprocessing.get_all_start_methods()

    @property
    def description(self) -> str:
        """How jobs run, in words: ``inline`` or ``N local processes``."""
        return f"{self.workers} local processes" if self.parallel else "inline"

    def submit(self, fn: Callable[..., T], /, *args: Any, **kwargs: Any) -> cf.Future[T]:
        """Run ``fn(*args, **kwargs)`` in a worker (or here, with one worker); its future.

        Parameters
        ----------
        fn : callable
            The job: a module-level function (it is pickled to the worker), with its arguments.
        *args, **kwargs
            Its arguments.

        Returns
        -------
        concurrent.futures.Future
            Its outcome, value or error.
        """
        if self._closed:
            raise RuntimeError("this run's pool is shut down: a step ran after its run ended")
        if not self.parallel:
            future: cf.Future[T] = cf.Future()
            try:
                future.set_result(fn(*args, **kwargs))
            except BaseException as exc:  # handed to the caller through the future, as a worker's would be
                future.set_exception(exc)
            return future
        if self._pool is None:
            fork = multiprocessing.get_context("fork")
            self._pool = cf.ProcessPoolExecutor(max_workers=self.workers, mp_context=fork)
        return self._pool.submit(fn, *args, **kwargs)

    def beside(self, fn: Callable[..., T], /, *args: Any, **kwargs: Any) -> Beside[T]:
        """Start ``fn(*args, **kwargs)`` beside what this process does next (at once, here, with one worker).

        Parameters
        ----------
        fn : callable
            The job, with its arguments.
        *args, **kwargs
            Its arguments.

        Returns
        -------
        Beside
            Its handle: ``result()`` waits for it.
        """
        return Beside(self.submit(fn, *args, **kwargs))

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Stop the processes (waiting for their jobs where ``wait``); the pool takes no job after.

        Parameters
        ----------
        wait : bool
            Wait for the running jobs.
        cancel_futures : bool
            Cancel the jobs not started.
        """
        self._closed = True
        if self._pool is not None:
            self._pool.shutdown(wait=wait, cancel_futures=cancel_futures)
            self._pool = None

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        # a run that failed does not wait for the jobs it no longer reads
        self.shutdown(wait=exc_type is None, cancel_futures=exc_type is not None)

    def __repr__(self) -> str:
        return f"Pool(workers={self.workers})"
