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
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["PIDGains", "ControllerState", "Controller", "Feedforward", "Terms"]


class Feedforward(Protocol):
    """An inverse hysteresis model: ``step(state, target) -> (input, state)``."""

    def step(self, state: NDArray, target: ArrayLike) -> tuple[NDArray, NDArray]: ...

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
    feedforward: Feedforward | None = None

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
        g, dt = self.gains, self.dt_s
        sp = np.asarray(setpoint, float)
        pv = np.asarray(pv, float)
        e = sp - pv
        proportional = g.Kc * (g.b * sp - pv)
        raw = (pv - state.pv_prev) / dt
        alpha = g.Tf_s / (g.Tf_s + dt)  # backward-Euler first-order filter; 0 when Tf = 0
        dpv = alpha * state.dpv + (1.0 - alpha) * raw
        derivative = -g.Kc * g.Td_s * dpv
        if self.feedforward is None:
            ff, ff_state = 0.0, None
        else:
            ff, ff_state = self.feedforward.step(state.ff, sp)
        increment = g.Kc / g.Ti_s * 0.5 * (e + state.e_prev) * dt if np.isfinite(g.Ti_s) else 0.0 * e
        trial = proportional + state.integral + increment + derivative + ff
        # conditional integration: no integrating further into a limit
        winding = ((trial > g.u_max) & (increment > 0)) | ((trial < g.u_min) & (increment < 0))
        integral = state.integral + np.where(winding, 0.0, increment)
        u = np.clip(proportional + integral + derivative + ff, g.u_min, g.u_max)
        terms = Terms(u=u, p=proportional, i=integral, d=derivative, ff=np.broadcast_to(ff, u.shape))
        return terms, ControllerState(integral, e, pv, sp, dpv, ff_state)

    def retune(self, state: ControllerState, gains: PIDGains) -> tuple[Controller, ControllerState]:
        """Switch to new gains without a jump in the output (bumpless gain change).

        The integral absorbs the change of the proportional and derivative actions at the last
        sample, so the next output with unchanged inputs equals the last one.
        """
        old = self.gains
        before = old.Kc * (old.b * state.sp_prev - state.pv_prev) - old.Kc * old.Td_s * state.dpv
        after = gains.Kc * (gains.b * state.sp_prev - state.pv_prev) - gains.Kc * gains.Td_s * state.dpv
        return replace(self, gains=gains), replace(state, integral=state.integral + before - after)
