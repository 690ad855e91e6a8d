"""First-order-plus-dead-time models: the least-squares fit of a step response, and the tuning rules on them.

:func:`fit_first_order` fits ``K exp(-theta s) / (T s + 1)`` to a step response (the dead time
on a grid, ``K`` in closed form and ``T`` by a bounded scalar search: variable projection);
:func:`fit_fopdt` applies it to the rig's compensated plant. The rules: Skogestad's SIMC PI
(:func:`simc`, Skogestad 2003) and Åström and Hägglund's AMIGO PI and PID (:func:`amigo`,
:func:`amigo_integrating`; Åström and Hägglund 2004, "Revisiting the Ziegler-Nichols step
response method for PID control", J. Process Control 14; *Advanced PID Control*, 2006,
Sections 7.4-7.5). They start the tuners and are the autotuner's benchmark peer.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from piezopreload.core.errors import InputError
from piezopreload.models.actuator import Rig
from piezopreload.models.closedloop import simulate_open_loop
from piezopreload.models.controller import OUTPUT_MAX_V, OUTPUT_MIN_V, PIDGains

__all__ = ["FOPDT", "fit_first_order", "fit_fopdt", "simc", "amigo", "amigo_integrating"]


@dataclass(frozen=True)
class FOPDT:
    """``K exp(-theta s) / (T s + 1)``: gain (output per input: N/V on the rig), time constant and dead time (s),
    and the fit's RMS residual (output units)."""

    K: float
    T_s: float
    theta_s: float
    rms_N: float


def _fit_at(t: np.ndarray, y: np.ndarray, step: float, theta: float,
            log_T_bounds: tuple[float, float]) -> tuple[float, float, float, np.ndarray]:
    """``(cost, K, T, residual)`` at dead time ``theta``: K enters linearly, so for each T it is
    the least-squares one in closed form and only T is searched (variable projection)."""
    after = t > theta

    def parts(log_T: float) -> tuple[float, float, np.ndarray]:
        phi = step * np.where(after, -np.expm1(-np.maximum(t - theta, 0.0) / np.exp(log_T)), 0.0)
        K = max(float(phi @ y) / max(float(phi @ phi), 1e-300), 1e-6)
        r = K * phi - y
        return 0.5 * float(r @ r), K, r

    from scipy.optimize import minimize_scalar  # loads on first use, not on import

    res = minimize_scalar(lambda log_T: parts(log_T)[0], bounds=log_T_bounds, method="bounded",
                          options={"xatol": 1e-10})
    cost, K, r = parts(float(res.x))
    return cost, K, float(np.exp(res.x)), r


def fit_first_order(t: np.ndarray, y: np.ndarray, step: float, thetas: np.ndarray,
                    T_range_s: tuple[float, float], refine: bool = False) -> FOPDT:
    """Least-squares FOPDT fit of the response ``y`` (from 0 at ``t = 0``) to an input step of ``step``.

    The dead time is the best of ``thetas`` (the residual is not smooth in it) and, with ``refine``, the best
    between that one's neighbours by a bounded scalar search; ``T`` is searched in ``T_range_s``, ``K``
    (>= 1e-6: the response is taken to rise) follows in closed form.
    """
    bounds = (float(np.log(T_range_s[0])), float(np.log(T_range_s[1])))
    fits = [_fit_at(t, y, step, float(th), bounds) for th in thetas]
    best = int(np.argmin([f[0] for f in fits]))
    theta = float(thetas[best])
    if refine and thetas.size > 1:
        lo, hi = float(thetas[max(best - 1, 0)]), float(thetas[min(best + 1, thetas.size - 1)])
        from scipy.optimize import minimize_scalar  # loads on first use, not on import

        res = minimize_scalar(lambda th: _fit_at(t, y, step, th, bounds)[0], bounds=(lo, hi), method="bounded",
                              options={"xatol": 1e-6 * max(hi - lo, 1e-12)})
        if float(res.fun) < fits[best][0]:
            theta = float(res.x)
            fits[best] = _fit_at(t, y, step, theta, bounds)
    _, K, T, residual = fits[best]
    return FOPDT(K=K, T_s=T, theta_s=theta, rms_N=float(np.sqrt(np.mean(residual**2))))


