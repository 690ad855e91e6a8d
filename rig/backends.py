"""Rig backends: what the executor's loop talks to, one small interface for every rig.

A backend arms, reads the force, writes the voltage and disarms::

    class Backend(Protocol):
        name: str
        def arm(self) -> None: ...                      # ready to write; the stacks at 0 V
        def read_force(self, t_s: float) -> Reading: ...  # the latest force sample
        def write_voltage(self, volts: float) -> None: ...  # the command for this sample
        def disarm(self) -> None: ...                   # outputs off, safe to leave

A backend that simulates its plant may say so with a class attribute ``simulated = True``;
only such a backend may run back to back (``rig run --fast``), any other runs in real time.

``t_s`` is the cycle's time on the run's timeline (seconds since the start, the nominal tick);
a :class:`Reading` says when its sample was taken on the same timeline, so the executor can
tell a fresh sample from a stale one. The executor never writes a voltage the interlocks have
not passed, and calls ``disarm`` on every way out, so a backend need not police either.

The simulated reference rig (:class:`SimBackend`, name ``sim``) is built in. Hardware backends
are plug-ins: a package declares an entry point in the group ``piezopreload.rig_backends``
whose object, called with the user's ``--backend-option KEY=VALUE`` pairs as a dict of
strings, returns a backend. A minimal plug-in for a DAQ card::

    # mydaq/backend.py
    from piezopreload.rig.backends import Reading

    class DaqBackend:
        name = "mydaq"
        def __init__(self, options):
            self.device = options.get("device", "Dev1")
        def arm(self): ...          # open the card, write 0 V, enable the amplifier
        def read_force(self, t_s):  # one A/D conversion of the load cell
            return Reading(force_N=..., t_s=t_s)
        def write_voltage(self, volts): ...
        def disarm(self): ...       # write 0 V, disable the amplifier, close the card

    # pyproject.toml of the plug-in
    [project.entry-points."piezopreload.rig_backends"]
    mydaq = "mydaq.backend:DaqBackend"

after which ``piezopreload rig run gains.json --backend mydaq --backend-option device=Dev2``
runs on it. :class:`FaultInjector` wraps any backend to test the interlocks (fire drills).
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Any, Protocol, TypedDict

import numpy as np

from piezopreload.core.errors import InputError
from piezopreload.models.actuator import Plant, Rig
from piezopreload.rig import watchdog
from piezopreload.rig.compiled import PlantStep
from piezopreload.rig.watchdog import SharedDAQ

__all__ = ["Reading", "Backend", "SimBackend", "CLibraryBackend", "Fault", "FaultInjector", "FAULT_KINDS",
           "ENTRY_POINT_GROUP", "BackendError", "InjectedFault", "injected_failure", "available_backends",
           "open_backend", "parse_fault", "native_backend", "NativeBackend"]

ENTRY_POINT_GROUP = "piezopreload.rig_backends"


class BackendError(InputError):
    """A backend that cannot be opened (not installed, bad options): exit code 2."""


@dataclass(frozen=True)
class Reading:
    """A force sample and the time (s, on the run's timeline) it was taken."""

    force_N: float
    t_s: float


class Backend(Protocol):
    name: str

    def arm(self) -> None: ...

    def read_force(self, t_s: float) -> Reading: ...

    def write_voltage(self, volts: float) -> None: ...

    def disarm(self) -> None: ...


class NativeBackend(TypedDict, total=False):
    """What the native loop needs to run a backend itself, by the names of its C struct's fields (``kind`` 0: the
    simulated rig's compiled plant step, its state and parameters, the noise drawn beforehand and the DAQ's shared
    words; ``kind`` 1: a C library's entry points). ``_keep`` holds the buffers the addresses point into."""

    kind: int
    plant_read: int | None
    plant_write: int | None
    plant_state: int
    plant_params: int
    noise: int
    n_noise: int
    _keep: Any
    heartbeat: int
    daq_V: int
    hw_arm: int | None
    hw_read: int | None
    hw_write: int | None
    hw_disarm: int | None
    hw_heartbeat: int | None


def native_backend(backend: Backend, n_noise: int) -> NativeBackend | None:
    """What the native loop needs to run ``backend`` itself (its ``native_backend(n_noise)``, which a backend may
    offer: the built-in ones do), or None where it offers none and the loop would call into the interpreter."""
    offer = getattr(backend, "native_backend", None)
    return offer(n_noise) if callable(offer) else None


class SimBackend:
    """The simulated reference rig of ``models/actuator``, one sample per write.

    Each :meth:`write_voltage` advances the plant by one sample period, whatever the wall
    clock did, so a run is the same whether the executor paces it in real time or runs it as
    fast as it can; for the same plant, gains and seed it is :func:`models.closedloop.simulate`.

    With ``watchdog_s`` the backend also models the rig's DAQ and watchdog relay
    (:mod:`piezopreload.rig.watchdog`): every write is held in a shared mapping at ``daq_path``
    (a temporary file by default), the loop's :meth:`heartbeat` counts there, and a watchdog
    process opens the relay (0 V at the stacks) when the heartbeat stops for ``watchdog_s``,
    also when the supervising process has been killed.
    """

    name = "sim"
    #: a simulation may run back to back (``rig run --fast``); a backend without this runs in real time
    simulated = True

    def __init__(self, plant: Plant, seed: int = 0, *, watchdog_s: float | None = None,
                 daq_path: str | None = None) -> None:
        if plant.batch_shape:
            raise ValueError("the simulated backend runs one plant, not a batch")
        if watchdog_s is not None and not (math.isfinite(watchdog_s) and 0.002 <= watchdog_s <= 60.0):
            raise ValueError(f"watchdog_s must be 0.002..60 s, got {watchdog_s!r}")
        self.rig = Rig(plant)
        self.seed = int(seed)
        self.plant = PlantStep(plant)  # the plant step of models/actuator, compiled where a compiler works
        self._rng = np.random.default_rng(self.seed)
        self.watchdog_s = watchdog_s
        self.daq: SharedDAQ | None = None
        self._watchdog: subprocess.Popen | None = None
        self._own_path = False
        if watchdog_s is not None:
            if daq_path is None:
                fd, daq_path = tempfile.mkstemp(prefix="piezopreload-daq-",
                                                dir="/dev/shm" if os.path.isdir("/dev/shm") else None)
                os.close(fd)
                self._own_path = True
            self.daq = SharedDAQ(daq_path, create=True)

    @property
    def sample_period_s(self) -> float:
        return self.rig.dt_s

    def _start_watchdog(self) -> None:
        if self.daq is None or self.watchdog_s is None:
            return
        if self._watchdog is not None and self._watchdog.poll() is None:
            return
        self.daq.set("ready", 0)
        self._watchdog = subprocess.Popen([sys.executable, str(Path(watchdog.__file__)), self.daq.path,
                                           repr(float(self.watchdog_s))], start_new_session=True,
                                          stdin=subprocess.DEVNULL)
        t_end = time.monotonic() + 10.0
        while not self.daq.get("ready"):
            if time.monotonic() > t_end or self._watchdog.poll() is not None:
                raise BackendError(f"the simulated watchdog did not start (exit {self._watchdog.poll()})")
            time.sleep(0.005)

    def arm(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        self.plant.reset()
        if self.daq is not None:
            self.daq.set("output_V", 0.0)
            self.daq.set("relay_open", 0)  # the relay closes on arming (a watchdog relay's reset)
            self._start_watchdog()
            self.daq.set("armed", 1)

    def read_force(self, t_s: float) -> Reading:
        return Reading(self.plant.read(float(self._rng.standard_normal()))[1], t_s)

    def write_voltage(self, volts: float) -> None:
        self.plant.write(volts)
        if self.daq is not None:
            self.daq.set("output_V", volts)

    def heartbeat(self) -> None:
        """The loop is alive (called once per cycle): the watchdog's heartbeat counts up."""
        if self.daq is not None:
            self.daq.set("heartbeat", self.daq.get("heartbeat") + 1)

    @property
    def amplifier_V(self) -> float:
        """The amplifier's output now (the stacks' voltage), for checks a real rig makes with a probe."""
        return self.plant.amplifier_V

    @property
    def force_N(self) -> float:
        """The true force now (what the sensor reads before noise and quantisation)."""
        return self.plant.read(0.0)[0]

    def disarm(self) -> None:
        if self.daq is not None:
            self.daq.set("output_V", 0.0)
            self.daq.set("armed", 0)

    def native_backend(self, n_noise: int) -> NativeBackend | None:
        """What the native loop needs to run this plant itself: the compiled plant step's entry points,
        its state and parameters, ``n_noise`` draws of the backend's noise (the Python loop's draws) and
        the DAQ's shared words; None where the plant step is not compiled."""
        if self.plant.kind != "c":
            return None
        noise = np.random.default_rng(self.seed).standard_normal(int(n_noise))
        read, write, state, params = self.plant.native_addresses()
        out = NativeBackend(kind=0, plant_read=read, plant_write=write, plant_state=state, plant_params=params,
                            noise=noise.ctypes.data, n_noise=noise.size, _keep=noise)
        if self.daq is not None:
            base = ctypes.addressof(ctypes.c_char.from_buffer(self.daq.mm))
            out["heartbeat"] = base + watchdog.FIELDS["heartbeat"][0]
            out["daq_V"] = base + watchdog.FIELDS["output_V"][0]
        return out

    def close(self) -> None:
        """Stop the watchdog (the relay stays as it is) and remove a DAQ file this backend made."""
        if self._watchdog is not None and self.daq is not None:
            self.daq.set("quit", 1)
            try:
                self._watchdog.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self._watchdog.kill()
            self._watchdog = None
        if self._own_path and self.daq is not None:
            with contextlib.suppress(OSError):
                os.unlink(self.daq.path)


class CLibraryBackend:
    """A hardware backend as a shared library with a small C ABI, which the native loop calls directly.

    The library exports (0 on success, anything else stops the run with cause ``exception``)::

        int arm(void);                                  /* ready to write; the stacks at 0 V */
        int read_force(double t_s, double* force_N, double* sample_t_s);
        int write_voltage(double volts);
        int disarm(void);                               /* outputs off, safe to leave */
        int heartbeat(int level);                       /* optional: the watchdog's digital output */

    ``t_s`` and ``sample_t_s`` are on the run's timeline, as :class:`Reading`'s. The functions
    are called from the loop's thread only, one at a time, inside the cycle: they must not
    block longer than the cycle allows. ``heartbeat`` is called once per cycle with 0 and 1 in
    turn (a square wave at half the loop's rate for a watchdog relay; see ``docs/rig.md``).
    The Python loop calls the same functions through ctypes.
    """

    def __init__(self, path: str, name: str | None = None) -> None:
        try:
            self.lib = ctypes.CDLL(str(path))
        except OSError as exc:
            raise BackendError(f"--backend-option library={path}: cannot load it: {exc}") from None
        missing = [f for f in ("arm", "read_force", "write_voltage", "disarm") if not hasattr(self.lib, f)]
        if missing:
            raise BackendError(f"--backend-option library={path}: the library lacks '{missing[0]}' of the C ABI "
                               "(arm, read_force, write_voltage, disarm; "
                               "see piezopreload.rig.backends.CLibraryBackend)")
        self.path = str(path)
        self.name = name or f"clib:{Path(path).name}"
        lib = self.lib
        lib.arm.restype = lib.disarm.restype = lib.read_force.restype = lib.write_voltage.restype = ctypes.c_int
        lib.arm.argtypes = lib.disarm.argtypes = []
        lib.read_force.argtypes = [ctypes.c_double, ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_double)]
        lib.write_voltage.argtypes = [ctypes.c_double]
        self._heartbeat = getattr(lib, "heartbeat", None) if hasattr(lib, "heartbeat") else None
        if self._heartbeat is not None:
            self._heartbeat.restype, self._heartbeat.argtypes = ctypes.c_int, [ctypes.c_int]
        self._level = 0
        self._f, self._t = ctypes.c_double(), ctypes.c_double()

    def _check(self, rc: int, what: str) -> None:
        if rc:
            raise RuntimeError(f"the backend's {what} returned {rc}")

    def arm(self) -> None:
        self._check(self.lib.arm(), "arm")

    def read_force(self, t_s: float) -> Reading:
        self._check(self.lib.read_force(t_s, ctypes.byref(self._f), ctypes.byref(self._t)), "read_force")
        return Reading(self._f.value, self._t.value)

    def write_voltage(self, volts: float) -> None:
        self._check(self.lib.write_voltage(volts), "write_voltage")

    def heartbeat(self) -> None:
        if self._heartbeat is not None:
            self._heartbeat(self._level)
            self._level ^= 1

    def disarm(self) -> None:
        self._check(self.lib.disarm(), "disarm")

    def native_backend(self, n_noise: int) -> NativeBackend:
        """The library's entry points for the native loop (which calls arm and disarm itself)."""
        def address(fn: Any) -> int | None:
            return None if fn is None else ctypes.cast(fn, ctypes.c_void_p).value
        return NativeBackend(kind=1, hw_arm=address(self.lib.arm), hw_read=address(self.lib.read_force),
                             hw_write=address(self.lib.write_voltage), hw_disarm=address(self.lib.disarm),
                             hw_heartbeat=address(self._heartbeat))


class InjectedFault(RuntimeError):
    """The backend failure a ``raise`` fault injects (a fire drill, not a bug: no traceback is logged)."""


def injected_failure(t_s: float) -> str:
    """The words of an injected backend failure at ``t_s`` (both loops say it so)."""
    return f"injected fault at t = {t_s:.3f} s: the backend failed"


FAULT_KINDS = {
    "nan": "the sensor reads NaN",
    "stale": "the sensor repeats its last sample (a frozen A/D)",
    "offset": "the force reads VALUE N more (a load the rig should not see)",
    "reading": "the sensor reads VALUE N (for example beyond its range)",
    "delay": "each cycle's read takes VALUE s longer (a stalled bus or host: the output held longer)",
    "raise": "the backend raises an exception",
    "signal": "the process receives signal VALUE (2 SIGINT, 15 SIGTERM)",
}


@dataclass(frozen=True)
class Fault:
    """A fault of ``kind`` (see :data:`FAULT_KINDS`) from ``at_s`` on the run's timeline, for ``duration_s``."""

    kind: str
    at_s: float
    value: float = 0.0
    duration_s: float = math.inf

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault '{self.kind}'; expected one of {', '.join(FAULT_KINDS)}")
        if not (math.isfinite(self.at_s) and self.at_s >= 0 and self.duration_s > 0):
            raise ValueError("a fault needs a finite at_s >= 0 and duration_s > 0, "
                             f"got {self.at_s} and {self.duration_s}")

    def active(self, t_s: float) -> bool:
        return self.at_s <= t_s < self.at_s + self.duration_s


def parse_fault(text: str) -> Fault:
    """``KIND@T_S[=VALUE][/DURATION_S]``, e.g. ``nan@1.5``, ``offset@2=80``, ``delay@1=0.003/0.05``."""
    try:
        kind, rest = text.split("@", 1)
        rest, _, duration = rest.partition("/")
        at, _, value = rest.partition("=")
        return Fault(kind.strip(), float(at), float(value) if value else 0.0,
                     float(duration) if duration else math.inf)
    except ValueError as exc:
        raise BackendError(f"--inject '{text}': {exc}; expected KIND@T_S[=VALUE][/DURATION_S] with KIND one of "
                           f"{', '.join(FAULT_KINDS)}") from None


class FaultInjector:
    """Any backend with faults injected at set times: how the interlocks are tested.

    A ``delay`` stalls the read through :attr:`stall` (``time.sleep``; the executor gives it
    its clock's, so that a run back to back stalls its virtual clock instead of the host).
    """

    def __init__(self, inner: Backend, faults: list[Fault]) -> None:
        self.inner = inner
        self.faults = list(faults)
        self.name = f"{inner.name}+faults"
        self.stall: Callable[[float], None] = time.sleep
        self._last: Reading | None = None
        self._signalled: set[int] = set()

    def __getattr__(self, name: str) -> Any:  # sample_period_s, force_N, ... of the wrapped backend
        return getattr(self.inner, name)

    def arm(self) -> None:
        self.inner.arm()

    def read_force(self, t_s: float) -> Reading:
        active = [f for f in self.faults if f.active(t_s)]
        for f in active:
            if f.kind == "raise":
                raise InjectedFault(injected_failure(t_s))
            if f.kind == "delay":
                self.stall(f.value)
            if f.kind == "signal" and id(f) not in self._signalled:
                self._signalled.add(id(f))
                os.kill(os.getpid(), int(f.value or signal.SIGTERM))
        if any(f.kind == "stale" for f in active) and self._last is not None:
            return self._last
        reading = self.inner.read_force(t_s)
        self._last = reading
        force = reading.force_N
        for f in active:
            if f.kind == "nan":
                force = math.nan
            elif f.kind == "offset":
                force += f.value
            elif f.kind == "reading":
                force = f.value
        return Reading(force, reading.t_s)

    def write_voltage(self, volts: float) -> None:
        self.inner.write_voltage(volts)

    def disarm(self) -> None:
        self.inner.disarm()


def _plugins() -> dict[str, EntryPoint]:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def available_backends() -> list[str]:
    """``sim``, ``clib`` (a library with the C ABI) and every installed plug-in's name."""
    return ["sim", "clib", *sorted(n for n in _plugins() if n not in ("sim", "clib"))]


def open_backend(name: str, options: Mapping[str, str] | None = None, *, plant: Plant | None = None,
                 seed: int = 0) -> Backend:
    """The backend ``name``: ``sim`` on ``plant``, or the installed plug-in of that name with ``options``."""
    options = dict(options or {})
    if name == "sim":
        if plant is None:
            raise BackendError("the simulated backend needs a plant: the gain set's 'plant.rig' or a study's [rig]")
        unknown = sorted(set(options) - {"seed", "watchdog_s", "daq"})
        if unknown:
            raise BackendError(f"--backend-option {unknown[0]}: the simulated backend takes only 'seed', 'watchdog_s' "
                               "and 'daq'")
        key = "seed"
        try:
            seed = int(options.get("seed", seed))
            key = "watchdog_s"
            wd = float(options["watchdog_s"]) if "watchdog_s" in options else None
            key = "daq"
            return SimBackend(plant, seed, watchdog_s=wd, daq_path=options.get("daq"))
        except (ValueError, OSError) as exc:
            raise BackendError(f"--backend-option {key}={options.get(key)!r}: {exc}") from None
    if name == "clib":
        if set(options) != {"library"}:
            raise BackendError("the backend 'clib' takes one option, library=PATH (a shared library with the C ABI "
                               "of piezopreload.rig.backends.CLibraryBackend)")
        return CLibraryBackend(options["library"])
    plugins = _plugins()
    if name not in plugins:
        raise BackendError(f"backend '{name}' is not installed; installed: {', '.join(available_backends())}. "
                           f"A hardware backend is a package with an entry point in the group '{ENTRY_POINT_GROUP}' "
                           "(see piezopreload.rig.backends)")
    try:
        factory: Callable[[dict[str, str]], Backend] = plugins[name].load()
    except Exception as exc:  # a broken plug-in is named, not a traceback
        raise BackendError(f"backend '{name}' is installed but cannot be loaded: {type(exc).__name__}: {exc}") from None
    backend = factory(options)
    missing = [m for m in ("arm", "read_force", "write_voltage", "disarm") if not callable(getattr(backend, m, None))]
    if missing:
        raise BackendError(f"backend '{name}' lacks the method '{missing[0]}' of the backend interface")
    return backend
