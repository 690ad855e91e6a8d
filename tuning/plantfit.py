"""A plant from a measured step response: first or second order with dead time, fitted by least squares.

:func:`fit_plant` reads a step response (a CSV of time, input and output as
:func:`~piezopreload.core.tables.read_record` reads it: ``time_s,input_V,force_N``, say), finds the
input's step, and fits ``K e^{-L s} / (T s + 1)`` (``order=1``; the dead time on a grid, ``T`` by a
scalar search, ``K`` in closed form: :func:`~piezopreload.tuning.fopdt.fit_first_order`) or
``K e^{-L s} / ((T1 s + 1)(T2 s + 1))`` (``order=2``, started from the first-order fit, refined by
scipy's ``least_squares`` with ``K`` in closed form). ``order="auto"`` keeps the second order where
it halves the first order's residual's mean square. The result (:class:`FittedPlant`) gives the
python-control transfer function and its delay (``autotune`` takes it as it is) and plots the fit.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import control
import numpy as np
from scipy.optimize import least_squares

from piezopreload.core.errors import InputError
from piezopreload.core.tables import MeasuredRecord, read_record
from piezopreload.tuning.fopdt import fit_first_order

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["FittedPlant", "fit_plant", "read_frequency_response"]


@dataclass(frozen=True, eq=False)
class FittedPlant:
    """A fitted step response: gain ``K`` (output per input), time constants ``T_s`` (one or two), dead time, the
    fit's RMS residual (output units) and what it was fitted to (``t_s`` from the step, input step, response).

    Parameters
    ----------
    K : float
        The steady-state gain, output per input.
    T_s : tuple of float
        The time constants, one (first order) or two (second order), largest first (s).
    delay_s : float
        The dead time (s).
    rms : float
        The fit's RMS residual, in the output's unit.
    step : float
        The size of the input step.
    t_s : ndarray
        The sample times from the step (s).
    response : ndarray
        The measured response from its level before the step, in the output's unit.
    source : str
        The file (or record) it was fitted to.
    output_name : str
        The output column's name (its unit after the last underscore).
    """

    K: float
    T_s: tuple[float, ...]
    delay_s: float
    rms: float
    step: float
    t_s: np.ndarray
    response: np.ndarray
    source: str
    output_name: str = "output"

    @property
    def order(self) -> int:
        """The model's order: the number of time constants."""
        return len(self.T_s)

    def transfer_function(self) -> control.TransferFunction:
        """``K / prod(T s + 1)``; the delay is :attr:`delay_s`.

        Returns
        -------
        control.TransferFunction
            The model without its delay, ``K / prod(T_i s + 1)``.
        """
        den = np.array([1.0])
        for T in self.T_s:
            den = np.polymul(den, [T, 1.0])
        return control.tf([self.K], den)

    def model_response(self, t_s: np.ndarray) -> np.ndarray:
        """The fitted model's response to the measured input step at ``t_s`` (from the step).

        Parameters
        ----------
        t_s : ndarray
            Times from the step, in s.

        Returns
        -------
        ndarray
            The model's output change at each time, in the output's unit (0 before the delay).
        """
        return self.K * self.step * _unit_response(np.asarray(t_s, float), self.delay_s, self.T_s)

    def __repr__(self) -> str:
        lags = " ".join(f"({T:.4g} s + 1)" for T in self.T_s)
        return (f"FittedPlant({self.K:.4g} e^(-{self.delay_s:.4g} s) / {lags}; RMS residual {self.rms:.3g}, "
                f"{self.t_s.size} samples of {self.source})")

    def to_dict(self) -> dict[str, Any]:
        """The fit, as ``autotune --json`` prints it under ``fit``.

        Returns
        -------
        dict
            ``K``, ``T_s`` (s), ``delay_s`` (s), ``order``, ``rms`` (the output's unit), ``step``, ``samples`` and
            ``source``.
        """
        return {"K": self.K, "T_s": list(self.T_s), "delay_s": self.delay_s, "order": self.order, "rms": self.rms,
                "step": self.step, "samples": int(self.t_s.size), "source": self.source}

    def plot(self) -> Figure:
        """The measured response and the fit over it: a Figure.

        Returns
        -------
        matplotlib.figure.Figure
            The measured response and the model's against the time from the step.
        """
        from matplotlib.figure import Figure

        fig = Figure(figsize=(6.0, 3.4), layout="constrained")
        ax = fig.add_subplot()
        ax.plot(self.t_s, self.response, color="0.4", lw=1.0, label="measured")
        ax.plot(self.t_s, self.model_response(self.t_s), color="C3", lw=1.2,
                label=f"fit, order {self.order} (RMS {self.rms:.3g})")
        ax.set_xlabel("time from the step (s)")
        ax.set_ylabel(f"{self.output_name} change")
        ax.legend(loc="lower right", fontsize=8)
        ax.grid(True, alpha=0.3)
        return fig


def _unit_response(t: np.ndarray, L: float, T: tuple[float, ...]) -> np.ndarray:
    tau = np.maximum(t - L, 0.0)
    if len(T) == 1:
        return -np.expm1(-tau / T[0])
    T1, T2 = T
    if abs(T1 - T2) <= 1e-9 * max(T1, T2):  # a double pole
        return 1.0 - (1.0 + tau / T1) * np.exp(-tau / T1)
    return 1.0 - (T1 * np.exp(-tau / T1) - T2 * np.exp(-tau / T2)) / (T1 - T2)


