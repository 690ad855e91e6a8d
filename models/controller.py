"""The controller step: PID in the form of LabVIEW's PID VIs, plus a pluggable feedforward.

One definition (:class:`ControllerModel`, over the ops table of :mod:`piezopreload.models.ops`)
runs in the numpy simulation, in the compiled simulation, in the tuning NLP, in the rig
executor's compiled step and in the exported C code. The PID follows NI's documented algorithm
(PID Control Toolkit, 371685C, "PID Algorithms"), ideal/ISA form
``u = Kc (e + 1/Ti int e dt + Td de/dt)``:

* proportional action ``Kc (b SP - PV)`` (setpoint weight ``b``, 1 in LabVIEW);
* trapezoidal integration ``Kc / Ti * sum (e_k + e_{k-1}) / 2 * dt``;
* derivative on the measurement only (no derivative kick), ``-Kc Td d(PV)/dt``, optionally
  through a first-order filter of time constant ``Tf`` (``filter_order`` 1, the default);
* or (``filter_order`` 2) the measurement itself through the second-order filter
  ``F = 1/(1 + Tf s + (Tf s)^2/2)`` (Garpinger, Hägglund and Åström 2012, as the autotuner tunes it), the
  proportional, integral and derivative actions all acting on the filtered measurement ``y_f`` and the derivative
  being the filter's own second state ``d(y_f)/dt`` (:func:`measurement_filter2`): from the measurement to the
  output this is ``(Kc + Kc/(Ti s) + Kc Td s) F(s)`` mapped by Tustin's rule at the sample period, exactly;
* output clamped to ``[u_min, u_max]`` with conditional integration as anti-windup (the
  integral does not move in the direction that drives the output further into its limit).

The feedforward adds, before the clamp, the output of an inverse hysteresis model of the
setpoint (a *feedforward component*: :class:`FeedforwardStep`, the one inverse step
:class:`~piezopreload.models.hysteresis.InverseStep` of the classical, modified or asymmetric
P-I model, with or without creep) and an external feedforward
signal ``ff_extra`` given per sample (0 unless a caller supplies one: a learned or previewed
correction, or the tuning's precomputed inverse).

A gain schedule (:class:`GainSchedule`) makes ``Kc``, ``Ti``, ``Td`` and the setpoint weight
``b`` functions of the setpoint: linear interpolation between a table's entries, constant beyond
its ends (:meth:`ControllerModel.gains_at`). The integral state is the integral *action* in volts, so a
change of gains, scheduled or switched, moves no state: the output stays continuous.

Times are in seconds inside; LabVIEW enters ``Ti`` and ``Td`` in minutes, converted only by
:meth:`PIDGains.from_labview` and :meth:`PIDGains.labview`. Every operation broadcasts, so
the state may hold a batch of independent loops.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any, Protocol

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezopreload.core.errors import InputError
from piezopreload.core.records import Checked, Invalid, UnitKey, checked, entry
from piezopreload.models.ops import CASADI, NUMPY, Layout, Ops

__all__ = ["PIDGains", "GainSchedule", "SCHEDULE_MAX", "Controller", "ControllerState", "ControllerModel", "Terms",
           "Feedforward", "FeedforwardStep", "pid_update", "pid_law", "measurement_filter2", "FILTER_ORDERS",
           "controller_functions", "OUTPUT_MIN_V", "OUTPUT_MAX_V", "INTEGRAL_TIME", "TIME_UNITS"]

#: the controller's output range where nothing else sets one (V): the paper's closed loop drives its amplifier over
#: 0-110 V; the study's ``[controller]``, the tuning, the interlocks and the exports all start from these
OUTPUT_MIN_V, OUTPUT_MAX_V = 0.0, 110.0




#: the derivative filters the controller step runs: 1, first order on the derivative; 2, second order on the measurement
FILTER_ORDERS = (1, 2)


def pid_law(ops: Any, gains: Any, u_range: tuple[Any, Any], dt: Any, integral: Any, e_prev: Any, sp: Any, y: Any,
            dy: Any, ff: Any) -> tuple[Any, ...]:
    """The PID's output from the measurement ``y`` and its derivative ``dy`` as the filter gives them.

    ``gains = (Kc, Ti, Td, Tf, b)`` (``Tf`` unused here). Returns ``(u, p, i, d, e)``: the clamped output, its
    proportional, integral (the new integral action) and derivative parts, and this sample's error ``sp - y``.
    """
    Kc, Ti, Td, _, b = gains
    u_min, u_max = u_range
    e = sp - y
    proportional = Kc * (b * sp - y)
    derivative = -Kc * Td * dy
    increment = Kc / Ti * 0.5 * (e + e_prev) * dt  # 0 for Ti = inf
    trial = proportional + integral + increment + derivative + ff
    # conditional integration: no integrating further into a limit
    winding = ops.logical_or(ops.logical_and(trial > u_max, increment > 0),
                             ops.logical_and(trial < u_min, increment < 0))
    integral = integral + ops.where(winding, 0.0 * increment, increment)
    u = ops.minimum(ops.maximum(proportional + integral + derivative + ff, u_min), u_max)
    return u, proportional, integral, derivative, e


def pid_update(ops: Any, gains: Any, u_range: tuple[Any, Any], dt: Any, integral: Any, e_prev: Any,
               pv_prev: Any, dpv: Any, sp: Any, pv: Any, ff: Any) -> tuple[Any, ...]:
    """One sample of the PID with the first-order derivative filter, on numpy arrays or CasADi expressions (``ops``).

    ``gains = (Kc, Ti, Td, Tf, b)``. Returns ``(u, p, i, d, e, dpv)``: the clamped output, its
    proportional, integral (the new integral action) and derivative parts, this sample's error
    and filtered derivative of the measurement. See the module docstring for the algorithm.
    """
    Tf = gains[3]
    alpha = Tf / (Tf + dt)  # backward-Euler first-order filter; 0 when Tf = 0
    dpv = alpha * dpv + (1.0 - alpha) * (pv - pv_prev) / dt
    u, proportional, integral, derivative, e = pid_law(ops, gains, u_range, dt, integral, e_prev, sp, pv, dpv, ff)
    return u, proportional, integral, derivative, e, dpv


def measurement_filter2(Tf: Any, dt: Any, y: Any, dy: Any, pv_prev: Any, pv: Any) -> tuple[Any, Any]:
    """One sample of the second-order filter ``F = 1/(1 + Tf s + (Tf s)^2/2)`` on the measurement, by Tustin's rule.

    The filter as two states, ``y`` (the filtered measurement) and ``dy = dy/dt``: ``dy/dt = dy``,
    ``d(dy)/dt = 2 (pv - y - Tf dy) / Tf^2``, advanced by the trapezoidal rule ``x_k = x_{k-1} + dt/2 (f_{k-1} +
    f_k)``, solved for ``x_k`` (linear, closed form below, written over ``Tf^2`` so a small ``Tf`` stays exact). From
    ``pv`` to ``y`` it is ``F`` at ``s = 2/dt (z - 1)/(z + 1)``, and to ``dy`` ``s F(s)`` there: each exactly the
    continuous filter's response at the warped frequency ``2/dt tan(w dt/2)``. Needs ``Tf > 0``.

    Returns
    -------
    tuple
        ``(y, dy)`` after this sample's measurement ``pv`` (``pv_prev`` the last one).
    """
    h, T2 = dt, Tf * Tf
    r1 = y + 0.5 * h * dy  # (I + h/2 A) x_{k-1} + h/2 B (u_{k-1} + u_k), times Tf^2 in its second row
    r2 = T2 * dy - h * y - h * Tf * dy + h * (pv_prev + pv)
    D = T2 + h * Tf + 0.5 * h * h  # Tf^2 det(I - h/2 A)
    return ((T2 + h * Tf) * r1 + 0.5 * h * r2) / D, (r2 - h * r1) / D


class FeedforwardStep(Protocol):
    """A feedforward component's real-time step, over an ops table (the controller's plug-in).

    ``kind`` names it; ``params`` is the layout of its parameter vector; ``n_states`` the size of
    its state; ``rest_state(ops, params)`` its state before the first sample;
    ``step(ops, params, state, target) -> (output, next_state)`` one sample for the setpoint
    ``target``. Equal structures (frozen dataclasses) compile to the same code.
    """

    kind: str

    @property
    def params(self) -> Layout: ...

    @property
    def n_states(self) -> int: ...

    def rest_state(self, ops: Ops, params: Any) -> Any: ...

    def step(self, ops: Ops, params: Any, state: Any, target: Any) -> tuple[Any, Any]: ...


class Feedforward(Protocol):
    """An inverse hysteresis model: ``step(state, target) -> (input, state)`` on numpy, and
    ``realtime() -> (FeedforwardStep, parameter vector)`` for the controller step."""

    def step(self, state: Any, target: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray[np.float64]: ...

    def realtime(self) -> tuple[Any, NDArray[np.float64]]: ...



def _finite(name: str, value: float) -> float:
    x = float(value)
    if not np.isfinite(x):
        raise ValueError(f"{name} must be finite, got {value!r}.")
    return x


#: the most entries a gain schedule may have (each entry is five numbers of the compiled step's parameters)
SCHEDULE_MAX = 32


def _interpolate(ops: Ops, levels: Any, values: Any, n: int, x: Any) -> Any:
    """``values`` linear in ``x`` between ``levels``, constant beyond the ends, over ``ops``.

    Written as ``v_0 + sum_i s_i (clip(x, L_i, L_{i+1}) - L_i)`` with ``s_i`` the slope of
    segment ``i``: min/max only, so it is one expression on numpy and in CasADi (and C).
    """
    def at(v: Any, i: int) -> Any:
        return v[i] if ops.symbolic else v[..., i]

    out = at(values, 0) + 0.0 * x
    for i in range(n - 1):
        lo, hi = at(levels, i), at(levels, i + 1)
        slope = (at(values, i + 1) - at(values, i)) / (hi - lo)
        out = out + slope * (ops.minimum(ops.maximum(x, lo), hi) - lo)
    return out


@dataclass(frozen=True)
class GainSchedule:
    """``Kc``, ``Ti``, ``Td`` and the setpoint weight ``b`` scheduled on the setpoint (the preload level).

    Between two entries each gain is linear in the setpoint; below the first level and above the
    last it keeps the end entry's value. ``Tf`` and the output range are the :class:`PIDGains`'
    own (single), and so is ``b`` where the table has no column of its own (``b=None``).

    Parameters
    ----------
    levels_N : tuple of float
        The setpoints of the entries (N), finite and strictly increasing; 2 to :data:`SCHEDULE_MAX`.
    Kc : tuple of float
        Controller gain per entry (V/N), finite.
    Ti_s : tuple of float
        Integral time per entry (s), finite and > 0 (interpolated as a time).
    Td_s : tuple of float
        Derivative time per entry (s), finite and >= 0.
    b : tuple of float or None
        Setpoint weight per entry, finite (each entry's is tuned with it); None: the single ``b``.
    """

    levels_N: tuple[float, ...]
    Kc: tuple[float, ...]
    Ti_s: tuple[float, ...]
    Td_s: tuple[float, ...]
    b: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        n = len(self.levels_N)
        if not 2 <= n <= SCHEDULE_MAX:
            raise ValueError(f"schedule.levels_N must have 2 to {SCHEDULE_MAX} entries, got {n}.")
        for name in ("levels_N", "Kc", "Ti_s", "Td_s") + (() if self.b is None else ("b",)):
            values = tuple(float(x) for x in getattr(self, name))
            object.__setattr__(self, name, values)
            if len(values) != n:
                raise ValueError(f"schedule.{name} must have one entry per level ({n}), got {len(values)}.")
            if not all(np.isfinite(values)):
                raise ValueError(f"schedule.{name} must be finite, got {list(values)!r}.")
        if not all(b > a for a, b in zip(self.levels_N, self.levels_N[1:])):
            raise ValueError(f"schedule.levels_N must be strictly increasing, got {list(self.levels_N)!r}.")
        if not all(t > 0 for t in self.Ti_s):
            raise ValueError(f"schedule.Ti_s must be > 0 (finite: it is interpolated), got {list(self.Ti_s)!r}.")
        if not all(t >= 0 for t in self.Td_s):
            raise ValueError(f"schedule.Td_s must be >= 0, got {list(self.Td_s)!r}.")

    @property
    def size(self) -> int:
        return len(self.levels_N)

    def at(self, setpoint_N: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """``(Kc, Ti_s, Td_s)`` at ``setpoint_N`` (numpy), the step's interpolation."""
        x = np.asarray(setpoint_N, float)
        lv = np.asarray(self.levels_N)
        Kc, Ti, Td = (np.asarray(_interpolate(NUMPY, lv, np.asarray(v), self.size, x), np.float64)
                      for v in (self.Kc, self.Ti_s, self.Td_s))
        return Kc, Ti, Td

    def b_at(self, setpoint_N: ArrayLike, single: float) -> NDArray[np.float64]:
        """The setpoint weight at ``setpoint_N`` (numpy): the table's column interpolated, or ``single`` without one."""
        x = np.asarray(setpoint_N, float)
        column = np.full(self.size, float(single)) if self.b is None else np.asarray(self.b)
        return np.asarray(_interpolate(NUMPY, np.asarray(self.levels_N), column, self.size, x), np.float64)

    def to_dict(self) -> dict[str, Any]:
        return {"levels_N": list(self.levels_N), "Kc_V_per_N": list(self.Kc), "Ti_s": list(self.Ti_s),
                "Td_s": list(self.Td_s), **({} if self.b is None else {"b": list(self.b)}),
                "interpolation": SCHEDULE_INTERPOLATION}


#: how every format states the schedule's interpolation
SCHEDULE_INTERPOLATION = ("Kc, Ti, Td and the setpoint weight b linear in the setpoint between entries, the end "
                          "entries' values beyond them (b single where the table has no b column); Tf and the output "
                          "range single; the integral state is the integral action (V), so a change of gains does not "
                          "jump the output")


#: what an integral time takes (its rule is :meth:`PIDGains.check`'s)
INTEGRAL_TIME = "a number > 0, or inf for no integral action"


def _integral_time(value: Any) -> float:
    """An integral time as a study's table enters it: a finite number > 0 (a ``ValueError`` otherwise). A study's
    gains go into JSON records and exports, which hold no infinity: no integral action is for gains made in code."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < float(value) < np.inf:
        raise ValueError(value)
    return float(value)


#: the unit ``[controller]`` enters ``Ti`` and ``Td`` in: seconds, or LabVIEW's minutes
TIME_UNITS = UnitKey("units", "the unit Ti and Td are entered in (LabVIEW's PID takes minutes); minutes are "
                     "converted to seconds as the file is read",
                     (("seconds", 1.0), ("minutes", 60.0)), ("Ti_s", "Td_s"))


@checked
class PIDGains(Checked):
    """PID gains and output range, SI units: the study's ``[controller]`` table is read straight into them, its
    ``Ti`` and ``Td`` entered in ``units`` (seconds, or LabVIEW's minutes) and held in seconds."""

    Kc: float = entry("Controller gain, output units per measured unit (V/N for the preload loop).", unit="V/N")
    Ti_s: float = entry("Integral time in s; inf for no integral action, in code (a study's [controller] enters it "
                        "as Ti, in its units, finite).", name="Ti", read=_integral_time, takes="a number > 0")
    Td_s: float = entry("Derivative time in s, 0 for no derivative action (a study's [controller] enters it as Td, "
                        "in its units).", name="Td",
                        default=0.0, ge=0, required=True)
    Tf_s: float = entry("Time constant of the derivative filter (0: unfiltered; > 0 for filter_order 2).",
                        default=0.0, unit="s", ge=0)
    b: float = entry("Setpoint weight of the proportional action (1: error feedback, as LabVIEW).", default=1.0)
    u_min_V: float = entry("The controller's lowest output (default: the paper's 0 V).", default=OUTPUT_MIN_V,
                           unit="V")
    u_max_V: float = entry("The controller's highest output (default: the paper's 110 V).", default=OUTPUT_MAX_V,
                           unit="V")
    schedule: GainSchedule | None = entry("Kc, Ti and Td scheduled on the setpoint; the step then uses the table, and "
                                          "the single Kc, Ti_s, Td_s are the set it was chosen against (the robust "
                                          "set), kept for the record. None: one set.", default=None)
    filter_order: int = entry("1: the derivative through the first-order filter 1/(Tf s + 1), backward Euler; 2: "
                              "the measurement through 1/(1 + Tf s + (Tf s)^2/2), Tustin's rule "
                              "(measurement_filter2).", default=1, ge=1, le=2)

    #: the fields a study's ``[controller]`` table gives
    TABLE_KEYS = ("Kc", "Ti_s", "Td_s", "Tf_s", "b", "u_min_V", "u_max_V")

    def check(self) -> None:
        """The rules between fields: an integral time > 0 (inf: none), the output range's order, the second-order
        filter's time constant, a schedule's type."""
        try:
            integral_time = float(self.Ti_s)
        except (TypeError, ValueError):
            integral_time = float("nan")
        if isinstance(self.Ti_s, bool | str) or not integral_time > 0:
            raise Invalid("Ti_s", f"must be {INTEGRAL_TIME}, got {self.Ti_s!r}", "PIDGains")
        if not self.u_min_V < self.u_max_V:
            raise Invalid("u_max_V", f"must be above u_min_V ({self.u_min_V:g} V), got {self.u_max_V:g}", "PIDGains")
        if self.filter_order == 2 and not self.Tf_s > 0:
            raise Invalid("Tf_s", f"must be > 0 for filter_order 2 (the second-order filter), got {self.Tf_s!r}",
                          "PIDGains")
        if self.schedule is not None and not isinstance(self.schedule, GainSchedule):
            raise Invalid("schedule", f"must be a GainSchedule or None, got {type(self.schedule).__name__}",
                          "PIDGains")

    def at(self, setpoint_N: ArrayLike) -> tuple[Any, Any, Any]:
        """``(Kc, Ti_s, Td_s)`` the step uses at ``setpoint_N``: the schedule's, or the single set.

        Parameters
        ----------
        setpoint_N : array_like
            The setpoint, in N.

        Returns
        -------
        tuple
            The gain ``Kc`` (V/N), ``Ti_s`` and ``Td_s`` (s) at each setpoint: the schedule's, interpolated, or the
            single set's numbers.
        """
        if self.schedule is None:
            return self.Kc, self.Ti_s, self.Td_s
        return self.schedule.at(setpoint_N)

    def b_at(self, setpoint_N: ArrayLike) -> Any:
        """The setpoint weight the step uses at ``setpoint_N``: the schedule's column, or the single ``b``.

        Parameters
        ----------
        setpoint_N : array_like
            The setpoint, in N.

        Returns
        -------
        float or ndarray
            The setpoint weight of the proportional part (no unit) at each setpoint.
        """
        return self.b if self.schedule is None else self.schedule.b_at(setpoint_N, self.b)

    @classmethod
    def from_labview(cls, Kc: float, Ti_min: float, Td_min: float, **kwargs: Any) -> PIDGains:
        """Gains as entered in LabVIEW's PID VIs, whose Ti and Td are in minutes.

        Parameters
        ----------
        Kc : float
            The proportional gain, in V/N.
        Ti_min : float
            The integral time, in minutes.
        Td_min : float
            The derivative time, in minutes.
        **kwargs
            The other fields of :class:`PIDGains` (``b``, ``N``, ...).

        Returns
        -------
        PIDGains
            The gains, their times in s.
        """
        return cls(Kc=Kc, Ti_s=60.0 * Ti_min, Td_s=60.0 * Td_min, **kwargs)

    def labview(self) -> dict[str, float]:
        """Kc, Ti and Td (minutes) for LabVIEW's PID VIs.

        Returns
        -------
        dict of str to float
            ``Kc`` (V/N), ``Ti_min`` and ``Td_min`` (minutes).
        """
        return {"Kc": self.Kc, "Ti_min": self.Ti_s / 60.0, "Td_min": self.Td_s / 60.0}


@dataclass(frozen=True, eq=False)
class ControllerState:
    """Everything the controller remembers between samples; copy it to branch a simulation.

    ``integral`` is the integral *action* (output units), so a change of ``Kc`` or ``Ti``
    leaves it as it is; ``dpv`` the filtered derivative of the measurement; ``ff`` the state
    of the feedforward's operators; ``pv_filtered`` the filtered measurement (second-order filter only, else None).
    """

    integral: NDArray[np.float64]
    e_prev: NDArray[np.float64]
    pv_prev: NDArray[np.float64]
    sp_prev: NDArray[np.float64]
    dpv: NDArray[np.float64]
    ff: NDArray[np.float64] | None
    pv_filtered: NDArray[np.float64] | None = None


@dataclass(frozen=True, eq=False)
class Terms:
    """One sample's output ``u`` (after the clamp) and its parts before it: ``p + i + d + ff``."""

    u: Any
    p: Any
    i: Any
    d: Any
    ff: Any


@dataclass(frozen=True)
class ControllerModel:
    """The controller step's structure: the PID and an optional feedforward component.

    The numbers (gains, range, sample period, the feedforward model's) are a parameter vector
    (:attr:`params`, :meth:`Controller.parameter_vector`), so one compiled step serves every
    gain set and every model of the same structure. The state layout (:attr:`state`) is
    ``[integral action (V), previous error (N), previous measurement (N), previous setpoint
    (N), filtered d(measurement)/dt (N/s), feedforward state...]``; with the second-order filter
    (``filter_order`` 2) the filtered measurement (N) follows the derivative, before the feedforward's state.
    """

    feedforward: Any = None  # a FeedforwardStep, or None for the PID alone
    schedule_size: int = 0  # entries of the gain schedule; 0 or 1: none (the single Kc, Ti_s, Td_s)
    filter_order: int = 1  # 1: first order on the derivative; 2: second order on the measurement

    def __post_init__(self) -> None:
        if isinstance(self.filter_order, bool) or self.filter_order not in FILTER_ORDERS:
            raise InputError(f"filter_order must be 1 or 2, got {self.filter_order!r}.")
        if int(self.schedule_size) != self.schedule_size or not 0 <= self.schedule_size <= SCHEDULE_MAX:
            raise InputError(f"schedule_size must be a whole number in 0..{SCHEDULE_MAX}, got {self.schedule_size!r}.")

    @property
    def scheduled(self) -> bool:
        return self.schedule_size > 1

    @property
    def n_ff_states(self) -> int:
        return 0 if self.feedforward is None else int(self.feedforward.n_states)

    @cached_property
    def state(self) -> Layout:
        filtered: list[tuple[str, int | None]] = [("pv_filtered_N", None)] if self.filter_order == 2 else []
        return Layout("controller state", [("integral_V", None), ("e_prev_N", None), ("pv_prev_N", None),
                                           ("sp_prev_N", None), ("dpv_N_per_s", None), *filtered,
                                           ("ff", self.n_ff_states)])

    @cached_property
    def params(self) -> Layout:
        n_ff = 0 if self.feedforward is None else self.feedforward.params.size
        fields: list[tuple[str, int | None]] = [
            ("Kc", None), ("Ti_s", None), ("Td_s", None), ("Tf_s", None), ("b", None), ("u_min_V", None),
            ("u_max_V", None), ("dt_s", None), ("ff", n_ff)]
        if self.scheduled:  # the table after everything else: an unscheduled layout is as it was
            n = int(self.schedule_size)
            fields += [("schedule_levels_N", n), ("schedule_Kc", n), ("schedule_Ti_s", n), ("schedule_Td_s", n),
                       ("schedule_b", n)]
        return Layout("controller parameters", fields)

    def gains_at(self, ops: Ops, p: Any, setpoint: Any) -> tuple[Any, Any, Any, Any, Any]:
        """``(Kc, Ti, Td, Tf, b)`` at ``setpoint``: the single set, or the schedule's entries interpolated
        linearly in the setpoint (the ends' values beyond them; :class:`GainSchedule`); ``Tf`` single."""
        if not self.scheduled:
            return p.Kc, p.Ti_s, p.Td_s, p.Tf_s, p.b
        n, lv = int(self.schedule_size), p.schedule_levels_N
        return (_interpolate(ops, lv, p.schedule_Kc, n, setpoint), _interpolate(ops, lv, p.schedule_Ti_s, n, setpoint),
                _interpolate(ops, lv, p.schedule_Td_s, n, setpoint), p.Tf_s,
                _interpolate(ops, lv, p.schedule_b, n, setpoint))

    def _feedforward(self, ops: Ops, p: Any, ff_state: Any, setpoint: Any, ff_extra: Any) -> tuple[Any, Any]:
        if self.feedforward is None:
            return 0.0 * setpoint + ff_extra, ff_state
        out, ff_next = self.feedforward.step(ops, p.ff, ff_state, setpoint)
        return out + ff_extra, ff_next

    def step(self, ops: Ops, params: Any, state: Any, setpoint: Any, pv: Any,
             ff_extra: Any = 0.0) -> tuple[Any, Terms]:
        """One sample: the next state and the output's :class:`Terms` (``u`` clamped)."""
        p, s = self.params.unpack(params), self.state.unpack(state)
        ff, ff_next = self._feedforward(ops, p, s.ff, setpoint, ff_extra)
        gains, u_range = self.gains_at(ops, p, setpoint), (p.u_min_V, p.u_max_V)
        filtered: dict[str, Any] = {}
        if self.filter_order == 2:
            y, dpv = measurement_filter2(p.Tf_s, p.dt_s, s.pv_filtered_N, s.dpv_N_per_s, s.pv_prev_N, pv)
            u, prop, integral, deriv, e = pid_law(ops, gains, u_range, p.dt_s, s.integral_V, s.e_prev_N, setpoint, y,
                                                  dpv, ff)
            filtered = {"pv_filtered_N": y}
        else:
            u, prop, integral, deriv, e, dpv = pid_update(ops, gains, u_range, p.dt_s, s.integral_V, s.e_prev_N,
                                                          s.pv_prev_N, s.dpv_N_per_s, setpoint, pv, ff)
        nxt = self.state.pack(ops, integral_V=integral, e_prev_N=e, pv_prev_N=pv, sp_prev_N=setpoint, dpv_N_per_s=dpv,
                              ff=ff_next, **filtered)
        return nxt, Terms(u=u, p=prop, i=integral, d=deriv, ff=ff)

    def start(self, ops: Ops, params: Any, setpoint: Any, pv: Any, u0: Any, ff_extra: Any = 0.0) -> Any:
        """A state at rest at ``(setpoint, pv)`` whose first output is ``u0`` (a bumpless start).

        The integral takes up ``u0`` less the proportional action and the feedforward at the
        setpoint (the feedforward's operators start at rest and are not advanced).
        """
        p = self.params.unpack(params)
        ff_rest = None if self.feedforward is None else self.feedforward.rest_state(ops, p.ff)
        ff0, _ = self._feedforward(ops, p, ff_rest, setpoint, ff_extra)
        Kc, _, _, _, b = self.gains_at(ops, p, setpoint)
        integral = u0 - Kc * (b * setpoint - pv) - ff0
        filtered = {"pv_filtered_N": pv + 0.0 * setpoint} if self.filter_order == 2 else {}
        return self.state.pack(ops, integral_V=integral, e_prev_N=setpoint - pv, pv_prev_N=pv, sp_prev_N=setpoint,
                               dpv_N_per_s=0.0 * pv, ff=ops.repeat(0.0, 0) if ff_rest is None else ff_rest, **filtered)


@dataclass(frozen=True, eq=False)
class Controller:
    """PID with optional inverse-P-I feedforward of the setpoint, sampled every ``dt_s``.

    The numpy face of :class:`ControllerModel`: the same step, on :class:`ControllerState`.
    """

    gains: PIDGains
    dt_s: float
    feedforward: Any = None  # a Feedforward: an inverse hysteresis model

    def __post_init__(self) -> None:
        if not (np.isfinite(self.dt_s) and self.dt_s > 0):
            raise ValueError(f"dt_s must be a positive sample period, got {self.dt_s!r}.")
        if self.feedforward is not None and not hasattr(self.feedforward, "realtime"):
            raise TypeError(f"{type(self.feedforward).__name__} has no real-time step (realtime()); the controller's "
                            "feedforward is an inverse model such as ClassicalPI.inverse().")

    @cached_property
    def _realtime(self) -> tuple[ControllerModel, NDArray[np.float64]]:
        g = self.gains
        if self.feedforward is None:
            structure, ff = None, np.zeros(0)
        else:
            structure, ff = self.feedforward.realtime()
        sch = g.schedule
        model = ControllerModel(structure, 0 if sch is None else sch.size, g.filter_order)
        table = {} if sch is None else {"schedule_levels_N": np.array(sch.levels_N), "schedule_Kc": np.array(sch.Kc),
                                        "schedule_Ti_s": np.array(sch.Ti_s), "schedule_Td_s": np.array(sch.Td_s),
                                        "schedule_b": np.full(sch.size, g.b) if sch.b is None else np.array(sch.b)}
        params = model.params.numbers(Kc=g.Kc, Ti_s=g.Ti_s, Td_s=g.Td_s, Tf_s=g.Tf_s, b=g.b, u_min_V=g.u_min_V,
                                      u_max_V=g.u_max_V, dt_s=self.dt_s, ff=ff, **table)
        return model, params

    @property
    def model(self) -> ControllerModel:
        """The step's structure."""
        return self._realtime[0]

    def parameter_vector(self) -> NDArray[np.float64]:
        """The numbers the step takes (:attr:`ControllerModel.params`): gains, range, period, feedforward model."""
        return self._realtime[1].copy()

    @property
    def n_feedforward_states(self) -> int:
        return self.model.n_ff_states

    def vector(self, state: ControllerState) -> NDArray[np.float64]:
        """``state`` as the (batched) vector of :attr:`ControllerModel.state`."""
        ff = np.zeros(np.shape(state.integral) + (0,)) if state.ff is None else state.ff
        filtered: dict[str, Any] = {}
        if self.model.filter_order == 2:
            if state.pv_filtered is None:
                raise InputError("the state holds no filtered measurement (pv_filtered), which the second-order "
                                 "filter needs; start it with initial_state")
            filtered = {"pv_filtered_N": state.pv_filtered}
        return self.model.state.numbers(integral_V=state.integral, e_prev_N=state.e_prev, pv_prev_N=state.pv_prev,
                                        sp_prev_N=state.sp_prev, dpv_N_per_s=state.dpv, ff=ff, **filtered)

    def state_from_vector(self, x: ArrayLike) -> ControllerState:
        """The inverse of :meth:`vector` (a batch, or one loop's flat vector)."""
        x = np.asarray(x, float)
        if x.shape[-1:] != (self.model.state.size,):
            raise InputError(f"expected a state of {self.model.state.size} numbers, got shape {x.shape}.")
        s = self.model.state.unpack(x)
        ff = None if self.feedforward is None else np.array(s.ff)
        filtered = np.array(s.pv_filtered_N) if self.model.filter_order == 2 else None
        return ControllerState(np.array(s.integral_V), np.array(s.e_prev_N), np.array(s.pv_prev_N),
                               np.array(s.sp_prev_N), np.array(s.dpv_N_per_s), ff, filtered)

    def state_vector(self, state: ControllerState) -> NDArray[np.float64]:
        """One loop's state as a flat vector (:meth:`vector` of one loop)."""
        return self.vector(state).reshape(-1)

    def initial_state(self, setpoint: ArrayLike, pv: ArrayLike, u0: ArrayLike | None = None) -> ControllerState:
        """A state at rest at ``(setpoint, pv)`` whose first output is ``u0`` (bumpless start).

        Without ``u0`` the integral starts at 0.
        """
        sp, pv = (np.array(x) for x in np.broadcast_arrays(np.asarray(setpoint, float), np.asarray(pv, float)))
        model, params = self._realtime
        state = self.state_from_vector(model.start(NUMPY, params, sp, pv, 0.0 if u0 is None else u0))
        if u0 is None:
            state = replace(state, integral=np.zeros_like(sp))
        return state

    def step(
        self, state: ControllerState, setpoint: ArrayLike, pv: ArrayLike
    ) -> tuple[NDArray[np.float64], ControllerState]:
        """One sample: the command for measurement ``pv`` and ``setpoint``, and the next state."""
        terms, state = self.step_terms(state, setpoint, pv)
        return terms.u, state

    def step_terms(self, state: ControllerState, setpoint: ArrayLike, pv: ArrayLike) -> tuple[Terms, ControllerState]:
        """:meth:`step` with the output's parts, for run logs and figures."""
        model, params = self._realtime
        sp, pv = np.asarray(setpoint, float), np.asarray(pv, float)
        nxt, t = model.step(NUMPY, params, self.vector(state), sp, pv)
        u = np.asarray(t.u, float)
        terms = Terms(u=u, p=np.asarray(t.p, float), i=np.asarray(t.i, float), d=np.asarray(t.d, float),
                      ff=np.broadcast_to(np.asarray(t.ff, float), u.shape))
        return terms, self.state_from_vector(nxt)

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

        # the measurement each acts on: a second-order filter's output (a new one starts where the old one's
        # measurement was), else the measurement itself
        measured = state.pv_prev if state.pv_filtered is None else state.pv_filtered

        def actions(c: Controller,
                    ff_state: NDArray[np.float64] | None) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
            g = c.gains
            Kc, _, Td = g.at(state.sp_prev)  # a schedule's gains at the last setpoint
            y = measured if g.filter_order == 2 else state.pv_prev
            pd = Kc * (g.b_at(state.sp_prev) * state.sp_prev - y) - Kc * Td * state.dpv
            if c.feedforward is None:
                return pd, None
            ff, ff_state = c.feedforward.step(ff_state, state.sp_prev)  # play operators: idempotent at equal input
            return pd + ff, ff_state

        before, _ = actions(self, state.ff)
        same_ff = new.feedforward is self.feedforward
        after, ff_state = actions(new, state.ff if same_ff else
                                  None if new.feedforward is None
                                  else new.feedforward.initial_state(state.sp_prev.shape))
        y_new = measured if new.gains.filter_order == 2 else state.pv_prev
        return replace(state, integral=state.integral + before - after, ff=ff_state, e_prev=state.sp_prev - y_new,
                       pv_filtered=np.array(y_new) if new.gains.filter_order == 2 else None)


def controller_functions(model: ControllerModel, params: ArrayLike | None = None,
                         prefix: str = "pp_controller", *, ff_extra: bool = False) -> tuple[ca.Function, ca.Function]:
    """The controller as CasADi functions ``(initial_state, step)``, for code generation.

    ``initial_state(setpoint, pv, u0[, ff_extra][, params]) -> state`` is
    :meth:`ControllerModel.start`; ``step(state, setpoint, pv[, ff_extra][, params]) -> (u, p, i,
    d, ff, state_next)`` is :meth:`ControllerModel.step`. With ``params`` (numbers) they are
    constants of the code (an export for one gain set); without, an input (one compiled step for
    every gain set). ``ff_extra=True`` makes the external feedforward sample an input (a learned
    signal played back); without it the functions have none (it is 0).
    """
    x = ca.SX.sym("state", model.state.size)
    sp, pv, u0 = ca.SX.sym("setpoint"), ca.SX.sym("pv"), ca.SX.sym("u0")
    extra: Any = ca.SX.sym("ff_extra") if ff_extra else 0.0
    extra_in_ff, extra_names_ff = ([extra], ["ff_extra"]) if ff_extra else ([], [])
    p: Any
    if params is None:
        p = ca.SX.sym("params", model.params.size)
        extra_in, extra_names = [p], ["params"]
    else:
        values = np.asarray(params, float)
        if values.shape != (model.params.size,):
            raise InputError(f"params must be {model.params.size} numbers, got shape {values.shape}.")
        p, extra_in, extra_names = ca.DM(values), [], []
    nxt, t = model.step(CASADI, p, x, sp, pv, extra)
    step = ca.Function(f"{prefix}_step_fn", [x, sp, pv, *extra_in_ff, *extra_in], [t.u, t.p, t.i, t.d, t.ff, nxt],
                       ["state", "setpoint", "pv", *extra_names_ff, *extra_names],
                       ["u", "p", "i", "d", "ff", "state_next"])
    start = model.start(CASADI, p, sp, pv, u0, extra)
    init = ca.Function(f"{prefix}_initial_state_fn", [sp, pv, u0, *extra_in_ff, *extra_in], [start],
                       ["setpoint", "pv", "u0", *extra_names_ff, *extra_names], ["state"])
    return init, step
