"""The rig executor: the one controller step at a fixed rate against a backend, behind interlocks.

Each cycle ``k`` has the absolute deadline ``t0 + k / rate`` on the monotonic clock: the loop
sleeps to just before it and spins the rest, reads the force, checks it, computes the command
with the controller step of ``models/controller`` (compiled, :mod:`piezopreload.rig.compiled`),
passes it through the voltage clamp and slew limit, and writes it. A cycle that ends after the
next deadline is *missed*; the next one starts at once (no catching up by skipping samples:
the controller's discrete time stays the rig's).

Interlocks (:class:`Safety`). The clamp and the slew limit shape every command. These stop
the run:

* ``force_high`` / ``force_low``: the force above ``force_max_N``, or below the bolt preload
  minus ``force_low_margin_N`` (a loose nut, a broken stack, a lost sensor);
* ``sensor_nan``, ``sensor_stale`` (the sample older than ``stale_after_s``),
  ``sensor_range`` (a reading at or beyond the sensor's range);
* ``deadline``: ``missed_streak`` missed deadlines in a row (by default 5 on the native loop;
  50 on the Python loop, a 50 ms hold of the voltage at 1 kHz, because the interpreter
  stalls a thread for a few ms now and then, which a shorter streak would turn into stops);
* ``signal``: SIGINT or SIGTERM (or :meth:`Executor.stop`);
* ``command``: a non-finite command; ``exception``: anything raised in the loop.

Two loops run this cycle. The native loop (:mod:`piezopreload.rig.native_loop`) runs it in a
C thread with absolute deadlines, the interlocks and the ramp down inside the thread, while
Python supervises (starts, switches gain sets, drains the samples to the log, stops). The
Python loop below runs it in the interpreter; :class:`Executor` takes the native loop where it
can (``loop="auto"``: a C compiler, the compiled step, a backend the loop can call directly:
the simulated rig or a :class:`~piezopreload.rig.backends.CLibraryBackend`) and the Python
loop otherwise (a Python plug-in backend, ``step="numpy"``). Both take their limits from the
one :class:`Safety` and give the same samples for a simulated run.

Each cycle toggles the backend's ``heartbeat()`` where it has one (an external watchdog's).

A stop ramps the voltage linearly from where it is to ``safe_V`` over ``ramp_s`` (still at the
loop's rate), disarms the backend, records the event and its cause, and ends the run with status
``tripped``. A run that reaches the end of its reference ramps down the same way and ends
``completed``.
"""

from __future__ import annotations

import gc
import math
import signal
import threading
import time
import traceback
from array import array
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import Controller
from piezopreload.rig import native_loop
from piezopreload.rig.backends import Backend, FaultInjector
from piezopreload.rig.compiled import controller_step
from piezopreload.rig.native_loop import NativeLoop
from piezopreload.rig.runlog import RunLog

__all__ = ["Safety", "Executor", "RunResult", "Trip", "TRIP_CAUSES", "NATIVE_STREAK", "PYTHON_STREAK", "trip_detail"]

#: the missed-deadline streak limits when :attr:`Safety.missed_streak` is None
NATIVE_STREAK = 5
PYTHON_STREAK = 50

TRIP_CAUSES = ("force_high", "force_low", "sensor_nan", "sensor_stale", "sensor_range", "deadline", "signal",
               "command", "exception")

_SPIN_S = 2e-4  # sleep to this much before a deadline, then spin: time.sleep alone overshoots ~60 us


