"""The rig's compensated loop, linearised: the plant's small-signal frequency response and the
loop's maximum sensitivity.

The feedforward cancels the hysteresis to first order, so what the PID sees around an operating
point is the rig's small-signal response from command to measured force: the amplifier's
first-order lag and the transport delay, the creep's lags, scaled by the local slope of force
over voltage (:func:`small_signal_gains`: lowest right after a reversal, highest far along a
branch and, with a Hertz coupling, at the stiffest force). The rig tuner bounds the maximum
sensitivity of this loop on every plant variant at both slopes, with the constraint rows and
the PID's response of :mod:`piezopreload.tuning.loopshape` (the autotuner's, too).
"""

from __future__ import annotations

import numpy as np

from piezopreload.models.actuator import Plant, hertz_force
from piezopreload.models.controller import OUTPUT_MAX_V, PIDGains
from piezopreload.models.ops import NUMPY
from piezopreload.tuning.loopshape import continuous_pid_response, isa_pid_response, omega_terms, peaks

__all__ = ["plant_frequency_response", "small_signal_gains", "controller_frequency_response", "loop_frequency_response",
           "omega_grid",
           "max_sensitivity"]


def plant_frequency_response(params: Plant, omega: np.ndarray, gain_N_per_V: float) -> np.ndarray:
    """Small-signal response from command to measured force of the discrete rig at ``omega`` (rad/s)."""
    dt = params.sample_period_s
    zi = np.exp(-1j * omega * dt)  # z^-1
    a = np.exp(-dt * 2.0 * np.pi * float(params.amp_bandwidth_Hz))
    amp = (1 - a) * zi / (1 - a * zi) * zi**params.delay_samples
    decay = np.exp(-dt / np.asarray(params.creep_tau_s, float))
    creep = 1 + float(params.creep_per_decade) * np.sum((1 - decay) / (1 - decay * zi[:, None]) - 1, axis=1)
    return gain_N_per_V * amp * creep


def small_signal_gains(params: Plant, force_range_N: tuple[float, float] | None = None) -> tuple[float, float]:
    """The lowest and highest local slope dF/dV of the quasi-static loop over 0..OUTPUT_MAX_V (N/V), or with a Hertz
    coupling over the measured forces ``force_range_N`` (within the stroke).

    Right after a reversal the Bouc-Wen state has slope ``alpha``, so the stroke's slope is
    ``1 - alpha`` (plus the asymmetry); far along a branch it approaches ``1 + 2 kappa v / 100``.
    """
    k = float(params.effective_stiffness_N_per_um) * float(params.stroke_um_per_V)
    k_lo = k
    if params.hertz:  # the nuts' Hertz contacts: softest at the bolts' preload, stiffest at full stroke
        x_top = float(params.stroke_um_per_V) * OUTPUT_MAX_V
        f_top = float(hertz_force(NUMPY, x_top, float(params.effective_stiffness_N_per_um),
                                  float(params.hertz_um_per_N23), float(params.hertz_preload_N)))
        f_lo, f_hi = 0.0, f_top
        if force_range_N is not None:  # the stacks' share of the measured force, inside the stroke
            bolts = float(params.bolt_preload_N)
            f_lo = min(max(force_range_N[0] - bolts, 0.0), f_top)
            f_hi = min(max(force_range_N[1] - bolts, f_lo), f_top)
        k_lo = float(params.local_stiffness_N_per_um(f_lo)) * float(params.stroke_um_per_V)
        k = float(params.local_stiffness_N_per_um(f_hi)) * float(params.stroke_um_per_V)
    lo = k_lo * (1.0 - float(params.bw_alpha))
    hi = k * (1.0 + 2.0 * max(float(params.bw_kappa), 0.0) * OUTPUT_MAX_V / 100.0)
    return lo, hi


def controller_frequency_response(gains: PIDGains, dt: float, omega: np.ndarray) -> np.ndarray:
    """The controller step's response from the measurement to the output (sign flipped) at ``omega`` (rad/s):
    the first-order filter's as the step runs it, or the second-order filter's, which the step runs by Tustin's rule
    (the continuous controller at the warped frequency ``2/dt tan(w dt/2)``)."""
    if gains.filter_order == 2:
        warped = 2.0 / dt * np.tan(np.asarray(omega, float) * dt / 2.0)
        re, im = continuous_pid_response(gains.Kc, gains.Kc / gains.Ti_s, gains.Kc * gains.Td_s, gains.Tf_s, warped, 2)
    else:
        re, im = isa_pid_response([gains.Kc, gains.Ti_s, gains.Td_s, gains.Tf_s], dt, omega_terms(omega, dt))
    return np.asarray(re) + 1j * np.asarray(im)


def loop_frequency_response(gains: PIDGains, params: Plant, omega: np.ndarray, gain_N_per_V: float) -> np.ndarray:
    """The loop transfer ``C G`` at ``omega`` (rad/s), numerically, for reports and checks."""
    return (controller_frequency_response(gains, params.sample_period_s, omega)
            * plant_frequency_response(params, omega, gain_N_per_V))


def omega_grid(dt: float, n: int = 160) -> np.ndarray:
    """``n`` frequencies (rad/s), log-spaced from 0.05 Hz to just below the Nyquist frequency of ``dt``."""
    return np.logspace(np.log10(2 * np.pi * 0.05), np.log10(0.999 * np.pi / dt), n)


def max_sensitivity(gains: PIDGains, params: Plant, force_range_N: tuple[float, float] | None = None) -> float:
    """The largest ``|S|`` of the linearised loop at both ends of the local slope, on a 2,000-point grid."""
    dt = params.sample_period_s
    omega = omega_grid(dt, 2000)
    c = controller_frequency_response(gains, dt, omega)
    return max(peaks(c, plant_frequency_response(params, omega, s))["Ms"]
               for s in small_signal_gains(params, force_range_N))
