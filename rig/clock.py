"""The Python loop's clocks: the monotonic clock for a run in real time, a virtual one for a run back to back.

Both count integer nanoseconds, as the native loop's clocks do (``native_loop.c``:
``clock_now``, ``clock_wait``, ``clock_stall``), so the two loops compute a cycle's period,
lateness and hold the same way. :class:`VirtualClock` moves only when the loop waits for a
deadline later than its time or a stall is injected: a run back to back with an injected
stall gives the same samples and events on every host, and the tests of the stall interlock
need no wall clock.
"""

from __future__ import annotations

import math
import time

__all__ = ["MonotonicClock", "VirtualClock", "SPIN_NS", "to_ns"]

#: the Python loop sleeps to this much before a deadline, then spins: time.sleep alone overshoots ~60 us
SPIN_NS = 200_000


def to_ns(seconds: float) -> int:
    """``seconds`` in integer nanoseconds, rounded half away from zero as C's ``llround``."""
    x = seconds * 1e9
    return int(math.floor(x + 0.5)) if x >= 0 else -int(math.floor(-x + 0.5))


class MonotonicClock:
    """The host's monotonic clock (``CLOCK_MONOTONIC``); waits sleep, then spin the last :data:`SPIN_NS`."""

    realtime = True

    @staticmethod
    def now() -> int:
        return time.perf_counter_ns()

    @staticmethod
    def wait(deadline_ns: int) -> int:
        now = time.perf_counter_ns()
        if deadline_ns - now > SPIN_NS:
            time.sleep((deadline_ns - now - SPIN_NS) * 1e-9)
        while (now := time.perf_counter_ns()) < deadline_ns:
            pass
        return now

    @staticmethod
    def stall(seconds: float) -> None:
        time.sleep(seconds)


class VirtualClock:
    """A clock that moves only by :meth:`wait` (to a later deadline) and :meth:`stall` (by the stall)."""

    realtime = False

    def __init__(self) -> None:
        self.t_ns = 0

    def now(self) -> int:
        return self.t_ns

    def wait(self, deadline_ns: int) -> int:
        self.t_ns = max(self.t_ns, int(deadline_ns))
        return self.t_ns

    def stall(self, seconds: float) -> None:
        self.t_ns += to_ns(seconds)
