"""The controller step: PID in the form of LabVIEW's PID VIs, plus inverse-P-I feedforward.

One implementation, used by the closed-loop simulation, the tuning validation and the rig
executor. The PID follows NI's documented algorithm (PID Control Toolkit, 371685C, "PID
Algorithms"), ideal/ISA form ``u = Kc (e + 1/Ti int e dt + Td de/dt)``:

* proportional action ``Kc (b SP - PV)`` (setpoint weight ``b``, 1 in LabVIEW);
* trapezoidal integration ``Kc / Ti * sum (e_k + e_{k-1}) / 2 * dt``;
* derivative on the measurement only (no derivative kick), ``-Kc Td d(PV)/dt``, optionally
  through a first-order filter of time constant ``Tf``;
* output clamped to ``[u_min, u_max]`` with conditional integration as anti-windup (the
  integral does not move in the direction that drives the output further into its limit).

Times are in seconds inside; LabVIEW enters ``Ti`` and ``Td`` in minutes, converted only by
:meth:`PIDGains.from_labview` and :meth:`PIDGains.labview`. Every operation broadcasts, so
the state may hold a batch of independent loops.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from types import SimpleNamespace
from typing import Any, Protocol

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezopreload.models.hysteresis import casadi_inverse_step

__all__ = ["PIDGains", "ControllerState", "Controller", "Feedforward", "Terms", "pid_update", "parametric_step", "NUMPY_OPS", "CASADI_OPS"]

#: The few operations :func:`pid_update` needs that differ between numpy arrays and CasADi
#: expressions, so the one PID update serves the simulation (numpy) and the tuning NLP and the
#: generated C code (CasADi).
NUMPY_OPS = SimpleNamespace(where=np.where, minimum=np.minimum, maximum=np.maximum,
                            logical_and=np.logical_and, logical_or=np.logical_or)
CASADI_OPS = SimpleNamespace(where=ca.if_else, minimum=ca.fmin, maximum=ca.fmax,
                             logical_and=ca.logic_and, logical_or=ca.logic_or)


def pid_update(ops: Any, gains: Any, u_range: tuple[Any, Any], dt: Any, integral: Any, e_prev: Any,
               pv_prev: Any, dpv: Any, sp: Any, pv: Any, ff: Any) -> tuple[Any, ...]:
    """One sample of the PID, on numpy arrays or CasADi expressions (``ops``).

    ``gains = (Kc, Ti, Td, Tf, b)``. Returns ``(u, p, i, d, e, dpv)``: the clamped output, its
    proportional, integral (the new integral action) and derivative parts, this sample's error
    and filtered derivative of the measurement. See the module docstring for the algorithm.
    """
    Kc, Ti, Td, Tf, b = gains
    u_min, u_max = u_range
    e = sp - pv
    proportional = Kc * (b * sp - pv)
    alpha = Tf / (Tf + dt)  # backward-Euler first-order filter; 0 when Tf = 0
    dpv = alpha * dpv + (1.0 - alpha) * (pv - pv_prev) / dt
    derivative = -Kc * Td * dpv
    increment = Kc / Ti * 0.5 * (e + e_prev) * dt  # 0 for Ti = inf
    trial = proportional + integral + increment + derivative + ff
    # conditional integration: no integrating further into a limit
    winding = ops.logical_or(ops.logical_and(trial > u_max, increment > 0), ops.logical_and(trial < u_min, increment < 0))
    integral = integral + ops.where(winding, 0.0 * increment, increment)
    u = ops.minimum(ops.maximum(proportional + integral + derivative + ff, u_min), u_max)
    return u, proportional, integral, derivative, e, dpv


class Feedforward(Protocol):
    """An inverse hysteresis model: ``step(state, target) -> (input, state)``."""

    def step(self, state: Any, target: ArrayLike) -> tuple[NDArray, NDArray]: ...

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray: ...


def _finite(name: str, value: float) -> float:
    x = float(value)
    if not np.isfinite(x):
        raise ValueError(f"{name} must be finite, got {value!r}.")
    return x


@dataclass(frozen=True)
class PIDGains:
    """PID gains and output range, SI units.

    Parameters
    ----------
    Kc : float
        Controller gain, output units per measured unit (V/N for the preload loop).
    Ti_s : float
        Integral time in s; ``inf`` switches integral action off.
    Td_s : float
        Derivative time in s (0: no derivative action).
    Tf_s : float
        Time constant of the first-order derivative filter in s (0: unfiltered).
    b : float
        Setpoint weight of the proportional action (1: error feedback, as LabVIEW).
    u_min, u_max : float
        Output range (V); the paper's closed loop uses 0-110 V.
    """

    Kc: float
    Ti_s: float
    Td_s: float = 0.0
    Tf_s: float = 0.0
    b: float = 1.0
    u_min: float = 0.0
    u_max: float = 110.0

    def __post_init__(self) -> None:
        _finite("Kc", self.Kc)
        if not (self.Ti_s > 0):
            raise ValueError(f"Ti_s must be > 0 (inf for no integral action), got {self.Ti_s!r}.")
        for name in ("Td_s", "Tf_s"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {getattr(self, name)!r}.")
        _finite("b", self.b)
        if not (np.isfinite(self.u_min) and np.isfinite(self.u_max) and self.u_min < self.u_max):
            raise ValueError(f"need finite u_min < u_max, got {self.u_min!r} and {self.u_max!r}.")

    @classmethod
    def from_labview(cls, Kc: float, Ti_min: float, Td_min: float, **kwargs: Any) -> PIDGains:
        """Gains as entered in LabVIEW's PID VIs, whose Ti and Td are in minutes."""
        return cls(Kc=Kc, Ti_s=60.0 * Ti_min, Td_s=60.0 * Td_min, **kwargs)

    def labview(self) -> dict[str, float]:
        """Kc, Ti and Td (minutes) for LabVIEW's PID VIs."""
        return {"Kc": self.Kc, "Ti_min": self.Ti_s / 60.0, "Td_min": self.Td_s / 60.0}


