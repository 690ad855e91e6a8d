"""The controller step as compiled C, for the rig's fixed-rate loop.

The controller step of ``models/controller`` (:class:`~piezopreload.models.controller.ControllerModel`:
the one PID update and feedforward, every number an input) goes through CasADi's code generator
and the system's C compiler (:mod:`piezopreload.core.native`) into a shared library, loaded
with :mod:`ctypes`. A step then costs about a microsecond instead of the numpy path's tens, which
leaves the loop's period to the backend. The library depends only on the controller's
structure (the feedforward's kind and size), so it is built once per structure (cached under
``$XDG_CACHE_HOME/piezopreload`` by the hash of its source) and a new gain set or feedforward
model is a new parameter vector, not new code.

Where no C compiler is found (or ``PIEZOPRELOAD_ENGINE=numpy``), :func:`controller_step`
returns the numpy step instead; both give the same numbers (tests hold them to 1e-9 V) and say
which they are in ``kind``.

The C entry point, for a native loop to call::

    int pp_rig_step(double setpoint, double pv, double ff_extra, double* state, const double* params,
                    double* out);

``ff_extra`` is the external feedforward sample (a learned signal played back, 0 without one),
added before the clamp as in :meth:`ControllerModel.step`; ``state``
(:attr:`ControllerModel.state`) is updated in place, ``params`` is
:meth:`Controller.parameter_vector` (its length is the model's layout's), ``out = (u, p, i,
d, ff)``; 0 on success.
"""

from __future__ import annotations

import contextlib
import ctypes
from typing import Any

import casadi as ca
import numpy as np

from piezopreload.core import native
from piezopreload.core.errors import InputError
from piezopreload.models.actuator import Plant, PlantModel, Rig
from piezopreload.models.controller import Controller, ControllerModel, ControllerState, controller_functions
from piezopreload.models.ops import CASADI, NUMPY

__all__ = ["CompiledStep", "PythonStep", "controller_step", "cache_dir", "step_library", "PlantStep", "plant_library"]

cache_dir = native.cache_dir

_WRAPPER = """
/* piezopreload: one controller sample; the state is updated in place, out = (u, p, i, d, ff) */
int pp_rig_step(double setpoint, double pv, double ff_extra, double* state, const double* params, double* out) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int iw[{iw}];
  casadi_real w[{w}];
  casadi_real next[{n}];
  int i, flag;
  arg[0] = state; arg[1] = &setpoint; arg[2] = &pv; arg[3] = &ff_extra; arg[4] = params;
  res[0] = out; res[1] = out + 1; res[2] = out + 2; res[3] = out + 3; res[4] = out + 4; res[5] = next;
  flag = {name}(arg, res, iw, w, 0);
  if (flag) return flag;
  for (i = 0; i < {n}; ++i) state[i] = next[i];
  return 0;
}}
"""


_STEPS: dict[ControllerModel, ctypes.CDLL] = {}


def step_library(model: ControllerModel) -> ctypes.CDLL:
    """The shared library with ``pp_rig_step`` for controllers of ``model``'s structure (built once, cached on disk
    and, once loaded, in the process: a loop switching to a structure built before finds it at once)."""
    try:
        return _STEPS[model]
    except (KeyError, TypeError):
        pass
    lib = _step_library(model)
    with contextlib.suppress(TypeError):
        _STEPS[model] = lib
    return lib


def _step_library(model: ControllerModel) -> ctypes.CDLL:
    _, fn = controller_functions(model, prefix="pp_rig", ff_extra=True)
    source = native.generate([fn], "pp_rig_step") + _WRAPPER.format(
        sz_arg=max(int(fn.sz_arg()), 5), sz_res=max(int(fn.sz_res()), 6), iw=max(int(fn.sz_iw()), 1),
        w=max(int(fn.sz_w()), 1), n=model.state.size, name=fn.name())
    return native.library("pp_rig_step", source)


class PythonStep:
    """The numpy step of :class:`Controller` behind the interface the rig loop calls.

    It runs :meth:`ControllerModel.step` on numpy with the state kept as the model's vector, as
    the compiled step does.
    """

    kind = "numpy"

    def __init__(self, controller: Controller) -> None:
        self._set(controller)
        self._x: np.ndarray | None = None

    def _set(self, controller: Controller) -> None:
        self.controller = controller
        self._model, self._p = controller.model, controller.parameter_vector()

    def start(self, setpoint: float, pv: float, u0: float, ff_extra: float = 0.0) -> None:
        """A bumpless start: the first output at ``(setpoint, pv)`` (with ``ff_extra``) is ``u0``."""
        if ff_extra:
            self._x = np.asarray(self._model.start(NUMPY, self._p, np.float64(setpoint), np.float64(pv), u0,
                                                   np.float64(ff_extra)), float)
        else:
            self._x = self.controller.state_vector(self.controller.initial_state(setpoint, pv, u0=u0))

    def step(self, setpoint: float, pv: float, ff_extra: float = 0.0) -> tuple[float, float, float, float, float]:
        """One sample: ``(u, p, i, d, ff)`` in volts; ``ff_extra`` is added to the feedforward."""
        if self._x is None:
            raise RuntimeError("start() the step before stepping it")
        self._x, t = self._model.step(NUMPY, self._p, self._x, np.float64(setpoint), np.float64(pv),
                                      np.float64(ff_extra))
        return float(t.u), float(t.p), float(t.i), float(t.d), float(t.ff)

    @property
    def state(self) -> ControllerState | None:
        return None if self._x is None else self.controller.state_from_vector(self._x)

    @property
    def entry_point(self) -> None:
        """No compiled function: the native loop loads its own (:attr:`CompiledStep.entry_point`)."""
        return None

    def switch(self, new: Controller) -> None:
        """Take ``new`` over between two samples without a jump of the output."""
        state = self.state
        if state is not None:
            self._x = new.state_vector(self.controller.switch(state, new))
        self._set(new)


