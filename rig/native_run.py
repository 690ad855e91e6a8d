"""The supervisor of the native loop: start it, feed it gain sets, drain its samples and stalls to the log, stop it.

The cycle runs in C (:mod:`piezopreload.rig.native_loop`); this side never runs inside a
cycle's deadline. Every 10 ms it drains the ring of samples and the ring of stalls into the run
log and the events, records the gain switches the loop took and publishes the latest cycle for
a server; when the loop has finished it takes the rest, says in words why it stopped (the same
words as the Python loop: :func:`piezopreload.rig.interlocks.trip_detail`) and closes the log.
"""

from __future__ import annotations

import signal
import time
import traceback
from array import array
from typing import TYPE_CHECKING, Any

import numpy as np

from piezopreload.core.errors import InternalError
from piezopreload.rig import native_loop
from piezopreload.rig.backends import FaultInjector, injected_failure, native_backend
from piezopreload.rig.interlocks import TRIP_CAUSES, Trip, trip_detail
from piezopreload.rig.native_loop import LoopStatus, NativeLoop
from piezopreload.rig.outcome import RunResult, timing_summary

if TYPE_CHECKING:
    from piezopreload.rig.executor import Executor

__all__ = ["NativeRun", "POLL_S"]

#: how often the supervisor drains the loop
POLL_S = 0.01