def _step_of(record: MeasuredRecord) -> tuple[np.ndarray, np.ndarray, float]:
    """The response from the input's step on (time from the step, output change) and the step's size."""
    u, y, t = record.input, record.output, record.time_s
    du = float(u[-1] - u[0])
    if abs(du) <= 1e-12 * max(1.0, float(np.max(np.abs(u)))):
        raise InputError(f"{record.path}: the input ({record.input_name}) does not step: it starts and ends at "
                         f"{u[0]:g}; expected a step from one level to another")
    k = int(np.flatnonzero(np.abs(u - u[0]) > 0.5 * abs(du))[0])
    y0 = float(np.mean(y[:k])) if k > 0 else float(y[0])
    t_rel, resp = t[k:] - t[k], y[k:] - y0
    if t_rel.size < 10:
        raise InputError(f"{record.path}: {t_rel.size} samples after the step at {t[k]:g} s; expected at least 10")
    return t_rel, resp, du


def fit_plant(source: str | Path | MeasuredRecord, *, order: int | str = "auto") -> FittedPlant:
    """Fit a step response (a CSV path or a :class:`~piezopreload.core.tables.MeasuredRecord`); see the module
    docstring.

    Parameters
    ----------
    source : str, Path or MeasuredRecord
        The step test: a CSV of time, input and output (the input steps once), or its record.
    order : {1, 2, 'auto'}
        The model's order: first or second order plus dead time, or the second where it halves the first's
        squared residual.

    Returns
    -------
    FittedPlant
        The fitted model and what it was fitted to.

    Raises
    ------
    InputError
        For an order that is not one of these, or a record with no step or too few samples after it.
    """
    if order not in (1, 2, "auto"):
        raise InputError(f"order must be 1, 2 or 'auto', got {order!r}")
    record = source if isinstance(source, MeasuredRecord) else read_record(source, min_samples=12)
    t, y, du = _step_of(record)
    span = float(t[-1])
    dt = float(np.min(np.diff(t)))
    thetas = np.linspace(0.0, 0.5 * span, min(400, max(20, int(0.5 * span / dt) + 1)))
    first = fit_first_order(t, y, du, thetas, (max(dt / 10.0, 1e-9), 10.0 * span), refine=True)
    fits = [FittedPlant(first.K, (first.T_s,), first.theta_s, first.rms_N, du, t, y, record.path, record.output_name)]
    if order in (2, "auto"):
        fits.append(_second_order(t, y, du, fits[0], record))
    if order == "auto":
        return fits[1] if fits[1].rms**2 < 0.5 * fits[0].rms**2 else fits[0]
    return fits[-1]


def _second_order(t: np.ndarray, y: np.ndarray, du: float, first: FittedPlant, record: MeasuredRecord) -> FittedPlant:
    span = float(t[-1])

    def residual(p: np.ndarray) -> np.ndarray:
        phi = du * _unit_response(t, p[0], (float(np.exp(p[1])), float(np.exp(p[2]))))
        K = float(phi @ y) / max(float(phi @ phi), 1e-300)
        return K * phi - y

    T = first.T_s[0]
    x0 = np.array([first.delay_s * 0.6, np.log(0.7 * T), np.log(0.3 * T + 1e-12)])
    res = least_squares(residual, x0, bounds=([0.0, np.log(1e-9 + 1e-6 * T), np.log(1e-9 + 1e-6 * T)],
                                              [0.5 * span, np.log(10 * span), np.log(10 * span)]))
    L, T1, T2 = float(res.x[0]), float(np.exp(res.x[1])), float(np.exp(res.x[2]))
    phi = du * _unit_response(t, L, (T1, T2))
    K = float(phi @ y) / max(float(phi @ phi), 1e-300)
    rms = float(np.sqrt(np.mean((K * phi - y) ** 2)))
    return FittedPlant(K, tuple(sorted((T1, T2), reverse=True)), L, rms, du, t, y, record.path, record.output_name)


def read_frequency_response(path: str | Path) -> control.FrequencyResponseData:
    """A measured frequency response from a CSV: the frequency as ``omega_rad_per_s`` or ``frequency_Hz``, the
    response as ``magnitude`` and ``phase_deg`` or as ``real`` and ``imag``; an :class:`InputError` names the file,
    the line and what is missing."""
    from piezopreload.core.tables import read_table

    cols = read_table(path, (), ("omega_rad_per_s", "frequency_Hz", "magnitude", "phase_deg", "real", "imag"))
    if "omega_rad_per_s" in cols:
        omega = cols["omega_rad_per_s"]
    elif "frequency_Hz" in cols:
        omega = 2.0 * np.pi * cols["frequency_Hz"]
    else:
        raise InputError(f"{path}: no frequency column; expected omega_rad_per_s or frequency_Hz in the header")
    if "magnitude" in cols and "phase_deg" in cols:
        data = cols["magnitude"] * np.exp(1j * np.radians(cols["phase_deg"]))
    elif "real" in cols and "imag" in cols:
        data = cols["real"] + 1j * cols["imag"]
    else:
        raise InputError(f"{path}: no response columns; expected magnitude and phase_deg, or real and imag")
    bad = np.flatnonzero(~(np.diff(omega) > 0))
    if bad.size:
        raise InputError(f"{path}: the frequencies must be strictly increasing (data row {int(bad[0]) + 2} is not "
                         "above the one before)")
    if np.any(omega <= 0):
        raise InputError(f"{path}: the frequencies must be > 0 (data row {int(np.flatnonzero(omega <= 0)[0]) + 1})")
    return control.frd(data, omega)