class CompiledStep:
    """:class:`PythonStep`'s interface on the compiled C step (see the module docstring)."""

    kind = "c"

    def __init__(self, controller: Controller) -> None:
        self._model = controller.model
        lib = step_library(self._model)
        fn = lib.pp_rig_step
        fn.argtypes = [ctypes.c_double, ctypes.c_double, ctypes.c_double, ctypes.c_void_p, ctypes.c_void_p,
                       ctypes.c_void_p]
        fn.restype = ctypes.c_int
        self._lib, self._fn = lib, fn
        self._x = np.zeros(self._model.state.size)
        self._out = np.zeros(5)
        self._set(controller)

    def _set(self, controller: Controller) -> None:
        if controller.model != self._model:
            raise InputError(f"this compiled step is for {self._model}, the controller is {controller.model}")
        self.controller = controller
        self._p = np.ascontiguousarray(controller.parameter_vector())
        self._ptr = (self._x.ctypes.data, self._p.ctypes.data, self._out.ctypes.data)

    def start(self, setpoint: float, pv: float, u0: float, ff_extra: float = 0.0) -> None:
        """A bumpless start: the first output at ``(setpoint, pv)`` (with ``ff_extra``) is ``u0``."""
        self._x[:] = np.asarray(self._model.start(NUMPY, self._p, np.float64(setpoint), np.float64(pv), u0,
                                                  np.float64(ff_extra)), float).reshape(-1)

    def step(self, setpoint: float, pv: float, ff_extra: float = 0.0) -> tuple[float, float, float, float, float]:
        """One sample: ``(u, p, i, d, ff)`` in volts; ``ff_extra`` is added to the feedforward."""
        x, p, out = self._ptr
        if self._fn(setpoint, pv, ff_extra, x, p, out):
            raise RuntimeError("the compiled controller step failed")
        u, prop, i, d, ff = self._out.tolist()
        return u, prop, i, d, ff

    @property
    def state(self) -> ControllerState:
        return self.controller.state_from_vector(self._x)

    @property
    def entry_point(self) -> Any:
        """The loaded ``pp_rig_step`` of this controller's structure (ctypes), which the native loop calls as well."""
        return self._fn

    def switch(self, new: Controller) -> None:
        state = self.controller.switch(self.state, new)
        if new.model != self._model:  # another structure (feedforward kind or size): another library
            self.__dict__.update(CompiledStep(new).__dict__)
        else:
            self._set(new)
        self._x[:] = new.state_vector(state)


def controller_step(controller: Controller, prefer: str = "c") -> PythonStep | CompiledStep:
    """The fastest step this machine can run: compiled C where a compiler works, else numpy.

    ``prefer="numpy"`` (or ``PIEZOPRELOAD_ENGINE=numpy``) forces the numpy step. A compiler
    that fails falls back to numpy too; the step's ``kind`` says which one runs.
    """
    if prefer not in ("c", "numpy"):
        raise ValueError(f"prefer must be 'c' or 'numpy', got {prefer!r}")
    if prefer == "c" and native.enabled():
        try:
            return CompiledStep(controller)
        except native.NativeBuildError:
            if native.engine() == "c":
                raise
    return PythonStep(controller)


_PLANT_WRAPPER = """
/* piezopreload: the rig's plant, one sample per call. pp_plant_read: the true force and the A/D
   reading for the standard normal draw z, out = (force, reading); pp_plant_write: the state one
   sample after the command u is written (updated in place). 0 on success. */
int pp_plant_read(const double* state, const double* params, double z, double* out) {{
  const casadi_real* arg[{r_arg}];
  casadi_real* res[{r_res}];
  casadi_int iw[{r_iw}];
  casadi_real w[{r_w}];
  arg[0] = state; arg[1] = params; arg[2] = &z;
  res[0] = out; res[1] = out + 1;
  return {read}(arg, res, iw, w, 0);
}}

int pp_plant_write(double* state, const double* params, double u) {{
  const casadi_real* arg[{w_arg}];
  casadi_real* res[{w_res}];
  casadi_int iw[{w_iw}];
  casadi_real w[{w_w}];
  casadi_real next[{n}];
  int i, flag;
  arg[0] = state; arg[1] = params; arg[2] = &u;
  res[0] = next;
  flag = {write}(arg, res, iw, w, 0);
  if (flag) return flag;
  for (i = 0; i < {n}; ++i) state[i] = next[i];
  return 0;
}}
"""