class NativeRun:
    """One run of ``executor`` on the native loop: :meth:`run` once."""

    def __init__(self, executor: Executor) -> None:
        self.ex = executor
        self.lateness, self.periods = array("d"), array("d")
        self.switches_seen = 0
        self.stalls_lost = 0
        self.t_last = 0.0

    def _setup(self) -> NativeLoop:
        ex = self.ex
        s, dt = ex.safety, ex.dt
        faults = []
        inner = ex.backend
        if isinstance(inner, FaultInjector):
            faults = [(native_loop.FAULT_CODES[f.kind], f.at_s, f.value, f.duration_s) for f in inner.faults]
            inner = inner.inner
        # noise draws for the whole finite run (control, stop, ramp); a held run reuses them cyclically
        n_noise = len(ex.setpoints_N) + int(np.ceil(s.ramp_s / dt)) + 16
        if ex.hold:
            n_noise = max(n_noise, 1 << 18)
        backend = native_backend(inner, n_noise)
        if backend is None:  # the executor chose the native loop because the backend offers one
            raise InternalError(f"the backend '{inner.name}' offers no native loop")
        extra = ex.ff_extra_V
        return NativeLoop(ex.controller, np.asarray(ex.setpoints_N), s, backend, realtime=ex.realtime, hold=ex.hold,
                          faults=faults, step_fn=ex.step.entry_point,
                          ff_extra=None if extra is None else np.asarray(extra))

    def run(self) -> RunResult:
        ex = self.ex
        trip: Trip | None = None
        status: LoopStatus | None = None
        loop: NativeLoop | None = None
        armed_here = False
        with ex.signal_handlers() as catching:
            try:
                loop = self._setup()
                loop.lock_memory()
                if loop.backend_kind == 0:  # the simulated rig is armed here; a C library's arm runs in the loop's
                    ex.backend.arm()        # thread
                    armed_here = True
                self._start(loop, catching)
                while not self._poll(loop):
                    time.sleep(POLL_S)
                status = self._collect(loop)
                trip = self._trip(loop, status)
            except Exception as exc:  # the loop never started (or the supervisor failed): the rig is safe, say why
                if loop is not None:
                    loop.stop(True)
                    status = self._collect(loop)
                trip = Trip("exception", f"{type(exc).__name__}: {exc}", self.t_last,
                            status.trip_v if status is not None else ex.safety.safe_V)
                ex.log_event("traceback", self.t_last, text="".join(traceback.format_exception(exc))[-4000:])
            finally:
                ex.detach_native()
                if armed_here:
                    ex.backend.disarm()
        return self._end(trip, status, loop)

    def _start(self, loop: NativeLoop, catch_signals: bool) -> None:
        ex = self.ex
        ex.attach_native(loop)  # a switch asked for before the start goes in with it
        loop.start(catch_signals=catch_signals)
        ex.log_event("armed", 0.0, persist=True, backend=ex.backend.name, controller_step=ex.step.kind, loop="native",
                     **loop.realtime_report)
        stop = ex.stop_request  # asked for before the loop could take it
        if stop is not None:
            loop.stop(stop.trip)

    def _poll(self, loop: NativeLoop) -> bool:
        """Drain samples, stalls and switches; publish the latest cycle. True once the loop has finished."""
        ex = self.ex
        finished = loop.finished
        self._drain(loop)
        n_sw = loop.switches
        while self.switches_seen < n_sw:
            self.switches_seen += 1
            ex.native_switched(loop.switch_t)
        t, sp, y, v, mode = loop.latest
        ex.latest = (t, sp, y, v, "running" if mode == 0 else "ramping down")
        return finished

    def _drain(self, loop: NativeLoop) -> None:
        ex = self.ex
        rows = loop.drain()
        if rows.shape[0]:
            control = rows[:, 13] == 0
            self.lateness.extend(rows[control, 10].tolist())
            self.periods.extend(rows[control, 9].tolist())
            ex.log_samples(rows)
            self.t_last = float(rows[-1, 0])
        stalls, lost = loop.stalls()
        self.stalls_lost += lost
        for t_s, held_s in stalls.tolist():
            ex.stalls.add(t_s, held_s)

    def _collect(self, loop: NativeLoop) -> LoopStatus:
        """Join the native loop, take the samples and stalls still in its rings, and return its status."""
        loop.join()
        self._drain(loop)
        return loop.status()

    def _trip(self, loop: NativeLoop, status: LoopStatus) -> Trip | None:
        ex = self.ex
        asked = None if ex.stop_request is None else ex.stop_request.reason
        if not status.trip_cause:
            if loop.stop_requested == 2:
                ex.log_event("stopped", status.trip_t, reason=asked)
            return None
        cause = TRIP_CAUSES[status.trip_cause - 1]
        if cause == "signal":
            detail = asked or signal.Signals(loop.stop_signal).name
        elif cause == "exception":
            where = native_loop.EXCEPTION_WHERE.get(status.trip_where, "the loop")
            detail = (injected_failure(status.trip_t) if status.trip_value == -1000
                      else f"{where} returned {status.trip_value:g}")
        else:
            detail = trip_detail(cause, status.trip_value, ex.safety)
        return Trip(cause, detail, status.trip_t, status.trip_v)

    def _end(self, trip: Trip | None, status: LoopStatus | None, loop: NativeLoop | None) -> RunResult:
        ex = self.ex
        s = ex.safety
        t_end = status.t_end if status is not None else self.t_last
        v_end = status.v_end if status is not None else s.safe_V
        if trip is not None:
            ex.record_trip(trip)
        if status is not None and status.ramp_failed:
            ex.log_event("ramp_failed", status.ramp_failed_t, detail="the backend's write_voltage failed in the ramp")
        ex.log_event("ramped_down", t_end, voltage_V=v_end)
        ex.log_event("disarmed", t_end)
        ex.latest = (t_end, ex.latest[1], ex.latest[2], s.safe_V, "tripped" if trip else "completed")
        report: dict[str, Any] = loop.realtime_report if loop is not None else {}
        timing = timing_summary(self.lateness, self.periods, missed=status.missed if status else 0, dt=ex.dt,
                                realtime=ex.realtime, loop="native", stalls=ex.stalls,
                                stall_count=status.stalls if status else 0,
                                held_max_s=status.held_max_s if status else 0.0, stall_limit_s=s.stall_limit_s,
                                lost=status.lost if status else 0, report=report)
        return ex.finish(trip, status.cycles if status else 0, timing, status.clamped if status else 0)
