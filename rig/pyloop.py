"""The executor's cycle in the interpreter: for a backend written in Python, or where nothing compiles.

Cycle for cycle what ``native_loop.c`` does (see :mod:`piezopreload.rig.executor`): wait for
the deadline on the run's clock (:mod:`piezopreload.rig.clock`), take a gain set asked for,
read the force, test the interlock rows of the reading stage
(:func:`piezopreload.rig.interlocks.first_trip`), step the controller, test the command rows,
clamp, slew-limit and write, log the sample. A stop ramps down at the loop's rate and disarms.
The interpreter's garbage collector is off for the run (the loop makes no reference cycles; a
full collection would hold it for milliseconds).
"""

from __future__ import annotations

import gc
import math
import traceback
from array import array
from typing import TYPE_CHECKING

from piezopreload.rig.backends import FaultInjector, InjectedFault
from piezopreload.rig.clock import MonotonicClock, VirtualClock, to_ns
from piezopreload.rig.interlocks import STAGES, TRIP_CAUSES, Trip, first_trip, rows, trip_detail
from piezopreload.rig.outcome import RunResult, timing_summary

if TYPE_CHECKING:
    from piezopreload.rig.executor import Executor

__all__ = ["PythonLoop"]

_READING, _COMMAND = STAGES.index("reading"), STAGES.index("command")
_NANS = (math.nan,) * 4


