"""The rig executor: the one controller step at a fixed rate against a backend, behind the interlocks.

Each cycle ``k`` has the absolute deadline ``t0 + k / rate``: the loop waits for it, reads the
force, tests the interlocks, computes the command with the controller step of
``models/controller`` (compiled, :mod:`piezopreload.rig.compiled`), passes it through the
voltage clamp and slew limit, and writes it. A cycle that ends after the next deadline is
*missed*; the next one starts at once (no catching up by skipping samples: the controller's
discrete time stays the rig's).

The interlocks are one table (:mod:`piezopreload.rig.interlocks`), tested in its order by both
loops: the sensor (NaN, stale, beyond its range), the force (above ``force_max_N``, below the
bolt preload less its margin), the *stall* (the output held longer than the stall limit the
session derives from the plant, :mod:`piezopreload.rig.stall`; a shorter hold longer than two
periods is counted and logged as a stall, not tripped) and a non-finite command. A signal
(SIGINT, SIGTERM or :meth:`Executor.stop`) and an exception stop a run too.

Two loops run this cycle. The native loop (:mod:`piezopreload.rig.native_run`) runs it in a C
thread with absolute deadlines, the interlocks and the ramp down inside the thread, while
Python supervises (starts, switches gain sets, drains the samples to the log, stops). The
Python loop (:mod:`piezopreload.rig.pyloop`) runs it in the interpreter. :class:`Executor`
holds what both share (the controller, the backend, the reference, the limits, the events and
the log, the requests from other threads), and the loops reach it through its methods only (a
switch taken, a sample or an event logged, the stop asked for read, the run closed); it takes
the native loop where it can
(``loop="auto"``: a C compiler, the compiled step, a backend the loop can call directly: the
simulated rig or a :class:`~piezopreload.rig.backends.CLibraryBackend`) and the Python loop
otherwise (a Python plug-in backend, ``step="numpy"``). For a simulated run both give the same
samples and events.

``realtime=False`` runs the cycles back to back on a virtual clock (:mod:`piezopreload.rig.clock`)
that moves only to the next deadline and by an injected stall: deadlines and stalls are judged
on it, the same on every host.

A stop ramps the voltage linearly from where it is to ``safe_V`` over ``ramp_s`` (still at the
loop's rate), disarms the backend, records the event (its cause, its words and the voltage
held at the trip) and ends the run with status ``tripped``. A run that reaches the end of its
reference ramps down the same way and ends ``completed``.
"""

from __future__ import annotations

import contextlib
import math
import signal
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from piezopreload.artifacts.rigrun import RunOutcome, RunTiming, TripRecord
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import Controller
from piezopreload.rig import native_loop
from piezopreload.rig.backends import Backend, FaultInjector, native_backend
from piezopreload.rig.compiled import controller_step, step_library
from piezopreload.rig.interlocks import STALL_REPORT_PERIODS, TRIP_CAUSES, Safety, Trip, trip_detail
from piezopreload.rig.native_run import NativeRun
from piezopreload.rig.outcome import RunResult, StallLog
from piezopreload.rig.pyloop import PythonLoop
from piezopreload.rig.runlog import RunLog

__all__ = ["Safety", "Executor", "RunResult", "StopRequest", "Trip", "TRIP_CAUSES", "trip_detail"]


@dataclass(frozen=True)
class StopRequest:
    """A stop asked of a run (:meth:`Executor.stop`): the reason in words, and whether it ends the run tripped."""

    reason: str
    trip: bool