@dataclass(frozen=True, eq=False)
class ControllerState:
    """Everything the controller remembers between samples; copy it to branch a simulation.

    ``integral`` is the integral *action* (output units), so a change of ``Kc`` or ``Ti``
    leaves it as it is; ``dpv`` the filtered derivative of the measurement; ``ff`` the state
    of the feedforward's operators.
    """

    integral: NDArray[np.float64]
    e_prev: NDArray[np.float64]
    pv_prev: NDArray[np.float64]
    sp_prev: NDArray[np.float64]
    dpv: NDArray[np.float64]
    ff: NDArray[np.float64] | None


@dataclass(frozen=True, eq=False)
class Terms:
    """One sample's output ``u`` (after the clamp) and its parts before it: ``p + i + d + ff``."""

    u: NDArray[np.float64]
    p: NDArray[np.float64]
    i: NDArray[np.float64]
    d: NDArray[np.float64]
    ff: NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Controller:
    """PID with optional inverse-P-I feedforward of the setpoint, sampled every ``dt_s``."""

    gains: PIDGains
    dt_s: float
    feedforward: Any = None  # a Feedforward: an inverse hysteresis model

    def __post_init__(self) -> None:
        if not (np.isfinite(self.dt_s) and self.dt_s > 0):
            raise ValueError(f"dt_s must be a positive sample period, got {self.dt_s!r}.")

    def initial_state(self, setpoint: ArrayLike, pv: ArrayLike, u0: ArrayLike | None = None) -> ControllerState:
        """A state at rest at ``(setpoint, pv)`` whose first output is ``u0`` (bumpless start).

        Without ``u0`` the integral starts at 0.
        """
        sp, pv = (np.array(x) for x in np.broadcast_arrays(np.asarray(setpoint, float), np.asarray(pv, float)))
        ff_state = None if self.feedforward is None else self.feedforward.initial_state(sp.shape)
        integral = np.zeros_like(sp)
        state = ControllerState(integral, sp - pv, pv, sp, np.zeros_like(sp), ff_state)
        if u0 is not None:
            ff = 0.0 if self.feedforward is None else self.feedforward.step(ff_state, sp)[0]
            p = self.gains.Kc * (self.gains.b * sp - pv)
            state = replace(state, integral=np.broadcast_to(np.asarray(u0, float) - p - ff, sp.shape).copy())
        return state

    def step(
        self, state: ControllerState, setpoint: ArrayLike, pv: ArrayLike
    ) -> tuple[NDArray[np.float64], ControllerState]:
        """One sample: the command for measurement ``pv`` and ``setpoint``, and the next state."""
        terms, state = self.step_terms(state, setpoint, pv)
        return terms.u, state

    def step_terms(self, state: ControllerState, setpoint: ArrayLike, pv: ArrayLike) -> tuple[Terms, ControllerState]:
        """:meth:`step` with the output's parts, for run logs and figures."""
        g = self.gains
        sp = np.asarray(setpoint, float)
        pv = np.asarray(pv, float)
        if self.feedforward is None:
            ff, ff_state = np.zeros(()), None
        else:
            ff, ff_state = self.feedforward.step(state.ff, sp)
        u, p, integral, d, e, dpv = pid_update(
            NUMPY_OPS, (g.Kc, g.Ti_s, g.Td_s, g.Tf_s, g.b), (g.u_min, g.u_max), self.dt_s,
            state.integral, state.e_prev, state.pv_prev, state.dpv, sp, pv, ff)
        u = np.asarray(u, float)
        terms = Terms(u=u, p=p, i=np.asarray(integral, float), d=d, ff=np.broadcast_to(ff, u.shape))
        return terms, ControllerState(np.asarray(integral, float), e, pv, sp, dpv, ff_state)

    def casadi_functions(self) -> tuple[ca.Function, ca.Function]:
        """The controller as CasADi functions, for code generation: ``(initial_state, step)``.

        ``initial_state(setpoint, pv, u0) -> state`` is :meth:`initial_state` with ``u0``
        (a bumpless start); ``step(state, setpoint, pv) -> (u, state_next)`` is :meth:`step`.
        The gains and the feedforward model are constants; ``state = [integral, e_prev,
        pv_prev, sp_prev, dpv, ff operator states...]`` (:meth:`state_vector` packs a
        :class:`ControllerState`). The same :func:`pid_update` as :meth:`step`, so the
        generated code computes what the simulation does.
        """
        ff_model = self.feedforward
        n_ff = 0
        if ff_model is not None:
            if not hasattr(ff_model, "casadi_step"):
                raise TypeError(f"{type(ff_model).__name__} has no CasADi step; use the classical P-I inverse.")
            n_ff = int(ff_model.initial_state().size)
        g = self.gains
        x = ca.SX.sym("state", 5 + n_ff)
        sp, pv, u0 = ca.SX.sym("setpoint"), ca.SX.sym("pv"), ca.SX.sym("u0")

        def feedforward(ff_state: Any, target: Any) -> tuple[Any, Any]:
            return (0.0, ca.SX(0, 1)) if ff_model is None else ff_model.casadi_step(ff_state, target)

        ff, ff_next = feedforward(x[5:], sp)
        u, _, integral, _, e, dpv = pid_update(
            CASADI_OPS, (g.Kc, g.Ti_s, g.Td_s, g.Tf_s, g.b), (g.u_min, g.u_max), self.dt_s,
            x[0], x[1], x[2], x[4], sp, pv, ff)
        step = ca.Function("piezopreload_controller_step", [x, sp, pv], [u, ca.vertcat(integral, e, pv, sp, dpv, ff_next)],
                           ["state", "setpoint", "pv"], ["u", "state_next"])
        ff_rest = ca.DM.zeros(n_ff)
        ff0, _ = feedforward(ff_rest, sp)
        start = ca.vertcat(u0 - g.Kc * (g.b * sp - pv) - ff0, sp - pv, pv, sp, 0.0, ff_rest)
        init = ca.Function("piezopreload_controller_initial_state", [sp, pv, u0], [start],
                           ["setpoint", "pv", "u0"], ["state"])
        return init, step

    @staticmethod
    def state_vector(state: ControllerState) -> NDArray[np.float64]:
        """One loop's state as the flat vector of :meth:`casadi_function`."""
        head = [float(state.integral), float(state.e_prev), float(state.pv_prev), float(state.sp_prev), float(state.dpv)]
        tail = [] if state.ff is None else list(np.asarray(state.ff, float).ravel())
        return np.array(head + tail)

    def state_from_vector(self, x: ArrayLike) -> ControllerState:
        """The inverse of :meth:`state_vector`, for this controller's feedforward."""
        x = np.asarray(x, float)
        if x.shape != (5 + self.n_feedforward_states,):
            raise ValueError(f"expected a state of {5 + self.n_feedforward_states} numbers, got shape {x.shape}.")
        ff = None if self.feedforward is None else x[5:].copy()
        integral, e_prev, pv_prev, sp_prev, dpv = (np.array(v) for v in x[:5])
        return ControllerState(integral, e_prev, pv_prev, sp_prev, dpv, ff)

    def retune(self, state: ControllerState, gains: PIDGains) -> tuple[Controller, ControllerState]:
        """Switch to new gains without a jump in the output (bumpless gain change).

        The integral absorbs the change of the proportional and derivative actions at the last
        sample, so the next output with unchanged inputs equals the last one.
        """
        new = replace(self, gains=gains)
        return new, self.switch(state, new)

    def switch(self, state: ControllerState, new: Controller) -> ControllerState:
        """The state under which ``new`` (other gains, another feedforward) takes over bumplessly.

        At the last sample's setpoint and measurement, ``new`` gives the output this controller
        gave: its integral absorbs the difference of the proportional, derivative and
        feedforward actions. A new feedforward model starts from rest and is brought to the last
        setpoint (its operators' history before the switch is not known to it).
        """
        if not np.isclose(new.dt_s, self.dt_s, rtol=1e-12, atol=0.0):
            raise ValueError(f"cannot switch from a {self.dt_s} s controller to a {new.dt_s} s one.")

        def actions(c: Controller, ff_state: NDArray | None) -> tuple[NDArray, NDArray | None]:
            g = c.gains
            pd = g.Kc * (g.b * state.sp_prev - state.pv_prev) - g.Kc * g.Td_s * state.dpv
            if c.feedforward is None:
                return pd, None
            ff, ff_state = c.feedforward.step(ff_state, state.sp_prev)  # play operators: idempotent at equal input
            return pd + ff, ff_state

        before, _ = actions(self, state.ff)
        same_ff = new.feedforward is self.feedforward
        after, ff_state = actions(new, state.ff if same_ff else
                                  None if new.feedforward is None else new.feedforward.initial_state(state.sp_prev.shape))
        return replace(state, integral=state.integral + before - after, ff=ff_state)

    def parameter_vector(self) -> NDArray[np.float64]:
        """The numbers :func:`parametric_step` takes: gains, range, sample period, feedforward model."""
        g = self.gains
        head = [g.Kc, g.Ti_s, g.Td_s, g.Tf_s, g.b, g.u_min, g.u_max, self.dt_s]
        ff = self.feedforward
        if ff is None:
            return np.array(head + [0.0])
        if not hasattr(ff, "casadi_step"):
            raise TypeError(f"{type(ff).__name__} has no CasADi step; use the classical P-I inverse.")
        return np.concatenate([head, [ff.forward.offset], ff.thresholds, ff.weights])

    @property
    def n_feedforward_states(self) -> int:
        return 0 if self.feedforward is None else int(self.feedforward.initial_state().size)