@dataclass(frozen=True)
class Safety:
    """Interlock settings; the defaults suit the paper's rig (forces 25-110 N, three P-888.91 stacks)."""

    v_min_V: float = 0.0
    v_max_V: float = 110.0
    slew_V_per_s: float = 20_000.0
    force_max_N: float = 150.0
    bolt_preload_N: float = 25.0
    force_low_margin_N: float = 10.0
    sensor_min_N: float = -1000.0
    sensor_max_N: float = 1000.0
    stale_after_s: float = 0.01
    #: missed deadlines in a row that stop the run; None: :data:`NATIVE_STREAK` on the native loop,
    #: :data:`PYTHON_STREAK` on the Python loop
    missed_streak: int | None = None
    ramp_s: float = 0.5
    safe_V: float = 0.0

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if name == "missed_streak" and value is None:
                continue
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise ValueError(f"safety.{name} must be a finite number, got {value!r}")
        if not self.v_min_V < self.v_max_V:
            raise ValueError(f"safety needs v_min_V < v_max_V, got {self.v_min_V} and {self.v_max_V}")
        if not self.v_min_V <= self.safe_V <= self.v_max_V:
            raise ValueError(f"safety.safe_V must lie in {self.v_min_V}..{self.v_max_V} V, got {self.safe_V}")
        for name in ("slew_V_per_s", "stale_after_s", "ramp_s", "force_low_margin_N"):
            if getattr(self, name) <= 0:
                raise ValueError(f"safety.{name} must be > 0, got {getattr(self, name)}")
        if self.missed_streak is not None and (self.missed_streak != int(self.missed_streak) or self.missed_streak < 1):
            raise ValueError(f"safety.missed_streak must be >= 1, got {self.missed_streak}")
        if not self.sensor_min_N < self.bolt_preload_N - self.force_low_margin_N < self.force_max_N <= self.sensor_max_N:
            raise ValueError("safety needs sensor_min_N < bolt_preload_N - force_low_margin_N < force_max_N <= "
                             "sensor_max_N")

    def to_dict(self) -> dict[str, float | None]:
        return asdict(self)

    def streak_limit(self, loop: str) -> int:
        """The missed-deadline streak that stops a run on ``loop`` (``native`` or ``python``)."""
        if self.missed_streak is not None:
            return int(self.missed_streak)
        return NATIVE_STREAK if loop == "native" else PYTHON_STREAK

    @property
    def force_low_N(self) -> float:
        """The force below which ``force_low`` trips: the bolt preload less the margin."""
        return self.bolt_preload_N - self.force_low_margin_N


def trip_detail(cause: str, value: float, safety: Safety, streak_limit: int = 0) -> str:
    """The words of an interlock's trip for the number that tripped it (one text for both loops)."""
    s = safety
    if cause == "sensor_nan":
        return "the force sensor reads NaN"
    if cause == "sensor_stale":
        return f"the force sample is {value:.4f} s old (limit {s.stale_after_s} s)"
    if cause == "sensor_range":
        return (f"the force reads {value:.6g} N, at or beyond the sensor's range "
                f"{s.sensor_min_N:g}..{s.sensor_max_N:g} N")
    if cause == "force_high":
        return f"the force reads {value:.6g} N, above the limit {s.force_max_N:g} N"
    if cause == "force_low":
        return f"the force reads {value:.6g} N, below the bolt preload less the margin ({s.force_low_N:g} N)"
    if cause == "deadline":
        return f"{int(value)} deadlines missed in a row (limit {streak_limit})"
    if cause == "command":
        return f"the controller's command is {value}"
    return str(value)


@dataclass(frozen=True)
class Trip:
    cause: str
    detail: str
    t_s: float


@dataclass
class RunResult:
    """How a run ended: ``status`` ``completed`` or ``tripped`` (with its :class:`Trip`), the timing, the log."""

    status: str
    trip: Trip | None
    cycles: int
    timing: dict[str, Any]
    clamped_cycles: int
    controller_step: str
    csv_path: str | None
    json_path: str | None
    events: list[dict[str, Any]] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.status == "completed"


