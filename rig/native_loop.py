"""The rig's fixed-rate loop in native code: a C thread the Python supervisor starts, feeds and drains.

The cycle (``native_loop.c`` beside this file, compiled once by :mod:`piezopreload.core.native`
and cached by hash) runs in a POSIX thread outside the interpreter. Each cycle ``k`` sleeps to
the absolute deadline ``t0 + k dt`` (``clock_nanosleep`` with ``TIMER_ABSTIME`` on
``CLOCK_MONOTONIC``, the timer slack set to 1 ns), reads the force, checks it against the
interlock rows of :mod:`piezopreload.rig.interlocks` (the table both loops test), calls the compiled controller step
(``pp_rig_step``, :mod:`.compiled`), clamps and slew-limits the command, writes it, toggles the backend's heartbeat and
puts the sample into a single-producer/single-consumer ring buffer. A stop (an interlock, SIGINT or SIGTERM caught in C,
:meth:`NativeLoop.stop`) ramps the voltage to the safe level at the loop's rate and disarms, all inside the thread.

Where the system permits, the thread runs under ``SCHED_FIFO`` and the process's memory is
locked (``mlockall(MCL_CURRENT)``); where it does not, the loop runs anyway and
:attr:`NativeLoop.realtime_report` says what was refused (``EPERM`` without
``CAP_SYS_NICE`` or an ``rtprio`` limit, ``ENOMEM``/``EPERM`` for ``RLIMIT_MEMLOCK``).

The supervisor never runs inside a cycle's deadline: it drains the ring (to the run log), polls
the loop's status and writes a new gain set's parameter vector into the buffer the loop is
not running, then flips the active index (one atomic store); the loop takes it at its next
cycle boundary and starts the new controller bumplessly at that cycle's setpoint and reading
with the last command written (the integral takes up the difference, as at the run's start;
a feedforward's operators start from rest at the setpoint). A sample the ring has no room for
is counted in :attr:`NativeLoop.lost` (a run reports it; it should be 0); when the run is not
in real time the loop waits for the supervisor instead of dropping.

Backends the loop calls directly:

* the simulated rig (:class:`~piezopreload.rig.backends.SimBackend`): the compiled plant
  step (``pp_plant_read``/``pp_plant_write``), the noise drawn beforehand from the backend's
  seed (the same draws as the Python loop's, so a run is the same on both loops), its DAQ's
  output and heartbeat in shared memory for the watchdog;
* a hardware library with the C ABI of :class:`~piezopreload.rig.backends.CLibraryBackend`.

A Python plug-in backend runs on the Python loop (:class:`~piezopreload.rig.executor.Executor`
falls back to it), since every call into Python from the thread would take the interpreter's
lock and with it the interpreter's pauses (see ``docs/rig.md``).
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from piezopreload.core import native
from piezopreload.models.controller import Controller, ControllerModel, controller_functions
from piezopreload.rig import interlocks
from piezopreload.rig.backends import FAULT_KINDS, NativeBackend
from piezopreload.rig.compiled import step_library

__all__ = ["NativeLoop", "loop_library", "start_library", "available", "COLS", "FAULT_CODES", "EXCEPTION_WHERE",
           "LoopStatus", "probe", "time_step", "source"]

COLS = 14
MAX_FAULTS = 16
MAX_INTERLOCKS = max(16, len(interlocks.INTERLOCKS))
#: the stall ring's length: the supervisor drains it every 10 ms, the loop writes one entry per stall
STALL_ROWS = 4096
#: each fault kind's code in the C source: numbered from 1 in the order of
#: :data:`~piezopreload.rig.backends.FAULT_KINDS` (the C source gets them as ``F_<KIND>`` defines, :func:`source`)
FAULT_CODES = {kind: code for code, kind in enumerate(FAULT_KINDS, start=1)}
#: what failed when the loop trips with cause ``exception``
EXCEPTION_WHERE = {1: "the backend's arm", 2: "the backend's read_force", 3: "the backend's write_voltage",
                   4: "the compiled controller step", 5: "the compiled controller start", 6: "an injected fault"}

_SOURCE = Path(__file__).with_name("native_loop.c")
_FN = ctypes.c_void_p


class _Fault(ctypes.Structure):
    _fields_ = [("kind", ctypes.c_int32), ("fired", ctypes.c_int32), ("at_s", ctypes.c_double),
                ("value", ctypes.c_double), ("duration_s", ctypes.c_double)]


_D, _I32, _I64, _P = ctypes.c_double, ctypes.c_int32, ctypes.c_int64, ctypes.c_void_p


class _Interlock(ctypes.Structure):
    """``pp_interlock``: one row of :func:`piezopreload.rig.interlocks.rows`."""

    _fields_ = [("stage", _I32), ("quantity", _I32), ("test", _I32), ("cause", _I32), ("lo", _D), ("hi", _D)]


class _Loop(ctypes.Structure):
    """The prefix of ``pp_loop`` in native_loop.c, field for field (the rest is the thread's)."""

    _fields_ = [
        ("dt_s", _D), ("n_ref", _I64), ("ref", _P), ("extra", _P), ("hold", _I32), ("realtime", _I32),
        ("v_min", _D), ("v_max", _D), ("slew_V_per_s", _D), ("ramp_s", _D), ("safe_V", _D), ("stall_report_s", _D),
        ("interlocks", _Interlock * MAX_INTERLOCKS), ("n_interlocks", _I32),
        ("step", _FN * 2), ("start", _FN * 2), ("state", _P * 2), ("params", _P * 2),
        ("backend", _I32),
        ("plant_read", _FN), ("plant_write", _FN), ("plant_state", _P), ("plant_params", _P),
        ("noise", _P), ("n_noise", _I64),
        ("hw_arm", _FN), ("hw_read", _FN), ("hw_write", _FN), ("hw_disarm", _FN), ("hw_heartbeat", _FN),
        ("heartbeat", _P), ("daq_V", _P),
        ("faults", _Fault * MAX_FAULTS), ("n_faults", _I32),
        ("want_fifo", _I32), ("fifo_priority", _I32), ("want_mlock", _I32), ("spin_ns", _I32),
        ("ring", _P), ("ring_rows", _I64), ("stalls", _P), ("stall_rows", _I64),
        ("head", _I64), ("tail", _I64), ("lost", _I64), ("n_stalls", _I64),
        ("active", _I32), ("taken", _I32),
        ("stop", _I32), ("stop_signal", _I32),
        ("started", _I32), ("finished", _I32), ("fifo_errno", _I32), ("mlock_errno", _I32),
        ("cycles", _I64), ("missed", _I64), ("clamped", _I64), ("switches", _I64),
        ("switch_t", _D), ("held_max", _D),
        ("trip_cause", _I32), ("trip_where", _I32), ("trip_t", _D), ("trip_value", _D), ("trip_v", _D),
        ("v_end", _D), ("t_end", _D), ("ramp_failed", _I32), ("ramp_failed_t", _D),
        ("latest_t", _D), ("latest_sp", _D), ("latest_y", _D), ("latest_v", _D), ("latest_mode", _I32),
    ]


class _Probe(ctypes.Structure):
    """``pp_probe`` in native_loop.c: the host check's bare thread."""

    _fields_ = [("dt_s", _D), ("n", _I64), ("want_fifo", _I32), ("fifo_priority", _I32), ("want_mlock", _I32),
                ("spin_ns", _I32), ("late_ns", _P), ("fifo_errno", _I32), ("mlock_errno", _I32)]


def source() -> str:
    """The loop's C source as it is built: the interlock table's and the fault kinds' codes, then ``native_loop.c``."""
    faults = "".join(f"#define F_{kind.upper()} {code}\n" for kind, code in FAULT_CODES.items())
    return (interlocks.c_defines() + "/* generated from rig/backends.py: the fault kinds' codes */\n" + faults
            + _SOURCE.read_text(encoding="utf-8"))


def loop_library() -> ctypes.CDLL:
    """The loop's shared library (built once per source and compiler, cached);
    :class:`native.NativeBuildError` if not."""
    lib = native.load(native.build("pp_loop", source(), (*native.FLAGS, "-pthread")))
    for name, res, args in (("pp_loop_start", ctypes.c_int, [_P]), ("pp_loop_join", ctypes.c_int, [_P]),
                            ("pp_loop_drain", ctypes.c_int64, [_P, _P, ctypes.c_int64]),
                            ("pp_loop_stalls", ctypes.c_int64, [_P]),
                            ("pp_loop_switch", None, [_P, ctypes.c_int32]),
                            ("pp_loop_stop", None, [_P, ctypes.c_int32]), ("pp_loop_sizeof", ctypes.c_int64, []),
                            ("pp_loop_catch_signals", ctypes.c_int, [_P]),
                            ("pp_loop_release_signals", ctypes.c_int, []), ("pp_loop_lock_memory", ctypes.c_int, [_P]),
                            ("pp_probe_run", ctypes.c_int, [_P]), ("pp_probe_sizeof", ctypes.c_int64, []),
                            ("pp_time_step", ctypes.c_int, [_FN, _D, _D, _P, _P, ctypes.c_int64, _P])):
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args
    if lib.pp_loop_sizeof() < ctypes.sizeof(_Loop) or lib.pp_probe_sizeof() != ctypes.sizeof(_Probe):
        raise native.NativeBuildError("native_loop.c and native_loop.py disagree on the loop's layout")
    return lib


_START = """
/* piezopreload: the controller's bumpless start, a state whose first output at (setpoint, pv) is u0 */
int pp_rig_start(double setpoint, double pv, double u0, double ff_extra, const double* params, double* state) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int iw[{iw}];
  casadi_real w[{w}];
  arg[0] = &setpoint; arg[1] = &pv; arg[2] = &u0; arg[3] = &ff_extra; arg[4] = params;
  res[0] = state;
  return {name}(arg, res, iw, w, 0);
}}
"""


_STARTS: dict[Any, ctypes.CDLL] = {}


def start_library(model: ControllerModel) -> ctypes.CDLL:
    """``pp_rig_start``: :meth:`ControllerModel.start` compiled, for controllers of ``model``'s structure
    (generated once per structure in a process, from the disk cache after the first build)."""
    try:
        return _STARTS[model]
    except (KeyError, TypeError):
        pass
    lib = _start_library(model)
    with contextlib.suppress(TypeError):
        _STARTS[model] = lib
    return lib


def _start_library(model: ControllerModel) -> ctypes.CDLL:
    init, _ = controller_functions(model, prefix="pp_rig_start", ff_extra=True)
    source = native.generate([init], "pp_rig_start") + _START.format(
        sz_arg=max(int(init.sz_arg()), 5), sz_res=max(int(init.sz_res()), 1), iw=max(int(init.sz_iw()), 1),
        w=max(int(init.sz_w()), 1), name=init.name())
    return native.library("pp_rig_start", source)


def available() -> bool:
    """Whether the native loop can run here (a working C compiler, not forced to numpy)."""
    if not native.enabled():
        return False
    try:
        loop_library()
    except native.NativeBuildError:
        return False
    return True


def _address(fn: Any) -> int:
    return int(ctypes.cast(fn, ctypes.c_void_p).value or 0)


def _errno_text(code: int, what: str) -> str:
    if code == -1:
        return f"{what}: not asked"
    if code == 0:
        return f"{what}: yes"
    name = errno.errorcode.get(code, str(code))
    return f"{what}: refused ({name}: {os.strerror(code)}); the loop runs without it"


@dataclass
class LoopStatus:
    """What the loop reports at its end (``trip_v``: the voltage held when it tripped)."""

    cycles: int
    missed: int
    clamped: int
    lost: int
    switches: int
    trip_cause: int
    trip_where: int
    trip_t: float
    trip_value: float
    trip_v: float
    v_end: float
    t_end: float
    ramp_failed: bool
    ramp_failed_t: float
    stalls: int
    held_max_s: float


class NativeLoop:
    """One run of the native loop: configure, :meth:`start`, :meth:`drain` until :attr:`finished`, :meth:`join`.

    ``controller``'s step and start are compiled for its structure; ``reference`` is the
    setpoint per sample; ``safety`` the interlocks' limits (the rows of
    :func:`piezopreload.rig.interlocks.rows` and the command's shaping); ``backend`` a dict
    (:class:`~piezopreload.rig.backends.NativeBackend`) made by the backend's ``native_backend()``. ``ring_s``
    seconds of samples fit the ring.
    ``step_fn``: the loaded ``pp_rig_step`` of ``controller``'s structure (a
    :class:`~piezopreload.rig.compiled.CompiledStep`'s), else it is loaded here. ``ff_extra``:
    the external feedforward per sample of ``reference`` (a learned signal), read by the loop
    at the sample counter as the setpoint is (held at its last value past the end); None: 0.
    ``realtime=False`` runs the cycles back to back on a virtual clock: a cycle waits no time,
    an injected delay advances the clock by its value, so a stall is the same on every host.
    """

    def __init__(self, controller: Controller, reference: np.ndarray, safety: interlocks.Safety,
                 backend: NativeBackend,
                 *, realtime: bool, hold: bool,
                 faults: list[tuple[int, float, float, float]] = (),  # type: ignore[assignment]
                 ring_s: float = 30.0, fifo_priority: int = 80, spin_us: float = 0.0, step_fn: Any = None,
                 ff_extra: np.ndarray | None = None) -> None:
        self._lib = loop_library()
        self.controller = controller
        self._model = controller.model
        #: each slot's controller structure, its step and start, and the state and parameters they use
        self._slots: list[tuple[ControllerModel, Any, Any, np.ndarray, np.ndarray] | None] = [None, None]
        self._keep: list[Any] = []  # every buffer the thread points into lives as long as this object
        self._mem = ctypes.create_string_buffer(int(self._lib.pp_loop_sizeof()))
        L = _Loop.from_buffer(self._mem)
        self._L = L
        self._ref = np.ascontiguousarray(reference, dtype=float)
        if self._ref.size < 1:
            raise ValueError("the reference has no samples")
        L.dt_s, L.n_ref, L.ref = controller.dt_s, self._ref.size, self._ref.ctypes.data
        self._extra = None
        if ff_extra is not None:
            self._extra = np.ascontiguousarray(ff_extra, dtype=float)
            if self._extra.shape != self._ref.shape or not np.all(np.isfinite(self._extra)):
                raise ValueError(f"ff_extra needs one finite value per sample of the reference ({self._ref.size}), "
                                 f"got shape {self._extra.shape}")
            L.extra = self._extra.ctypes.data
        L.hold, L.realtime = int(hold), int(realtime)
        self._set_limits(safety)
        for slot in (0, 1):
            self._fill(slot, controller, step_fn)
        self._set_backend(backend, faults)
        L.want_fifo = L.want_mlock = int(realtime)
        L.fifo_priority, L.spin_ns = int(fifo_priority), int(spin_us * 1e3)
        rows = max(1024, int(ring_s / controller.dt_s))
        self._ring = np.zeros((rows, COLS))
        self._out = np.zeros((rows, COLS))
        L.ring, L.ring_rows = self._ring.ctypes.data, rows
        self._stalls = np.zeros((STALL_ROWS, 2))
        L.stalls, L.stall_rows = self._stalls.ctypes.data, STALL_ROWS
        self._stalls_seen = 0
        self._addr = ctypes.addressof(L)
        L.mlock_errno = L.fifo_errno = -1
        self._started = False
        self._signals = False

    def _fill(self, slot: int, controller: Controller, step_fn: Any = None) -> None:
        """Put ``controller`` into ``slot`` (one the loop does not run): its parameters and, for another structure,
        its step and start (compiled now, or taken from the cache) and a state of its size."""
        model, L = controller.model, self._L
        current = self._slots[slot]
        if current is None or current[0] != model:
            step = step_library(model).pp_rig_step if step_fn is None else step_fn
            start = start_library(model).pp_rig_start
            state, params = np.zeros(model.state.size), np.zeros(model.params.size)
            self._slots[slot] = current = (model, step, start, state, params)
            L.step[slot], L.start[slot] = _address(step), _address(start)
            L.state[slot], L.params[slot] = state.ctypes.data, params.ctypes.data
        current[4][:] = controller.parameter_vector()

    def _set_limits(self, safety: interlocks.Safety) -> None:
        """The interlock table's rows and the command's shaping, from ``safety``."""
        L = self._L
        L.v_min, L.v_max, L.slew_V_per_s = safety.v_min_V, safety.v_max_V, safety.slew_V_per_s
        L.ramp_s, L.safe_V = safety.ramp_s, safety.safe_V
        L.stall_report_s = interlocks.STALL_REPORT_PERIODS * self.controller.dt_s
        table = interlocks.rows(safety)
        for j, row in enumerate(table):
            L.interlocks[j] = _Interlock(*row)
        L.n_interlocks = len(table)

    def _set_backend(self, backend: NativeBackend, faults: Any) -> None:
        """The backend's entry points and buffers, and the faults to inject."""
        L = self._L
        L.backend = int(backend["kind"])
        for key, value in backend.items():
            if key != "kind":
                setattr(L, key, value)
        self._keep.append(backend)
        if len(faults) > MAX_FAULTS:
            raise ValueError(f"at most {MAX_FAULTS} faults on the native loop, got {len(faults)}")
        for j, (kind, at_s, value, duration_s) in enumerate(faults):
            L.faults[j] = _Fault(kind, 0, at_s, value, duration_s)
        L.n_faults = len(faults)

    # ---- the supervisor's side ----------------------------------------------------------------
    def lock_memory(self) -> None:
        """``mlockall(MCL_CURRENT)`` where permitted (a run in real time); call before arming, it takes a while."""
        self._lib.pp_loop_lock_memory(self._addr)

    def start(self, catch_signals: bool = False) -> None:
        """Start the thread; ``catch_signals`` (main thread only) lets SIGINT/SIGTERM stop it in C."""
        if catch_signals:
            self._signals = self._lib.pp_loop_catch_signals(self._addr) == 0
        rc = self._lib.pp_loop_start(self._addr)
        if rc:
            self._release()
            raise OSError(rc, f"cannot start the loop's thread: {os.strerror(rc)}")
        self._started = True

    def _release(self) -> None:
        if self._signals:
            self._lib.pp_loop_release_signals()
            self._signals = False

    @property
    def backend_kind(self) -> int:
        """0: the simulated plant, 1: a C-ABI library."""
        return int(self._L.backend)

    @property
    def finished(self) -> bool:
        return bool(self._L.finished)

    def drain(self) -> np.ndarray:
        """The samples the loop has put in the ring since the last drain, as rows of the run log's columns."""
        n = int(self._lib.pp_loop_drain(self._addr, self._out.ctypes.data, self._out.shape[0]))
        return self._out[:n].copy()

    def stalls(self) -> tuple[np.ndarray, int]:
        """The stalls recorded since the last call, rows of ``(t_s, held_s)``, and how many of them the ring
        no longer held (overwritten before they were read)."""
        n = int(self._lib.pp_loop_stalls(self._addr))
        new = n - self._stalls_seen
        kept = min(new, STALL_ROWS)
        index = np.arange(n - kept, n) % STALL_ROWS
        self._stalls_seen = n
        return self._stalls[index].copy(), new - kept

    def join(self) -> None:
        if self._started:
            self._lib.pp_loop_join(self._addr)
            self._started = False
        self._release()

    def stop(self, trip: bool) -> None:
        """Ask the loop to end at its next cycle: ``trip`` as a signal does, else completed."""
        self._lib.pp_loop_stop(self._addr, 1 if trip else 2)

    @property
    def stop_requested(self) -> int:
        return int(self._L.stop)

    @property
    def stop_signal(self) -> int:
        return int(self._L.stop_signal)

    def switch(self, controller: Controller) -> None:
        """Write ``controller`` into the idle slot (its parameters; for another structure, its compiled step and
        start and a state of its size) and flip the index; the loop takes it at a cycle boundary and starts it
        bumplessly from the last command written."""
        if self.switch_pending:
            raise ValueError("the previous gain set has not been taken by the loop yet")
        idle = 1 - int(self._L.taken)
        self._fill(idle, controller)
        self.controller = controller
        self._lib.pp_loop_switch(self._addr, idle)

    @property
    def cycles(self) -> int:
        """The cycles the loop has completed (the next to start is this one's index)."""
        return int(self._L.cycles)

    @property
    def switch_pending(self) -> bool:
        return int(self._L.active) != int(self._L.taken)

    @property
    def switches(self) -> int:
        return int(self._L.switches)

    @property
    def switch_t(self) -> float:
        return float(self._L.switch_t)

    @property
    def latest(self) -> tuple[float, float, float, float, int]:
        L = self._L
        return float(L.latest_t), float(L.latest_sp), float(L.latest_y), float(L.latest_v), int(L.latest_mode)

    @property
    def lost(self) -> int:
        return int(self._L.lost)

    @property
    def realtime_report(self) -> dict[str, str]:
        """Whether SCHED_FIFO and locked memory were granted, in words."""
        return {"sched_fifo": _errno_text(int(self._L.fifo_errno), "SCHED_FIFO"),
                "memory_locked": _errno_text(int(self._L.mlock_errno), "mlockall")}

    def status(self) -> LoopStatus:
        L = self._L
        return LoopStatus(int(L.cycles), int(L.missed), int(L.clamped), int(L.lost), int(L.switches),
                          int(L.trip_cause), int(L.trip_where), float(L.trip_t), float(L.trip_value), float(L.trip_v),
                          float(L.v_end), float(L.t_end), bool(L.ramp_failed), float(L.ramp_failed_t),
                          int(L.n_stalls), float(L.held_max))


def probe(dt_s: float, n: int, *, fifo_priority: int = 80, spin_us: float = 0.0,
          realtime: bool = True) -> tuple[np.ndarray, dict[str, str]]:
    """The host check's bare thread: ``n`` wake-ups every ``dt_s`` on absolute deadlines, waited for as the loop
    waits (the same priority, memory locking, timer slack and spin); their lateness in seconds and what the
    system granted (:attr:`NativeLoop.realtime_report`'s words)."""
    lib = loop_library()
    late = np.zeros(int(n), dtype=np.int64)
    P = _Probe(float(dt_s), int(n), int(realtime), int(fifo_priority), int(realtime), int(spin_us * 1e3),
               late.ctypes.data, -1, -1)
    rc = lib.pp_probe_run(ctypes.byref(P))
    if rc:
        raise OSError(rc, f"cannot start the check's thread: {os.strerror(rc)}")
    return late * 1e-9, {"sched_fifo": _errno_text(int(P.fifo_errno), "SCHED_FIFO"),
                         "memory_locked": _errno_text(int(P.mlock_errno), "mlockall")}


def time_step(controller: Controller, n: int = 2000) -> np.ndarray:
    """The compiled controller step's compute time (s) over ``n`` calls from C, each timed by the monotonic clock."""
    lib = loop_library()
    model = controller.model
    step = step_library(model).pp_rig_step
    state = np.zeros(model.state.size)
    params = np.ascontiguousarray(controller.parameter_vector(), dtype=float)
    ns = np.zeros(int(n), dtype=np.int64)
    if lib.pp_time_step(_address(step), 50.0, 50.0, state.ctypes.data, params.ctypes.data, int(n), ns.ctypes.data):
        raise RuntimeError("the compiled controller step failed while being timed")
    return ns * 1e-9