class PythonLoop:
    """One run of ``executor`` on the Python loop: :meth:`run` once."""

    def __init__(self, executor: Executor) -> None:
        self.ex = executor
        self.clock: MonotonicClock | VirtualClock = MonotonicClock() if executor.realtime else VirtualClock()
        self.table = rows(executor.safety)
        self.dt_ns = to_ns(executor.dt)
        self.slew_V = executor.safety.slew_V_per_s * executor.dt
        self.heartbeat = getattr(executor.backend, "heartbeat", None)
        self.lateness, self.periods = array("d"), array("d")
        self.k = self.missed = self.clamped = 0
        self.t = 0.0
        self.v_last = executor.safety.safe_V
        self.held_max = 0.0
        self.t0 = self.wake_prev = self.last_write = 0

    def run(self) -> RunResult:
        ex = self.ex
        handlers = ex._install_signal_handlers()
        gc_was_enabled = gc.isenabled()
        gc.collect()
        gc.disable()
        if isinstance(ex.backend, FaultInjector):  # an injected delay stalls this run's clock
            ex.backend.stall = self.clock.stall
        trip: Trip | None = None
        t_end = 0.0
        try:
            ex.backend.arm()
            ex._event("armed", 0.0, backend=ex.backend.name, controller_step=ex.step.kind, loop="python",
                      loop_reason=ex.loop_reason)
            self.t0 = self.wake_prev = self.last_write = self.clock.now()
            done = False
            while not done and (self.k < len(ex._ref) or ex.hold):
                done, trip = self._cycle()
        except Exception as exc:  # anything in the loop: stop the rig first, explain after
            trip = self._exception(exc)
        finally:
            try:
                if trip is not None:
                    ex._trip_event(trip)
                v_end, t_end = self._ramp_down()
                ex._event("ramped_down", t_end, voltage_V=v_end)
            finally:
                try:
                    ex.backend.disarm()
                finally:
                    ex._restore_signal_handlers(handlers)
                    if gc_was_enabled:
                        gc.enable()
        ex.latest = (self.t, ex.latest[1], ex.latest[2], ex.safety.safe_V, "tripped" if trip else "completed")
        ex._event("disarmed", t_end)
        timing = timing_summary(self.lateness, self.periods, missed=self.missed, dt=ex.dt, realtime=ex.realtime,
                                loop="python", stalls=ex.stalls, stall_count=ex.stalls.count, held_max_s=self.held_max,
                                stall_limit_s=ex.safety.stall_limit_s)
        return ex._finish(trip, self.k, timing, self.clamped)

    def _exception(self, exc: Exception) -> Trip:
        ex = self.ex
        ex._log_row((self.t, math.nan, math.nan, math.nan, self.v_last, *_NANS, 0.0, 0.0, 0.0, 0, 2))
        if isinstance(exc, InjectedFault):  # a fire drill: its words, as the native loop says them
            return Trip("exception", str(exc), self.t, self.v_last)
        ex._event("traceback", self.t, text="".join(traceback.format_exception(exc))[-4000:])
        return Trip("exception", f"{type(exc).__name__}: {exc}", self.t, self.v_last)

    def _trip(self, hit: tuple[int, float]) -> Trip:
        cause = TRIP_CAUSES[hit[0] - 1]
        return Trip(cause, trip_detail(cause, hit[1], self.ex.safety), self.t, self.v_last)

    def _take_switch(self) -> None:
        ex = self.ex
        if ex._pending is not None:
            new, info = ex._pending
            ex.step.switch(new)
            ex.controller = new  # before the switch stops pending: a server shows the new hash with the new gains
            ex._pending = None
            # recorded now, written to the sidecar by the server's thread (Executor.save_events): a sidecar's
            # rewrite (its fsync) has no place inside a cycle
            ex._event("gains_switched", self.t, persist=False, cycle=self.k, **info)
            ex._unsaved = True

    def _cycle(self) -> tuple[bool, Trip | None]:
        """One cycle: ``(stop, trip)``; a stop without a trip is a run ended by :meth:`Executor.stop`."""
        ex, k = self.ex, self.k
        n_ref = len(ex._ref)
        self.t = t = k * ex.dt
        sp = ex._ref[min(k, n_ref - 1)]
        deadline = self.t0 + k * self.dt_ns
        wake = self.clock.wait(deadline)
        self._take_switch()
        late, period = (wake - deadline) * 1e-9, (wake - self.wake_prev) * 1e-9
        if ex._stop is not None:  # this cycle is the stop's: logged, no reading, no command
            ex._log_row((t, sp, math.nan, math.nan, self.v_last, *_NANS, period, late, 0.0, 0, 2))
            if ex._stop_trips:
                return True, Trip("signal", ex._stop, t, self.v_last)
            ex._event("stopped", t, reason=ex._stop)
            return True, None
        reading = ex.backend.read_force(t)
        y, age = float(reading.force_N), t - reading.t_s
        held = (self.clock.now() - self.last_write) * 1e-9
        self.held_max = max(self.held_max, held)
        if held > ex.stall_report_s:
            ex.stalls.add(t, held)
        hit = first_trip(self.table, _READING, (y, age, held, math.nan))
        if hit is not None:
            ex._log_row((t, sp, y, math.nan, self.v_last, *_NANS, period, late, 0.0, 0, 2))
            return True, self._trip(hit)
        u, p, i, d, ff = self._step(sp, y)
        hit = first_trip(self.table, _COMMAND, (y, age, held, u))
        if hit is not None:
            ex._log_row((t, sp, y, u, self.v_last, ff, p, i, d, period, late, 0.0, 0, 2))
            return True, self._trip(hit)
        v = self._write(u)
        done = self.clock.now()
        miss = int(done > deadline + self.dt_ns)
        self.missed += miss
        self.lateness.append(late)
        self.periods.append(period)
        ex._log_row((t, sp, y, u, v, ff, p, i, d, period, late, (done - wake) * 1e-9, miss, 0))
        self.wake_prev = wake
        ex.latest = (t, sp, y, v, "running")
        self.k += 1
        return False, None

    def _step(self, sp: float, y: float) -> tuple[float, float, float, float, float]:
        ex, k = self.ex, self.k
        if ex._extra is None:
            if k == 0:  # bumpless start on the first reading: the first command is the safe level
                ex.step.start(sp, y, self.v_last)
            return ex.step.step(sp, y)
        fx = ex._extra[min(k, len(ex._extra) - 1)]
        if k == 0:
            ex.step.start(sp, y, self.v_last, ex._extra[0])
        return ex.step.step(sp, y, fx)

    def _write(self, u: float) -> float:
        s = self.ex.safety
        v = min(max(u, s.v_min_V), s.v_max_V)
        v = min(max(v, self.v_last - self.slew_V), self.v_last + self.slew_V)
        if v != u:
            self.clamped += 1
        self.ex.backend.write_voltage(v)
        self.last_write = self.clock.now()
        if self.heartbeat is not None:
            self.heartbeat()
        self.v_last = v
        return v

    def _ramp_down(self) -> tuple[float, float]:
        """From the last voltage to the safe level in a straight line over ``ramp_s``, at the loop's rate.

        The ramp's samples follow the last one logged, whichever way the loop ended. Returns the
        voltage reached and the time of the ramp's last sample.
        """
        ex = self.ex
        s, dt, v_from = ex.safety, ex.dt, self.v_last
        n = 0 if v_from == s.safe_V else max(1, int(math.ceil(s.ramp_s / dt)))
        k0 = ex._rows - 1  # the last sample logged
        t0 = self.t0 if ex._rows else self.clock.now()
        v, t = v_from, max(k0, 0) * dt
        for j in range(1, n + 1):
            t = (k0 + j) * dt
            self.clock.wait(t0 + (k0 + j) * self.dt_ns)
            v = s.safe_V if j == n else v_from + (s.safe_V - v_from) * j / n
            try:
                y = float(ex.backend.read_force(t).force_N)
            except Exception:
                y = math.nan
            try:
                ex.backend.write_voltage(v)
            except Exception as exc:  # the backend is gone: one last try at the safe level, then disarm
                ex._event("ramp_failed", t, detail=f"{type(exc).__name__}: {exc}")
                try:
                    ex.backend.write_voltage(s.safe_V)
                    v = s.safe_V
                except Exception:
                    pass
                return v, t
            if self.heartbeat is not None:
                self.heartbeat()
            ex._log_row((t, math.nan, y, math.nan, v, *_NANS, dt, 0.0, 0.0, 0, 1))
            ex.latest = (t, math.nan, y, v, "ramping down")
        return v, t