class Executor:
    """Runs ``controller`` on ``backend`` over ``reference``; see the module docstring.

    ``realtime=False`` runs the cycles back to back (a simulated backend gives the same run,
    faster; deadlines are not checked). ``hold=True`` keeps the reference's last level after
    its end until :meth:`stop` (a served rig). ``log`` receives every sample and event.
    ``ff_extra_V`` (one value per sample of the reference, as in
    :func:`~piezopreload.models.closedloop.simulate`) is added to the feedforward before the
    clamp: a learned signal played back, on either loop (the compiled step takes it as an input;
    the native loop reads it at its sample counter, as it reads the reference).
    ``loop``: ``native``, ``python`` or ``auto`` (native where it can run, see the module
    docstring; :attr:`loop` says which one will, :attr:`loop_reason` why not native).
    """

    def __init__(self, controller: Controller, backend: Backend, reference: Reference, safety: Safety, *,
                 realtime: bool = True, hold: bool = False, log: RunLog | None = None, step: str = "c",
                 ff_extra_V: Any = None, loop: str = "auto") -> None:
        if loop not in ("auto", "native", "python"):
            raise ValueError(f"loop must be 'auto', 'native' or 'python', got {loop!r}")
        self.controller = controller
        self.backend = backend
        self.reference = reference
        self.safety = safety
        self.realtime = bool(realtime)
        self.hold = bool(hold)
        self.log = log
        self.dt = float(controller.dt_s)
        n = int(round(reference.duration_s / self.dt)) + 1
        self._ref = reference.at(np.arange(n) * self.dt).tolist()
        self._extra: list[float] | None = None
        if ff_extra_V is not None:  # a learned or previewed feedforward, added by the step itself
            extra = np.asarray(ff_extra_V, float)
            if extra.shape != (n,) or not np.all(np.isfinite(extra)):
                raise ValueError(f"ff_extra_V needs one finite value per sample of the reference ({n}), got shape "
                                 f"{extra.shape}")
            self._extra = extra.tolist()
        self.step = controller_step(controller, prefer=step)
        self._pending: tuple[Controller, dict[str, Any]] | None = None
        self._stop: str | None = None
        self._stop_trips = True
        self._rows = 0  # samples logged in this run: the ramp down follows the last
        self.events: list[dict[str, Any]] = []
        #: the latest cycle: (t_s, setpoint_N, force_N, voltage_V, state) for a server to show
        self.latest: tuple[float, float, float, float, str] = (0.0, reference.levels_N[0], math.nan, 0.0, "idle")
        self._native: NativeLoop | None = None
        self._switch_lock = threading.Lock()
        self._switch_info: list[dict[str, Any]] = []
        self.loop, self.loop_reason = self._choose_loop(loop)

    def _choose_loop(self, want: str) -> tuple[str, str]:
        if want == "python":
            return "python", "asked for"
        why = ""
        if self.step.kind != "c":
            why = "the controller step is not compiled (no C compiler, or numpy asked for)"
        elif not native_loop.available():
            why = "the native loop could not be built (no working C compiler)"
        else:
            inner = self.backend.inner if isinstance(self.backend, FaultInjector) else self.backend
            if not callable(getattr(inner, "native_backend", None)) or inner.native_backend(1) is None:
                why = f"the backend '{self.backend.name}' is a Python backend (the loop would call into the interpreter)"
            elif isinstance(self.backend, FaultInjector) and len(self.backend.faults) > native_loop.MAX_FAULTS:
                why = f"more than {native_loop.MAX_FAULTS} injected faults"
        if not why:
            try:  # built now, not when the run starts (a served rig answers clients meanwhile)
                native_loop.start_library(self.controller.model)
                return "native", ""
            except native_loop.native.NativeBuildError as exc:
                why = f"the controller's start could not be built: {exc}"
        if want == "native":
            raise ValueError(f"the native loop cannot run: {why}")
        return "python", why

    # ---- called from other threads ------------------------------------------------------------
    def request_switch(self, controller: Controller, info: dict[str, Any]) -> None:
        """Switch to ``controller`` between two cycles, bumplessly; ``info`` goes into the event."""
        if not math.isclose(controller.dt_s, self.dt, rel_tol=1e-12):
            raise ValueError(f"the new controller samples every {controller.dt_s} s, the loop every {self.dt} s")
        with self._switch_lock:
            if self._native is not None:
                self._switch_info.append(info)
                try:
                    self._native.switch(controller)
                except ValueError:
                    self._switch_info.pop()
                    raise
                self.controller = controller
                return
            self._pending = (controller, info)

    @property
    def switch_pending(self) -> bool:
        """A requested switch the loop has not made yet."""
        if self._native is not None:
            return self._native.switch_pending
        return self._pending is not None

    def stop(self, reason: str, *, trip: bool = True) -> None:
        """Ask the loop to ramp down and end; safe from any thread.

        ``trip=True`` (a signal, an operator's stop) ends the run ``tripped`` with cause
        ``signal``; ``trip=False`` (a served run's set duration) ends it ``completed``.
        """
        self._stop_trips = trip
        self._stop = reason
        if self._native is not None:
            self._native.stop(trip)

    def record(self, kind: str, **detail: Any) -> None:
        """An event from outside the loop (a refused push, an operator's note), at the loop's last time."""
        self._event(kind, self.latest[0], **detail)

    # ---- the loop -------------------------------------------------------------------------------
    def _event(self, kind: str, t_s: float, **detail: Any) -> None:
        ev = {"event": kind, "t_s": round(t_s, 9), **detail}
        self.events.append(ev)
        if self.log is not None:
            self.log.event(ev)

    def _check(self, force: float, sample_t: float, t: float) -> Trip | None:
        s = self.safety
        if math.isnan(force):
            cause, value = "sensor_nan", force
        elif t - sample_t > s.stale_after_s:
            cause, value = "sensor_stale", t - sample_t
        elif not s.sensor_min_N < force < s.sensor_max_N:
            cause, value = "sensor_range", force
        elif force > s.force_max_N:
            cause, value = "force_high", force
        elif force < s.force_low_N:
            cause, value = "force_low", force
        else:
            return None
        return Trip(cause, trip_detail(cause, value, s), t)

    def _wait(self, deadline: float) -> float:
        now = time.perf_counter()
        if deadline - now > _SPIN_S:
            time.sleep(deadline - now - _SPIN_S)
        while (now := time.perf_counter()) < deadline:
            pass
        return now

    def run(self) -> RunResult:
        """The run, start to end; never raises for what happens on the rig (that is a trip)."""
        if self.loop == "native":
            return self._run_native()
        return self._run_python()

    def _run_python(self) -> RunResult:
        handlers = self._install_signal_handlers()
        gc_was_enabled = gc.isenabled()
        gc.collect()
        gc.disable()  # the loop makes no reference cycles; a full collection would stall it for ms
        s, dt, ref = self.safety, self.dt, self._ref
        streak_limit = s.streak_limit("python")
        heartbeat = getattr(self.backend, "heartbeat", None)
        n_ref = len(ref)
        lateness, periods = array("d"), array("d")
        missed = streak = clamped = 0
        v_last = s.safe_V
        trip: Trip | None = None
        k = 0
        t = 0.0
        t0 = wake_prev = time.perf_counter()
        try:
            self.backend.arm()
            self._event("armed", 0.0, backend=self.backend.name, controller_step=self.step.kind, loop="python",
                        loop_reason=self.loop_reason)
            t0 = wake_prev = time.perf_counter()
            while True:
                if k >= n_ref and not self.hold:
                    break
                t = k * dt
                sp = ref[k] if k < n_ref else ref[-1]
                deadline = t0 + t
                wake = self._wait(deadline) if self.realtime else time.perf_counter()
                if self._pending is not None:
                    new, info = self._pending
                    self._pending = None
                    self.step.switch(new)
                    self.controller = new
                    self._event("gains_switched", t, **info)
                if self._stop is not None:  # this cycle is the stop's: logged, no reading, no command
                    self._log_row(t, sp, math.nan, math.nan, v_last, (math.nan,) * 4,
                                  wake - wake_prev, wake - deadline if self.realtime else 0.0, 0.0, 0, 2)
                    if self._stop_trips:
                        trip = Trip("signal", self._stop, t)
                    else:
                        self._event("stopped", t, reason=self._stop)
                    break
                reading = self.backend.read_force(t)
                y = float(reading.force_N)
                trip = self._check(y, reading.t_s, t)
                if trip is not None:
                    self._log_row(t, sp, y, math.nan, v_last, (math.nan,) * 4, wake - wake_prev,
                                  wake - deadline if self.realtime else 0.0, 0.0, 0, 2)
                    break
                if k == 0:  # bumpless start on the first reading: the first command is the safe level
                    if self._extra is None:
                        self.step.start(sp, y, v_last)
                    else:
                        self.step.start(sp, y, v_last, self._extra[0])
                if self._extra is None:
                    u, p, i, d, ff = self.step.step(sp, y)
                else:
                    u, p, i, d, ff = self.step.step(sp, y, self._extra[min(k, n_ref - 1)])
                if not math.isfinite(u):
                    trip = Trip("command", f"the controller's command is {u}", t)
                    self._log_row(t, sp, y, u, v_last, (ff, p, i, d), wake - wake_prev,
                                  wake - deadline if self.realtime else 0.0, 0.0, 0, 2)
                    break
                v = min(max(u, s.v_min_V), s.v_max_V)
                slew = s.slew_V_per_s * dt
                v = min(max(v, v_last - slew), v_last + slew)
                if v != u:
                    clamped += 1
                self.backend.write_voltage(v)
                if heartbeat is not None:
                    heartbeat()
                v_last = v
                done = time.perf_counter()
                late = wake - deadline if self.realtime else 0.0
                miss = int(self.realtime and done > deadline + dt)
                missed += miss
                streak = streak + 1 if miss else 0
                lateness.append(late)
                periods.append(wake - wake_prev)
                self._log_row(t, sp, y, u, v, (ff, p, i, d), wake - wake_prev, late, done - wake, miss, 0)
                wake_prev = wake
                self.latest = (t, sp, y, v, "running")
                k += 1
                if streak >= streak_limit:
                    trip = Trip("deadline", trip_detail("deadline", streak, s, streak_limit), t)
                    break
        except Exception as exc:  # anything in the loop: stop the rig first, explain after
            trip = Trip("exception", f"{type(exc).__name__}: {exc}", t)
            self._log_row(t, math.nan, math.nan, math.nan, v_last, (math.nan,) * 4, 0.0, 0.0, 0.0, 0, 2)
            self._event("traceback", t, text="".join(traceback.format_exception(exc))[-4000:])
        finally:
            try:
                if trip is not None:
                    self._event("interlock", trip.t_s, cause=trip.cause, detail=trip.detail, voltage_V=v_last)
                v_end, t_end = self._ramp_down(v_last, t0)
                self._event("ramped_down", t_end, voltage_V=v_end)
            finally:
                try:
                    self.backend.disarm()
                finally:
                    self._restore_signal_handlers(handlers)
                    if gc_was_enabled:
                        gc.enable()
        self.latest = (t, self.latest[1], self.latest[2], s.safe_V, "tripped" if trip else "completed")
        self._event("disarmed", t_end)
        timing = _timing(lateness, periods, missed, dt, self.realtime)
        timing.update(loop="python", missed_streak_limit=streak_limit, lost_samples=0)
        return self._finish(trip, k, timing, clamped)

    def _finish(self, trip: Trip | None, cycles: int, timing: dict[str, Any], clamped: int) -> RunResult:
        """The run's result, also closing its log with the same numbers (both loops end here)."""
        result = RunResult("tripped" if trip else "completed", trip, cycles, timing, clamped, self.step.kind,
                           None if self.log is None else str(self.log.csv_path),
                           None if self.log is None else str(self.log.json_path), list(self.events))
        if self.log is not None:
            self.log.close(result.status, {"cycles": cycles, "timing": timing, "clamped_cycles": clamped,
                                           "trip": None if trip is None else asdict(trip)})
        return result

    # ---- the native loop's supervisor -----------------------------------------------------------
    def _native_setup(self) -> NativeLoop:
        s, dt = self.safety, self.dt
        limits = {"v_min": s.v_min_V, "v_max": s.v_max_V, "slew_V_per_s": s.slew_V_per_s, "force_max": s.force_max_N,
                  "force_low": s.force_low_N, "sensor_min": s.sensor_min_N, "sensor_max": s.sensor_max_N,
                  "stale_after_s": s.stale_after_s, "ramp_s": s.ramp_s, "safe_V": s.safe_V,
                  "missed_streak": s.streak_limit("native")}
        faults = []
        inner = self.backend
        if isinstance(inner, FaultInjector):
            faults = [(native_loop.FAULT_CODES[f.kind], f.at_s, f.value, f.duration_s) for f in inner.faults]
            inner = inner.inner
        # noise draws for the whole finite run (control, stop, ramp); a held run reuses them cyclically
        n_noise = len(self._ref) + int(math.ceil(s.ramp_s / dt)) + 16
        if self.hold:
            n_noise = max(n_noise, 1 << 18)
        backend = inner.native_backend(n_noise)  # type: ignore[attr-defined]
        return NativeLoop(self.controller, np.asarray(self._ref), limits, backend, realtime=self.realtime,
                          hold=self.hold, faults=faults, step_fn=getattr(self.step, "_fn", None),
                          ff_extra=None if self._extra is None else np.asarray(self._extra))

    def _run_native(self) -> RunResult:
        s, dt = self.safety, self.dt
        streak_limit = s.streak_limit("native")
        handlers = self._install_signal_handlers()
        lateness, periods = array("d"), array("d")
        trip: Trip | None = None
        status = None
        loop: NativeLoop | None = None
        armed_here = False
        switches_seen = 0
        t_last = 0.0
        try:
            loop = self._native_setup()
            loop.lock_memory()
            if loop.backend_kind == 0:  # the simulated rig is armed here; a C library's arm runs in the loop's thread
                self.backend.arm()
                armed_here = True
            with self._switch_lock:
                self._native = loop
                if self._pending is not None:  # asked for before the start: the start takes it
                    new, info = self._pending
                    self._pending = None
                    self._switch_info.append(info)
                    loop.switch(new)
            loop.start(catch_signals=bool(handlers))
            self._event("armed", 0.0, backend=self.backend.name, controller_step=self.step.kind, loop="native",
                        **loop.realtime_report)
            if self._stop is not None:
                loop.stop(self._stop_trips)
            poll = 0.01
            while True:
                finished = loop.finished
                rows = loop.drain()
                if rows.shape[0]:
                    self._take_rows(rows, lateness, periods)
                    t_last = float(rows[-1, 0])
                n_sw = loop.switches
                while switches_seen < n_sw:
                    switches_seen += 1
                    with self._switch_lock:
                        info = self._switch_info.pop(0) if self._switch_info else {}
                    self._event("gains_switched", loop.switch_t, **info)
                t, sp, y, v, mode = loop.latest
                self.latest = (t, sp, y, v, "running" if mode == 0 else "ramping down")
                if finished:
                    break
                time.sleep(poll)
            status = self._collect(loop, lateness, periods)
            if status.trip_cause:
                cause = TRIP_CAUSES[status.trip_cause - 1]
                if cause == "signal":
                    detail = self._stop or signal.Signals(loop.stop_signal).name
                elif cause == "exception":
                    where = native_loop.EXCEPTION_WHERE.get(status.trip_where, "the loop")
                    detail = (f"injected fault at t = {status.trip_t:.3f} s: the backend failed"
                              if status.trip_value == -1000 else f"{where} returned {status.trip_value:g}")
                else:
                    detail = trip_detail(cause, status.trip_value, s, streak_limit)
                trip = Trip(cause, detail, status.trip_t)
            elif loop.stop_requested == 2:
                self._event("stopped", status.trip_t, reason=self._stop)
        except Exception as exc:  # the loop never started (or the supervisor failed): the rig is safe, say why
            if loop is not None:
                loop.stop(True)
                status = self._collect(loop, lateness, periods)
            trip = Trip("exception", f"{type(exc).__name__}: {exc}", t_last)
            self._event("traceback", t_last, text="".join(traceback.format_exception(exc))[-4000:])
        finally:
            with self._switch_lock:
                self._native = None
            try:
                if armed_here:
                    self.backend.disarm()
            finally:
                self._restore_signal_handlers(handlers)
        t_end = status.t_end if status is not None else t_last
        v_end = status.v_end if status is not None else s.safe_V
        if trip is not None:
            self._event("interlock", trip.t_s, cause=trip.cause, detail=trip.detail, voltage_V=v_end)
        if status is not None and status.ramp_failed:
            self._event("ramp_failed", status.ramp_failed_t, detail="the backend's write_voltage failed in the ramp")
        self._event("ramped_down", t_end, voltage_V=v_end)
        self._event("disarmed", t_end)
        self.latest = (t_end, self.latest[1], self.latest[2], s.safe_V, "tripped" if trip else "completed")
        cycles = status.cycles if status is not None else 0
        missed = status.missed if status is not None else 0
        timing = _timing(lateness, periods, missed, dt, self.realtime)
        timing.update(loop="native", missed_streak_limit=streak_limit, lost_samples=status.lost if status else 0,
                      **(loop.realtime_report if loop is not None else {}))
        clamped = status.clamped if status is not None else 0
        return self._finish(trip, cycles, timing, clamped)

    def _collect(self, loop: Any, lateness: array, periods: array) -> Any:
        """Join the native loop, take the samples still in its ring into the log, and return its status."""
        loop.join()
        rows = loop.drain()
        if rows.shape[0]:
            self._take_rows(rows, lateness, periods)
        return loop.status()

    def _take_rows(self, rows: np.ndarray, lateness: array, periods: array) -> None:
        control = rows[:, 13] == 0
        lateness.extend(rows[control, 10].tolist())
        periods.extend(rows[control, 9].tolist())
        self._rows += rows.shape[0]
        if self.log is not None:
            now = time.monotonic()
            for row in rows.tolist():
                self.log.sample(tuple(row), now)

    def _ramp_down(self, v_from: float, t0: float) -> tuple[float, float]:
        """From ``v_from`` to the safe level in a straight line over ``ramp_s``, at the loop's rate.

        The ramp's samples follow the last one logged, whichever way the loop ended. Returns the
        voltage reached and the time of the ramp's last sample.
        """
        s, dt = self.safety, self.dt
        n = 0 if v_from == s.safe_V else max(1, int(math.ceil(s.ramp_s / dt)))
        k0 = self._rows - 1  # the last sample logged
        v, t = v_from, max(k0, 0) * dt
        for j in range(1, n + 1):
            t = (k0 + j) * dt
            if self.realtime:
                self._wait(t0 + t)
            v = s.safe_V if j == n else v_from + (s.safe_V - v_from) * j / n
            try:
                y = float(self.backend.read_force(t).force_N)
            except Exception:
                y = math.nan
            try:
                self.backend.write_voltage(v)
            except Exception as exc:  # the backend is gone: one last try at the safe level, then disarm
                self._event("ramp_failed", t, detail=f"{type(exc).__name__}: {exc}")
                try:
                    self.backend.write_voltage(s.safe_V)
                    v = s.safe_V
                except Exception:
                    pass
                return v, t
            heartbeat = getattr(self.backend, "heartbeat", None)
            if heartbeat is not None:
                heartbeat()
            self._log_row(t, math.nan, y, math.nan, v, (math.nan,) * 4, dt, 0.0, 0.0, 0, 1)
            self.latest = (t, math.nan, y, v, "ramping down")
        return v, t

    def _log_row(self, t: float, sp: float, y: float, u: float, v: float, terms: tuple, period: float,
                 late: float, compute: float, miss: int, mode: int) -> None:
        self._rows += 1
        if self.log is not None:
            self.log.sample((t, sp, y, u, v, *terms, period, late, compute, miss, mode), time.monotonic())

    def _install_signal_handlers(self) -> dict[int, Any]:
        if threading.current_thread() is not threading.main_thread():
            return {}
        previous = {}
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda signum, frame: self.stop(signal.Signals(signum).name))
        return previous

    @staticmethod
    def _restore_signal_handlers(previous: dict[int, Any]) -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _timing(lateness: array, periods: array, missed: int, dt: float, realtime: bool) -> dict[str, Any]:
    late = np.frombuffer(lateness, dtype=float) if len(lateness) else np.zeros(1)
    per = np.frombuffer(periods, dtype=float)[1:] if len(periods) > 1 else np.full(1, dt)
    return {
        "realtime": realtime, "rate_Hz": 1.0 / dt, "cycles": len(lateness), "missed_deadlines": int(missed),
        "lateness_p50_s": float(np.percentile(late, 50)), "lateness_p99_s": float(np.percentile(late, 99)),
        "lateness_max_s": float(late.max()), "period_mean_s": float(per.mean()), "period_std_s": float(per.std()),
        "period_max_s": float(per.max()),
    }