def fit_fopdt(rig: Rig, feedforward: Any, *, level_N: float = 60.0, step_V: float = 5.0,
              window_s: float = 0.5) -> FOPDT:
    """Fit a FOPDT model to the compensated plant's response to a ``step_V`` voltage step.

    The feedforward holds the rig at ``level_N`` (from rest, approached as the step reference
    would), then the PID's output steps by ``step_V``; the noise-free force over ``window_s``
    is fitted by least squares (:func:`fit_first_order`).
    """
    dt = rig.dt_s
    settle = int(round(1.0 / dt))
    n = int(round(window_s / dt))
    v_ff = float(feedforward.step(feedforward.initial_state(), np.array(level_N))[0])
    command = np.concatenate([np.full(settle, v_ff), np.full(n, v_ff + step_V)])
    force = simulate_open_loop(rig, command)["force_N"]  # the true force (the noise only reaches the reading)
    y = force[settle:] - force[settle]
    t = np.arange(n) * dt
    # the creep still drifting from the approach is part of the response here; it is slow
    # against the window, so the fit's rms says how well a FOPDT describes the fast part.
    # The dead time no shorter than the loop's known transport delay (the delay samples plus half
    # a sample for the hold), which the creep's fast lag would otherwise let the fit trade for a longer T
    theta_min = (rig.params.delay_samples + 0.5) * dt
    thetas = np.arange(theta_min, theta_min + 20.0 * dt, 0.1 * dt)
    return fit_first_order(t, y, step_V, thetas, (1e-4, 10.0))


def simc(model: FOPDT, *, tau_c_s: float | None = None, u_min_V: float = OUTPUT_MIN_V,
         u_max_V: float = OUTPUT_MAX_V) -> PIDGains:
    """Skogestad's SIMC PI rule: ``Kc = T / (K (tau_c + theta))``, ``Ti = min(T, 4 (tau_c + theta))``.

    ``tau_c`` defaults to ``theta`` (SIMC's "tight control" choice).
    """
    tau_c = model.theta_s if tau_c_s is None else tau_c_s
    tau_c = max(tau_c, 1e-4)
    Kc = model.T_s / (model.K * (tau_c + model.theta_s))
    Ti = min(model.T_s, 4.0 * (tau_c + model.theta_s))
    return PIDGains(Kc=Kc, Ti_s=Ti, Td_s=0.0, Tf_s=0.0, u_min_V=u_min_V, u_max_V=u_max_V)


def _check_form(form: str) -> None:
    if form not in ("PI", "PID"):
        raise InputError(f"form must be 'PI' or 'PID', got {form!r}")


def amigo(model: FOPDT, form: str = "PID") -> PIDGains:
    """The AMIGO rules (Åström and Hägglund 2004) on a FOPDT model ``K e^{-L s} / (T s + 1)``, ideal/ISA gains.

    PI: ``Kc = 0.15/K + (0.35 - L T / (L + T)^2) T / (K L)``, ``Ti = 0.35 L + 13 L T^2 / (T^2 + 12 L T + 7 L^2)``;
    PID: ``Kc = (0.2 + 0.45 T / L) / K``, ``Ti = (0.4 L + 0.8 T) / (L + 0.1 T) L``, ``Td = 0.5 L T / (0.3 L + T)``.
    They were fitted to the MIGO designs (largest integral gain at a combined sensitivity of 1.4) of
    the test batch; no derivative filter (``Tf = 0``).
    """
    _check_form(form)
    K, T, L = model.K, model.T_s, model.theta_s
    if not (K > 0 and T >= 0 and L > 0):
        raise InputError(f"AMIGO needs K > 0, T >= 0 and L > 0, got K {K!r}, T {T!r} s, L {L!r} s")
    if form == "PI":
        Kc = 0.15 / K + (0.35 - L * T / (L + T) ** 2) * T / (K * L)
        Ti = 0.35 * L + 13.0 * L * T**2 / (T**2 + 12.0 * L * T + 7.0 * L**2)
        return PIDGains(Kc=Kc, Ti_s=Ti)
    Kc = (0.2 + 0.45 * T / L) / K
    Ti = (0.4 * L + 0.8 * T) / (L + 0.1 * T) * L
    Td = 0.5 * L * T / (0.3 * L + T)
    return PIDGains(Kc=Kc, Ti_s=Ti, Td_s=Td)


def amigo_integrating(Kv: float, L_s: float, form: str = "PID") -> PIDGains:
    """The AMIGO rules on an integrating process ``Kv e^{-L s} / s``: PI ``Kc = 0.35 / (Kv L)``, ``Ti = 13.4 L``;
    PID ``Kc = 0.45 / (Kv L)``, ``Ti = 8 L``, ``Td = 0.5 L``."""
    _check_form(form)
    if not (Kv > 0 and L_s > 0):
        raise InputError(f"AMIGO needs Kv > 0 and L > 0, got Kv {Kv!r}, L {L_s!r} s")
    if form == "PI":
        return PIDGains(Kc=0.35 / (Kv * L_s), Ti_s=13.4 * L_s)
    return PIDGains(Kc=0.45 / (Kv * L_s), Ti_s=8.0 * L_s, Td_s=0.5 * L_s)
