"""The controller step as compiled C, for the rig's fixed-rate loop.

:func:`~piezopreload.models.controller.parametric_step` (the one PID update and inverse P-I of
``models/controller``, every number an input) goes through CasADi's code generator and the
system's C compiler into a shared library, loaded with :mod:`ctypes`. A step then costs about
a microsecond instead of the numpy path's twenty, which leaves the loop's period to the
backend. The library depends only on the number of feedforward operators, so it is built
once per operator count (cached under ``$XDG_CACHE_HOME/piezopreload``, by the hash of its
source) and a new gain set or feedforward model is a new parameter vector, not new code.

Where no C compiler is found, :func:`controller_step` returns the numpy step instead; both
give the same numbers (tests hold them to 1e-9 V) and say which they are in ``kind``.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

from piezopreload.models.controller import Controller, ControllerState, parametric_step

__all__ = ["CompiledStep", "PythonStep", "controller_step", "cache_dir"]

_WRAPPER = """
/* piezopreload: one controller sample; the state is updated in place, out = (u, p, i, d, ff) */
int pp_rig_step(double setpoint, double pv, double* state, const double* params, double* out) {{
  const casadi_real* arg[4];
  casadi_real* res[6];
  casadi_int iw[{iw}];
  casadi_real w[{w}];
  casadi_real next[{n}];
  int i, flag;
  arg[0] = state; arg[1] = &setpoint; arg[2] = &pv; arg[3] = params;
  res[0] = out; res[1] = out + 1; res[2] = out + 2; res[3] = out + 3; res[4] = out + 4; res[5] = next;
  flag = {name}(arg, res, iw, w, 0);
  if (flag) return flag;
  for (i = 0; i < {n}; ++i) state[i] = next[i];
  return 0;
}}
"""


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "piezopreload"


def _compiler() -> str | None:
    return os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")


def _source(n_ff: int) -> str:
    fn = parametric_step(n_ff)
    with tempfile.TemporaryDirectory() as tmp:
        gen = ca.CodeGenerator("pp_rig_step.c", {"with_header": False, "casadi_real": "double"})
        gen.add(fn)
        gen.generate(tmp + os.sep)
        body = Path(tmp, "pp_rig_step.c").read_text()
    return body + _WRAPPER.format(iw=max(int(fn.sz_iw()), 1), w=max(int(fn.sz_w()), 1), n=5 + n_ff, name=fn.name())


def _library(n_ff: int, compiler: str) -> Path:
    """The shared library for ``n_ff`` operators, compiled once and cached by its source's hash."""
    source = _source(n_ff)
    digest = hashlib.sha256((source + compiler).encode()).hexdigest()[:16]
    folder = cache_dir()
    lib = folder / f"pp_rig_step_{n_ff}_{digest}.so"
    if lib.exists():
        return lib
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        src, out = Path(tmp, "step.c"), Path(tmp, "step.so")
        src.write_text(source)
        subprocess.run([compiler, "-O2", "-shared", "-fPIC", "-o", str(out), str(src), "-lm"],
                       check=True, capture_output=True, text=True)
        os.replace(out, lib)  # atomic: a concurrent build of the same source writes the same file
    return lib


class PythonStep:
    """The numpy step of :class:`Controller` behind the interface the rig loop calls."""

    kind = "numpy"

    def __init__(self, controller: Controller) -> None:
        self.controller = controller
        self._state: ControllerState | None = None

    def start(self, setpoint: float, pv: float, u0: float) -> None:
        """A bumpless start: the first output at ``(setpoint, pv)`` is ``u0``."""
        self._state = self.controller.initial_state(setpoint, pv, u0=u0)

    def step(self, setpoint: float, pv: float) -> tuple[float, float, float, float, float]:
        """One sample: ``(u, p, i, d, ff)`` in volts."""
        terms, self._state = self.controller.step_terms(self._state, setpoint, pv)
        return float(terms.u), float(terms.p), float(terms.i), float(terms.d), float(terms.ff)

    @property
    def state(self) -> ControllerState:
        return self._state

    def switch(self, new: Controller) -> None:
        """Take ``new`` over between two samples without a jump of the output."""
        self._state = self.controller.switch(self._state, new)
        self.controller = new


class CompiledStep:
    """:class:`PythonStep`'s interface on the compiled C step (see the module docstring)."""

    kind = "c"

    def __init__(self, controller: Controller, compiler: str) -> None:
        n_ff = controller.n_feedforward_states
        lib = ctypes.CDLL(str(_library(n_ff, compiler)))
        fn = lib.pp_rig_step
        fn.argtypes = [ctypes.c_double, ctypes.c_double, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
        fn.restype = ctypes.c_int
        self._lib, self._fn, self._n_ff, self._compiler = lib, fn, n_ff, compiler
        self._x = np.zeros(5 + n_ff)
        self._out = np.zeros(5)
        self._set(controller)

    def _set(self, controller: Controller) -> None:
        if controller.n_feedforward_states != self._n_ff:
            raise ValueError(f"this compiled step has {self._n_ff} feedforward operators, the controller "
                             f"{controller.n_feedforward_states}")
        self.controller = controller
        self._p = np.ascontiguousarray(controller.parameter_vector())
        self._ptr = (self._x.ctypes.data, self._p.ctypes.data, self._out.ctypes.data)

    def start(self, setpoint: float, pv: float, u0: float) -> None:
        self._x[:] = Controller.state_vector(self.controller.initial_state(setpoint, pv, u0=u0))

    def step(self, setpoint: float, pv: float) -> tuple[float, float, float, float, float]:
        x, p, out = self._ptr
        if self._fn(setpoint, pv, x, p, out):
            raise RuntimeError("the compiled controller step failed")
        return tuple(self._out.tolist())

    @property
    def state(self) -> ControllerState:
        return self.controller.state_from_vector(self._x)

    def switch(self, new: Controller) -> None:
        state = self.controller.switch(self.state, new)
        if new.n_feedforward_states != self._n_ff:  # another operator count: another library
            self.__dict__.update(CompiledStep(new, self._compiler).__dict__)
        else:
            self._set(new)
        self._x[:] = Controller.state_vector(state)


def controller_step(controller: Controller, prefer: str = "c") -> PythonStep | CompiledStep:
    """The fastest step this machine can run: compiled C where a compiler works, else numpy.

    ``prefer="numpy"`` forces the numpy step. A compiler that fails falls back to numpy too;
    the step's ``kind`` says which one runs.
    """
    if prefer not in ("c", "numpy"):
        raise ValueError(f"prefer must be 'c' or 'numpy', got {prefer!r}")
    compiler = _compiler() if prefer == "c" else None
    if compiler is not None:
        try:
            return CompiledStep(controller, compiler)
        except (OSError, subprocess.CalledProcessError):
            pass
    return PythonStep(controller)

