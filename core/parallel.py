"""Work started beside the current one: a forked worker process where the machine has a CPU to spare.

A study's stages hold independent computations (the minimum-time bound beside the PID tuning,
the report's figures); on a machine with more than one CPU they overlap. :func:`beside` starts a
function in a forked process and returns a handle whose :meth:`Beside.result` waits for it; with
one CPU, without ``fork``, or with ``PIEZOPRELOAD_WORKERS=1`` it runs the function at once, here.
The result is the same either way (the function gets the same arguments; nothing is shared).
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any, Generic, TypeVar, cast

from piezopreload.core.errors import InputError

__all__ = ["beside", "Beside", "spare_cpus", "fork_pool"]

T = TypeVar("T")


def spare_cpus() -> int:
    """CPUs a second process could use: ``PIEZOPRELOAD_WORKERS`` if set, else the machine's count."""
    env = os.environ.get("PIEZOPRELOAD_WORKERS", "").strip()
    if not env:
        return os.cpu_count() or 1
    try:
        workers = int(env)
    except ValueError:
        workers = 0
    if workers < 1:
        raise InputError(f"PIEZOPRELOAD_WORKERS={env!r}: expected a whole number of processes >= 1 (1: no workers)")
    return workers


class Beside(Generic[T]):
    """A computation started by :func:`beside`; :meth:`result` waits for it and returns (or raises) its outcome."""

    def __init__(self, future: Future[T] | None, value: T | None = None, error: BaseException | None = None,
                 pool: ProcessPoolExecutor | None = None) -> None:
        self._future, self._error, self._pool = future, error, pool
        self._value: T | None = value

    @property
    def in_worker(self) -> bool:
        return self._future is not None

    def discard(self) -> None:
        """The result is not wanted: return at once (a running worker finishes on its own, unread)."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
        self._future = self._pool = None
        self._value = self._error = None

    def result(self) -> T:
        if self._future is not None:
            try:
                self._value = self._future.result()
            finally:
                if self._pool is not None:
                    self._pool.shutdown(wait=True)
                self._future = None
        if self._error is not None:
            raise self._error
        # without an error the value is the function's (None only where the function returned None)
        return cast(T, self._value)


def fork_pool(workers: int) -> ProcessPoolExecutor | None:
    """A pool of ``workers`` forked processes (they start with this process's imports), or None without ``fork``."""
    if "fork" not in multiprocessing.get_all_start_methods():
        return None
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork"))


def beside(fn: Callable[..., T], /, *args: Any, **kwargs: Any) -> Beside[T]:
    """Start ``fn(*args, **kwargs)`` in a forked worker if a CPU is spare, else run it now."""
    pool = fork_pool(1) if spare_cpus() > 1 else None
    if pool is not None:
        return Beside(pool.submit(fn, *args, **kwargs), pool=pool)
    try:
        return Beside(None, value=fn(*args, **kwargs))
    except Exception as exc:  # raised from result(), where the worker's would be
        return Beside(None, error=exc)
