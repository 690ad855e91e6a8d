"""Step-response and tracking metrics (Section 4 of the paper).

Two definitions of rise and settling, both measured from the step time and both working for a
step between any two levels (python-control's ``step_info`` assumes the response starts at 0):

* ``band=None``, the conventional ones of MATLAB's ``stepinfo`` and python-control: rise time
  from 10 % to 90 % of the step, settling when the error stays within 2 % of the step size;
* ``band=1.5`` (output units), the paper's: rise time when the response first enters the band
  around the final value, settling when it stays inside it.

Times are read off the samples, without interpolation, as python-control does: they are exact
to one sample period.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["Signal", "SIGNALS", "StepMetrics", "step_metrics", "step_numbers", "run_numbers", "tracking_error"]


class Signal(StrEnum):
    """The force a step's numbers are read on: what the sensor read, or the true force (its value is the run's column
    of it, and what a study file's ``[simulation] signal`` and an artifact write)."""

    MEASURED = "measured_N"
    FORCE = "force_N"

    @property
    def words(self) -> str:
        """The signal in words, as the report and the console say it."""
        return "measured force" if self is Signal.MEASURED else "true force"


#: the signals, in their order
SIGNALS = tuple(Signal)


@dataclass(frozen=True)
class StepMetrics:
    """Metrics of one step from ``initial`` to ``final``; times in s from the step time.

    ``overshoot`` is in output units past ``final`` in the direction of the step, and
    ``overshoot_pct`` the same as a percentage of the step size. A time the response never
    reaches is ``nan``.

    Parameters
    ----------
    initial, final : float
        The levels before and after the step, in the output's unit.
    rise_s : float
        The rise time (s): from 10 % to 90 % of the step (the conventional definition), or until the output is
        within the error band of ``final`` (the paper's).
    peak_s : float
        The time of the peak (s).
    peak : float
        The peak value, in the output's unit.
    settling_s : float
        The time after which the output stays within its band of ``final`` (s).
    overshoot : float
        How far the output passed ``final`` in the direction of the step, in the output's unit.
    overshoot_pct, undershoot_pct : float
        The overshoot, and the swing below ``initial`` against the step, as percentages of the step size.
    """

    initial: float
    final: float
    rise_s: float
    peak_s: float
    peak: float
    settling_s: float
    overshoot: float
    overshoot_pct: float
    undershoot_pct: float

    def to_dict(self) -> dict[str, float]:
        """The metrics by name.

        Returns
        -------
        dict of str to float
            Each field by name, in the unit its name carries.
        """
        return asdict(self)