def parametric_step(n_ff: int) -> ca.Function:
    """The controller step with every number an input: one function for all gains and models of ``n_ff`` operators.

    ``step(state, setpoint, pv, params) -> (u, p, i, d, ff, state_next)``, ``params`` as
    :meth:`Controller.parameter_vector` gives them and ``state`` as
    :meth:`Controller.state_vector` packs it. The same :func:`pid_update` and inverse P-I as
    :meth:`Controller.step`, so code generated from it computes what the simulation does, and
    a gain change needs no new code.
    """
    x = ca.SX.sym("state", 5 + n_ff)
    sp, pv = ca.SX.sym("setpoint"), ca.SX.sym("pv")
    prm = ca.SX.sym("params", 9 + 2 * n_ff)
    Kc, Ti, Td, Tf, b, u_min, u_max, dt, offset = (prm[k] for k in range(9))
    if n_ff:
        ff, ff_next = casadi_inverse_step(x[5:], sp, offset, prm[9:9 + n_ff], prm[9 + n_ff:])
    else:
        ff, ff_next = ca.SX(0.0), ca.SX(0, 1)
    u, p, integral, d, e, dpv = pid_update(CASADI_OPS, (Kc, Ti, Td, Tf, b), (u_min, u_max), dt,
                                           x[0], x[1], x[2], x[4], sp, pv, ff)
    return ca.Function("pp_parametric_step", [x, sp, pv, prm],
                       [u, p, integral, d, ff, ca.vertcat(integral, e, pv, sp, dpv, ff_next)],
                       ["state", "setpoint", "pv", "params"], ["u", "p", "i", "d", "ff", "state_next"])