def plant_library(model: PlantModel) -> ctypes.CDLL:
    """The shared library with ``pp_plant_read`` and ``pp_plant_write`` for plants of ``model``'s structure."""
    x, p = ca.SX.sym("x", model.state.size), ca.SX.sym("p", model.params.size)
    z, u = ca.SX.sym("z"), ca.SX.sym("u")
    force = model.force(CASADI, p, x)
    read = ca.Function("pp_plant_read_fn", [x, p, z], [force, model.measure(CASADI, p, force, z)])
    write = ca.Function("pp_plant_write_fn", [x, p, u], [model.step(CASADI, p, x, u)])

    def sizes(fn: ca.Function, prefix: str, n_arg: int, n_res: int) -> dict[str, int]:
        return {f"{prefix}_arg": max(int(fn.sz_arg()), n_arg), f"{prefix}_res": max(int(fn.sz_res()), n_res),
                f"{prefix}_iw": max(int(fn.sz_iw()), 1), f"{prefix}_w": max(int(fn.sz_w()), 1)}

    source = native.generate([read, write], "pp_plant") + _PLANT_WRAPPER.format(
        read=read.name(), write=write.name(), n=model.state.size, **sizes(read, "r", 3, 2), **sizes(write, "w", 3, 1))
    return native.library("pp_plant", source)


class PlantStep:
    """One simulated plant stepped a sample at a time, for the rig executor's simulated backend.

    The plant step of :class:`~piezopreload.models.actuator.PlantModel` (the one the simulation
    runs), compiled to C and called through ctypes where a compiler works (``kind == "c"``),
    else on numpy (``"numpy"``): the same numbers. :meth:`read` is the A/D reading for a
    standard normal draw, :meth:`write` advances the plant by one sample under a command.
    """

    def __init__(self, params: Plant, prefer: str = "c") -> None:
        if params.batch_shape:
            raise InputError("a plant step runs one plant, not a batch")
        self.rig = Rig(params)
        self.model = self.rig.model
        self._p = np.ascontiguousarray(self.rig.parameter_vector, dtype=float)
        self._x = np.zeros(self.model.state.size)
        self._out = np.zeros(2)
        self.kind = "numpy"
        if prefer == "c" and native.enabled():
            try:
                lib = plant_library(self.model)
                self._read, self._write = lib.pp_plant_read, lib.pp_plant_write
                self._read.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double, ctypes.c_void_p]
                self._write.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double]
                self._read.restype = self._write.restype = ctypes.c_int
                self._lib, self.kind = lib, "c"
            except native.NativeBuildError:
                if native.engine() == "c":
                    raise
        self.reset()

    def reset(self, v0_V: float = 0.0) -> None:
        """At rest at ``v0_V``, creep settled (:meth:`PlantModel.rest_state`)."""
        self._x[:] = self.model.rest_state(NUMPY, self._p, float(v0_V))

    def read(self, z: float) -> tuple[float, float]:
        """``(true force, A/D reading)`` now, for the standard normal draw ``z``."""
        if self.kind == "c":
            if self._read(self._x.ctypes.data, self._p.ctypes.data, z, self._out.ctypes.data):
                raise RuntimeError("the compiled plant read failed")
            force, reading = self._out.tolist()
            return force, reading
        force = self.model.force(NUMPY, self._p, self._x)
        return float(force), float(self.model.measure(NUMPY, self._p, force, z))

    def write(self, command_V: float) -> None:
        """Advance one sample; ``command_V`` is written to the D/A at this tick."""
        if self.kind == "c":
            if self._write(self._x.ctypes.data, self._p.ctypes.data, command_V):
                raise RuntimeError("the compiled plant step failed")
        else:
            self._x[:] = self.model.step(NUMPY, self._p, self._x, float(command_V))

    @property
    def state(self) -> np.ndarray:
        """The state vector (:attr:`PlantModel.state`), a copy."""
        return self._x.copy()

    def native_addresses(self) -> tuple[int, int, int, int]:
        """Where the native loop steps this plant itself: the compiled read and write functions and the state and
        parameter vectors they work on (this object's own, so that the loop's steps are this plant's).

        Returns
        -------
        tuple of int
            ``(read, write, state, params)``, addresses.

        Raises
        ------
        RuntimeError
            The plant step is not compiled (``kind == "numpy"``).
        """
        if self.kind != "c":
            raise RuntimeError("the plant step is not compiled: the native loop cannot step it")
        read = ctypes.cast(self._read, ctypes.c_void_p).value
        write = ctypes.cast(self._write, ctypes.c_void_p).value
        if read is None or write is None:
            raise RuntimeError("the compiled plant step has no address")
        return read, write, int(self._x.ctypes.data), int(self._p.ctypes.data)

    @property
    def amplifier_V(self) -> float:
        return float(self._x[self.model.state.index("v_amp")])