class Executor:
    """Runs ``controller`` on ``backend`` over ``reference``; see the module docstring.

    ``realtime=False`` runs the cycles back to back on a virtual clock (a simulated backend gives
    the same run, faster). ``hold=True`` keeps the reference's last level after its end until
    :meth:`stop` (a served rig). ``log`` receives every sample and event. ``ff_extra_V`` (one
    value per sample of the reference, as in :func:`~piezopreload.models.closedloop.simulate`)
    is added to the feedforward before the clamp: a learned signal played back, on either loop.
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
        self._ref: tuple[float, ...] = tuple(reference.at(np.arange(n) * self.dt).tolist())
        self._extra: tuple[float, ...] | None = None
        if ff_extra_V is not None:  # a learned or previewed feedforward, added by the step itself
            extra = np.asarray(ff_extra_V, float)
            if extra.shape != (n,) or not np.all(np.isfinite(extra)):
                raise ValueError(f"ff_extra_V needs one finite value per sample of the reference ({n}), got shape "
                                 f"{extra.shape}")
            self._extra = tuple(extra.tolist())
        self.step = controller_step(controller, prefer=step)
        self._pending: tuple[Controller, dict[str, Any]] | None = None
        self._stop: StopRequest | None = None
        self._rows = 0  # samples logged in this run: the ramp down follows the last
        self.events: list[dict[str, Any]] = []
        self.stalls = StallLog(lambda t_s, held_s: self.log_event("stall", t_s, persist=False, held_s=held_s))
        #: the latest cycle: (t_s, setpoint_N, force_N, voltage_V, state) for a server to show
        self.latest: tuple[float, float, float, float, str] = (0.0, reference.levels_N[0], math.nan, 0.0, "idle")
        self._native: Any = None
        self._switch_lock = threading.Lock()
        self._switch_info: list[dict[str, Any]] = []
        self._unsaved = False  # an event the loop recorded and left to another thread to write
        self.loop, self.loop_reason = self._choose_loop(loop)

    @property
    def stall_report_s(self) -> float:
        """A hold longer than this is a stall (counted and logged): :data:`STALL_REPORT_PERIODS` periods."""
        return STALL_REPORT_PERIODS * self.dt

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
            if native_backend(inner, 1) is None:
                why = (f"the backend '{self.backend.name}' is a Python backend (the loop would "
                       "call into the interpreter)")
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
    def prepare(self, controller: Controller) -> None:
        """Compile what the loop needs to run ``controller`` (its step and, for the native loop, its start), here
        and not in the loop's cycle: a controller of another structure (a gain schedule where there was none,
        another feedforward) has code of its own. A ValueError says why it cannot run."""
        if controller.model == self.controller.model or self.step.kind != "c":
            return
        try:
            step_library(controller.model)
            if self.loop == "native":
                native_loop.start_library(controller.model)
        except native_loop.native.NativeBuildError as exc:
            raise ValueError(f"the rig cannot compile the new controller's step ({exc})") from None

    def request_switch(self, controller: Controller, info: dict[str, Any]) -> None:
        """Switch to ``controller`` between two cycles, bumplessly; ``info`` goes into the event, with the cycle the
        loop was at when asked (``requested_cycle``: the next to start) beside the one that took it (``cycle``)."""
        if not math.isclose(controller.dt_s, self.dt, rel_tol=1e-12):
            raise ValueError(f"the new controller samples every {controller.dt_s} s, the loop every {self.dt} s")
        self.prepare(controller)
        with self._switch_lock:
            if self._native is not None:
                info = {**info, "requested_cycle": self._native.cycles}
                self._switch_info.append(info)
                try:
                    self._native.switch(controller)
                except ValueError:
                    self._switch_info.pop()
                    raise
                self.controller = controller
                return
            t, state = self.latest[0], self.latest[4]
            self._pending = (controller, {**info, "requested_cycle": 0 if state == "idle" else round(t / self.dt) + 1})

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
        self._stop = StopRequest(reason, trip)  # one assignment: a loop reads the reason and the trip together
        if self._native is not None:
            self._native.stop(trip)

    def save_events(self) -> None:
        """Write the events the loop recorded without writing them (a gain switch on the Python loop) to the run log's
        sidecar; for the thread that serves the rig, never the loop's."""
        if self._unsaved and self.log is not None:
            self._unsaved = False
            self.log.save()

    def record(self, kind: str, **detail: Any) -> None:
        """An event from outside the loop (a refused push, an operator's note), at the loop's last time."""
        self.log_event(kind, self.latest[0], **detail)

    def run(self) -> RunResult:
        """The run, start to end; never raises for what happens on the rig (that is a trip)."""
        return NativeRun(self).run() if self.loop == "native" else PythonLoop(self).run()

    # ---- what the loops call (rig/pyloop.py, rig/native_run.py): the run's state stays here ---------------
    @property
    def setpoints_N(self) -> tuple[float, ...]:
        """The reference at each sample of the run (a held run keeps the last after the end)."""
        return self._ref

    @property
    def ff_extra_V(self) -> tuple[float, ...] | None:
        """The external feedforward at each sample (a learned signal played back); None: there is none."""
        return self._extra

    @property
    def stop_request(self) -> StopRequest | None:
        """The stop asked for by :meth:`stop` (its reason and whether it trips); None while the run may go on."""
        return self._stop

    @property
    def samples_logged(self) -> int:
        """How many samples this run has logged: a ramp down's samples follow the last of them."""
        return self._rows

    @contextlib.contextmanager
    def signal_handlers(self) -> Iterator[bool]:
        """A run's span: SIGINT and SIGTERM stop it (:meth:`stop`, the signal's name as the reason), and the handlers
        found before come back at its end.

        Yields
        ------
        bool
            Whether the handlers were set: only the main thread can set them, a run in another thread leaves them.
        """
        previous: dict[signal.Signals, Any] = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                previous[sig] = signal.signal(sig, lambda signum, frame: self.stop(signal.Signals(signum).name))
        try:
            yield bool(previous)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def take_switch(self, t_s: float, cycle: int) -> None:
        """The Python loop between two cycles: the switch asked for (:meth:`request_switch`), if any, taken now.

        The step takes the new controller over bumplessly; the event is recorded for the serving thread to write
        (:meth:`save_events`), not written here: a sidecar's rewrite has no place inside a cycle.

        Parameters
        ----------
        t_s, cycle
            The loop's time and the cycle about to run.
        """
        if self._pending is None:
            return
        new, info = self._pending
        self.step.switch(new)
        self.controller = new  # before the switch stops pending: a server shows the new hash with the new gains
        self._pending = None
        self.log_event("gains_switched", t_s, persist=False, cycle=cycle, **info)
        self._unsaved = True

    def attach_native(self, loop: native_loop.NativeLoop) -> None:
        """The native loop about to start: switches and stops go to it from now on, and a switch asked for before
        goes in with its start.

        Parameters
        ----------
        loop
            The configured loop, not started yet.
        """
        with self._switch_lock:
            self._native = loop
            if self._pending is not None:
                new, info = self._pending
                self._pending = None
                self._switch_info.append(info)
                loop.switch(new)

    def detach_native(self) -> None:
        """The native loop has ended: a switch asked for now waits for a run that takes it."""
        with self._switch_lock:
            self._native = None

    def native_switched(self, t_s: float) -> None:
        """The native loop took the oldest switch asked of it at ``t_s``: its event, with what it was asked with.

        Parameters
        ----------
        t_s
            The loop's time at the switch.
        """
        with self._switch_lock:
            info = self._switch_info.pop(0) if self._switch_info else {}
        self.log_event("gains_switched", t_s, cycle=round(t_s / self.dt), **info)

    def log_event(self, kind: str, t_s: float, *, persist: bool = True, **detail: Any) -> None:
        """An event of the run at the loop's time ``t_s``, kept in :attr:`events` and written to the log.

        Parameters
        ----------
        kind
            What happened (``armed``, ``interlock``, ``ramped_down``...).
        t_s
            When, on the run's timeline.
        persist
            Write the log's sidecar now (False inside a cycle: the next write takes it along).
        **detail
            The event's fields.
        """
        ev = {"event": kind, "t_s": round(t_s, 9), **detail}
        self.events.append(ev)
        if self.log is not None:
            self.log.event(ev, write=persist)

    def log_sample(self, row: tuple) -> None:
        """One sample of the Python loop, written to the run log as it goes.

        Parameters
        ----------
        row
            The log's columns (:mod:`piezopreload.rig.runlog`).
        """
        self._rows += 1
        if self.log is not None:
            self.log.sample(row, time.monotonic())

    def log_samples(self, rows: np.ndarray) -> None:
        """The samples the native loop's ring held, written to the run log with one time of writing.

        Parameters
        ----------
        rows
            One row of the log's columns per sample.
        """
        self._rows += rows.shape[0]
        if self.log is not None:
            now = time.monotonic()
            for row in rows.tolist():
                self.log.sample(tuple(row), now)

    def record_trip(self, trip: Trip) -> None:
        """The interlock event of ``trip``: its cause, its words and the voltage held.

        Parameters
        ----------
        trip
            What stopped the run.
        """
        self.log_event("interlock", trip.t_s, cause=trip.cause, detail=trip.detail, voltage_V=trip.voltage_V)

    def finish(self, trip: Trip | None, cycles: int, timing: RunTiming, clamped: int) -> RunResult:
        """The run's result, also closing its log with the same numbers (both loops end here).

        Parameters
        ----------
        trip
            What stopped the run; None: it completed.
        cycles, timing, clamped
            The cycles run, their timing and how many were clamped.

        Returns
        -------
        RunResult
            The run's outcome, events included.
        """
        result = RunResult("tripped" if trip else "completed", trip, cycles, timing, clamped, self.step.kind,
                           None if self.log is None else str(self.log.csv_path),
                           None if self.log is None else str(self.log.json_path), list(self.events))
        if self.log is not None:
            record = None if trip is None else TripRecord(trip.cause, trip.detail, trip.t_s, trip.voltage_V)
            self.log.close(result.status, RunOutcome(cycles, timing, clamped, record, controller_step=self.step.kind))
        return result