def _step_samples(t: ArrayLike, y: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """``t`` and ``y`` as float arrays, checked: 1-D, of equal length >= 2, finite, ``t`` strictly increasing."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if t.ndim != 1 or t.shape != y.shape or t.size < 2:
        raise ValueError(f"t and y must be 1-D of equal length >= 2, got {t.shape} and {y.shape}.")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))):
        raise ValueError("t and y must be finite.")
    if np.any(np.diff(t) <= 0):
        raise ValueError("t must be strictly increasing.")
    return t, y


def _first(tt: np.ndarray, mask: np.ndarray) -> float:
    """The first time at which ``mask`` holds; ``nan`` when it never does."""
    idx = np.flatnonzero(mask)
    return float(tt[idx[0]]) if idx.size else float("nan")


def _settling_s(tt: np.ndarray, error: np.ndarray, tolerance: float) -> float:
    """The time from which ``error`` stays within ``tolerance``; ``nan`` when it is still outside at the end."""
    outside = np.flatnonzero(error > tolerance)
    if outside.size == 0:
        return 0.0
    if outside[-1] == tt.size - 1:
        return float("nan")  # still outside at the end of the record
    return float(tt[outside[-1] + 1])


def step_metrics(
    t: ArrayLike,
    y: ArrayLike,
    final: float,
    *,
    initial: float | None = None,
    t_step: float | None = None,
    band: float | None = None,
    rise_limits: tuple[float, float] = (0.1, 0.9),
    settling_threshold: float = 0.02,
) -> StepMetrics:
    """Rise, peak and settling time and overshoot of a step response.

    Parameters
    ----------
    t, y : array_like
        Sample times (s, increasing) and the response.
    final : float
        The level the step goes to (the setpoint, or the steady-state value).
    initial : float, optional
        The level before the step; default ``y`` at the step time.
    t_step : float, optional
        When the step is applied; default ``t[0]``.
    band : float, optional
        Absolute error band (output units) for the paper's definitions; ``None`` for the
        conventional ones (``rise_limits`` and ``settling_threshold`` of the step size).
    """
    t, y = _step_samples(t, y)
    t_step = float(t[0]) if t_step is None else float(t_step)
    after = t >= t_step
    if not after.any():
        raise ValueError(f"t_step = {t_step} is after the last sample {t[-1]}.")
    tt, yy = t[after] - t_step, y[after]
    initial = float(yy[0]) if initial is None else float(initial)
    final = float(final)
    size = final - initial
    if size == 0:
        raise ValueError("final equals initial: there is no step to measure.")
    progress = np.sign(size) * (yy - initial)  # rises from 0 to |size|
    error = np.abs(yy - final)
    if band is None:
        lo, hi = rise_limits
        rise = _first(tt, progress >= hi * abs(size)) - _first(tt, progress >= lo * abs(size))
        tolerance = settling_threshold * abs(size)
    else:
        if not band > 0:
            raise ValueError(f"band must be positive, got {band}.")
        rise = _first(tt, error <= band)
        tolerance = float(band)
    settling = _settling_s(tt, error, tolerance)
    k = int(np.argmax(progress))
    overshoot = max(0.0, float(progress[k]) - abs(size))
    undershoot = max(0.0, -float(np.min(progress)))
    return StepMetrics(
        initial=initial,
        final=final,
        rise_s=rise,
        peak_s=float(tt[k]),
        peak=float(yy[k]),
        settling_s=settling,
        overshoot=overshoot,
        overshoot_pct=100.0 * overshoot / abs(size),
        undershoot_pct=100.0 * undershoot / abs(size),
    )


def tracking_error(
    t: ArrayLike, y: ArrayLike, reference: ArrayLike, *, t_from: float | None = None
) -> dict[str, float]:
    """RMS and maximum absolute tracking error (output units) from ``t_from`` on."""
    t = np.asarray(t, dtype=float)
    e = np.asarray(y, dtype=float) - np.asarray(reference, dtype=float)
    if e.shape != t.shape:
        raise ValueError(f"y and reference must have the shape of t {t.shape}.")
    keep = t >= (t[0] if t_from is None else t_from)
    if not keep.any():
        raise ValueError(f"no samples at or after t_from = {t_from}.")
    return {"rms": float(np.sqrt(np.mean(e[keep] ** 2))), "max": float(np.max(np.abs(e[keep])))}


def step_numbers(m: StepMetrics) -> dict[str, float | None]:
    """Rise, peak and settling time (s) and overshoot (N) of a step as JSON holds them: None where never reached."""
    values = {"rise_s": m.rise_s, "peak_s": m.peak_s, "settling_s": m.settling_s, "overshoot_N": m.overshoot}
    return {k: (float(v) if np.isfinite(v) else None) for k, v in values.items()}


def run_numbers(run: Any, band_N: float, signal: Signal,
                after_change_s: float | None = None) -> dict[str, float | None]:
    """The numbers a single-plant :class:`~piezopreload.models.closedloop.ClosedLoopRun` is scored by.

    The step numbers of the reference's first change (band ``band_N`` on ``signal``), the peak
    command, and the tracking error of the true force from that change on (RMS and maximum; with
    ``after_change_s``, also the RMS outside that long after every change).
    """
    out: dict[str, float | None] = {**step_numbers(run.step_metrics(band_N, signal=signal)),
                                    "peak_command_V": float(np.max(run.command_V))}
    te = run.tracking_error()
    out.update(tracking_rms_N=float(te.rms_N), tracking_max_N=float(te.max_N))
    if after_change_s is not None:
        out["tracking_rms_after_change_N"] = float(run.tracking_error(after_change_s=after_change_s).rms_N)
    return out
