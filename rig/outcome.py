"""How a rig run ended, for both loops: the result, the stalls it counted, its timing summary."""

from __future__ import annotations

from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from piezopreload.artifacts.rigrun import RunTiming
from piezopreload.rig.interlocks import Trip

__all__ = ["RunResult", "StallLog", "timing_summary", "MAX_STALL_EVENTS"]

#: stalls logged as events in one run (every stall is counted; beyond this many only counted)
MAX_STALL_EVENTS = 1000


@dataclass
class RunResult:
    """How a run ended: ``status`` ``completed`` or ``tripped`` (with its :class:`Trip`), the timing, the log."""

    status: str
    trip: Trip | None
    cycles: int
    timing: RunTiming
    clamped_cycles: int
    controller_step: str
    csv_path: str | None
    json_path: str | None
    events: list[dict[str, Any]] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.status == "completed"


class StallLog:
    """The stalls of a run: counted, the first :data:`MAX_STALL_EVENTS` given to ``event(t_s, held_s)`` to log
    (the executor logs them without rewriting the sidecar at once: a rewrite would stall the Python loop)."""

    def __init__(self, event: Callable[[float, float], None]) -> None:
        self._event = event
        self.count = 0
        self.logged = 0

    def add(self, t_s: float, held_s: float) -> None:
        self.count += 1
        if self.logged < MAX_STALL_EVENTS:
            self.logged += 1
            self._event(t_s, held_s)


def timing_summary(lateness: array, periods: array, *, missed: int, dt: float, realtime: bool, loop: str,
                   stalls: StallLog, stall_count: int, held_max_s: float, stall_limit_s: float, lost: int = 0,
                   report: dict[str, str] | None = None) -> RunTiming:
    """A run's timing from its control cycles' lateness and periods (s) and its counts."""
    late = np.frombuffer(lateness, dtype=float) if len(lateness) else np.zeros(1)
    per = np.frombuffer(periods, dtype=float)[1:] if len(periods) > 1 else np.full(1, dt)
    return RunTiming(
        loop=loop, realtime=realtime, rate_Hz=1.0 / dt, cycles=len(lateness), missed_deadlines=int(missed),
        lateness_p50_s=float(np.percentile(late, 50)), lateness_p99_s=float(np.percentile(late, 99)),
        lateness_max_s=float(late.max()), period_mean_s=float(per.mean()), period_std_s=float(per.std()),
        period_max_s=float(per.max()), stalls=int(stall_count), stall_events_logged=stalls.logged,
        held_max_s=float(held_max_s), stall_limit_s=float(stall_limit_s), lost_samples=int(lost),
        sched_fifo=(report or {}).get("sched_fifo"), memory_locked=(report or {}).get("memory_locked"))
