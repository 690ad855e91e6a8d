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
        self.setpoints, self.ff_extra = executor.setpoints_N, executor.ff_extra_V
        self.lateness, self.periods = array("d"), array("d")
        self.k = self.missed = self.clamped = 0
        self.t = 0.0
        self.v_last = executor.safety.safe_V
        self.held_max = 0.0
        self.t0 = self.wake_prev = self.last_write = 0

    def run(self) -> RunResult:
        ex = self.ex
        trip: Trip | None = None
        t_end = 0.0
        with ex.signal_handlers():
            gc_was_enabled = gc.isenabled()
            gc.collect()
            gc.disable()
            if isinstance(ex.backend, FaultInjector):  # an injected delay stalls this run's clock
                ex.backend.stall = self.clock.stall
            try:
                ex.backend.arm()
                ex.log_event("armed", 0.0, backend=ex.backend.name, controller_step=ex.step.kind, loop="python",
                             loop_reason=ex.loop_reason)
                self.t0 = self.wake_prev = self.last_write = self.clock.now()
                n_ref, done = len(self.setpoints), False
                while not done and (self.k < n_ref or ex.hold):
                    done, trip = self._cycle()
            except Exception as exc:  # anything in the loop: stop the rig first, explain after
                trip = self._exception(exc)
            finally:
                try:
                    if trip is not None:
                        ex.record_trip(trip)
                    v_end, t_end = self._ramp_down()
                    ex.log_event("ramped_down", t_end, voltage_V=v_end)
                finally:
                    try:
                        ex.backend.disarm()
                    finally:
                        if gc_was_enabled:
                            gc.enable()
        ex.latest = (self.t, ex.latest[1], ex.latest[2], ex.safety.safe_V, "tripped" if trip else "completed")
        ex.log_event("disarmed", t_end)
        timing = timing_summary(self.lateness, self.periods, missed=self.missed, dt=ex.dt, realtime=ex.realtime,
                                loop="python", stalls=ex.stalls, stall_count=ex.stalls.count, held_max_s=self.held_max,
                                stall_limit_s=ex.safety.stall_limit_s)
        return ex.finish(trip, self.k, timing, self.clamped)

    def _exception(self, exc: Exception) -> Trip:
        ex = self.ex
        ex.log_sample((self.t, math.nan, math.nan, math.nan, self.v_last, *_NANS, 0.0, 0.0, 0.0, 0, 2))
        if isinstance(exc, InjectedFault):  # a fire drill: its words, as the native loop says them
            return Trip("exception", str(exc), self.t, self.v_last)
        ex.log_event("traceback", self.t, text="".join(traceback.format_exception(exc))[-4000:])
        return Trip("exception", f"{type(exc).__name__}: {exc}", self.t, self.v_last)

    def _trip(self, hit: tuple[int, float]) -> Trip:
        cause = TRIP_CAUSES[hit[0] - 1]
        return Trip(cause, trip_detail(cause, hit[1], self.ex.safety), self.t, self.v_last)

    def _cycle(self) -> tuple[bool, Trip | None]:
        """One cycle: ``(stop, trip)``; a stop without a trip is a run ended by :meth:`Executor.stop`."""
        ex, k, ref = self.ex, self.k, self.setpoints
        self.t = t = k * ex.dt
        sp = ref[min(k, len(ref) - 1)]
        deadline = self.t0 + k * self.dt_ns
        wake = self.clock.wait(deadline)
        ex.take_switch(t, k)
        late, period = (wake - deadline) * 1e-9, (wake - self.wake_prev) * 1e-9
        stop = ex.stop_request
        if stop is not None:  # this cycle is the stop's: logged, no reading, no command
            ex.log_sample((t, sp, math.nan, math.nan, self.v_last, *_NANS, period, late, 0.0, 0, 2))
            if stop.trip:
                return True, Trip("signal", stop.reason, t, self.v_last)
            ex.log_event("stopped", t, reason=stop.reason)
            return True, None
        reading = ex.backend.read_force(t)
        y, age = float(reading.force_N), t - reading.t_s
        held = (self.clock.now() - self.last_write) * 1e-9
        self.held_max = max(self.held_max, held)
        if held > ex.stall_report_s:
            ex.stalls.add(t, held)
        hit = first_trip(self.table, _READING, (y, age, held, math.nan))
        if hit is not None:
            ex.log_sample((t, sp, y, math.nan, self.v_last, *_NANS, period, late, 0.0, 0, 2))
            return True, self._trip(hit)
        u, p, i, d, ff = self._step(sp, y)
        hit = first_trip(self.table, _COMMAND, (y, age, held, u))
        if hit is not None:
            ex.log_sample((t, sp, y, u, self.v_last, ff, p, i, d, period, late, 0.0, 0, 2))
            return True, self._trip(hit)
        v = self._write(u)
        done = self.clock.now()
        miss = int(done > deadline + self.dt_ns)
        self.missed += miss
        self.lateness.append(late)
        self.periods.append(period)
        ex.log_sample((t, sp, y, u, v, ff, p, i, d, period, late, (done - wake) * 1e-9, miss, 0))
        self.wake_prev = wake
        ex.latest = (t, sp, y, v, "running")
        self.k += 1
        return False, None

    def _step(self, sp: float, y: float) -> tuple[float, float, float, float, float]:
        step, k, extra = self.ex.step, self.k, self.ff_extra
        if extra is None:
            if k == 0:  # bumpless start on the first reading: the first command is the safe level
                step.start(sp, y, self.v_last)
            return step.step(sp, y)
        fx = extra[min(k, len(extra) - 1)]
        if k == 0:
            step.start(sp, y, self.v_last, extra[0])
        return step.step(sp, y, fx)

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
        logged = ex.samples_logged
        k0 = logged - 1  # the last sample logged
        t0 = self.t0 if logged else self.clock.now()
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
                ex.log_event("ramp_failed", t, detail=f"{type(exc).__name__}: {exc}")
                try:
                    ex.backend.write_voltage(s.safe_V)
                    v = s.safe_V
                except Exception:
                    pass
                return v, t
            if self.heartbeat is not None:
                self.heartbeat()
            ex.log_sample((t, math.nan, y, math.nan, v, *_NANS, dt, 0.0, 0.0, 0, 1))
            ex.latest = (t, math.nan, y, v, "ramping down")
        return v, t
