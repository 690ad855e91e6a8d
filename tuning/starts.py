"""Where the autotuner starts: AMIGO and SIMC on a first-order-plus-dead-time reading of the plant, and a coarse search.

:func:`fotd_of` reads a FOPDT model ``K e^{-L s} / (T s + 1)`` (or, with an integrator, ``Kv e^{-L s} / s``)
off the plant's frequency response at its phase crossover (the frequency where the phase reaches
-180 degrees: ``T`` from the gain there, ``L`` from the phase), the same way for a transfer function
and for its measured response. :func:`rule_starts` applies the AMIGO rules and SIMC to it;
:func:`search_starts` scores a log-spaced grid of gains at once on the design grid (the worst bound
and the Nyquist criterion) and keeps the best stabilising ones: an unstable plant's starts come from
there. Every start is a :class:`~piezopreload.tuning.pidform.PIDController` for the plant of positive gain.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from piezopreload.core.errors import InputError
from piezopreload.tuning.fopdt import FOPDT, amigo, amigo_integrating, simc
from piezopreload.tuning.lti import LinearPlant
from piezopreload.tuning.pidform import PIDController, controller_response

__all__ = ["FOTDReading", "fotd_of", "rule_starts", "search_starts", "reference_frequency"]


@dataclass(frozen=True)
class FOTDReading:
    """``K e^{-L s} / (T s + 1)`` (``integrating``: ``K e^{-L s} / s``, ``T = 0``) read off the response."""

    K: float
    T_s: float
    L_s: float
    integrating: bool


def _phase_crossover(omega: np.ndarray, G: np.ndarray) -> int | None:
    phase = np.unwrap(np.angle(G))
    phase -= 2 * np.pi * np.round(phase[0] / (2 * np.pi))  # start within (-pi, pi]
    below = np.flatnonzero(phase <= -np.pi)
    return None if below.size == 0 else int(below[0])


def reference_frequency(plant: LinearPlant, omega: np.ndarray) -> float:
    """The plant's phase crossover on ``omega`` (rad/s), or the geometric middle of its characteristic frequencies."""
    G = plant.sign * plant.response(omega)
    i = _phase_crossover(omega, G)
    if i is not None:
        return float(omega[i])
    f = plant.characteristic_frequencies()
    return float(np.sqrt(f.min() * f.max()))


def fotd_of(plant: LinearPlant, omega: np.ndarray) -> FOTDReading | None:
    """The FOPDT reading of a stable (or integrating) plant (see the module docstring); None for an unstable one."""
    if plant.unstable_poles:
        return None
    G = plant.sign * plant.response(omega)
    m = plant.integrators
    i = _phase_crossover(omega, G)
    w0 = float(omega[0])
    if m == 1:  # an integrator; without a phase crossover there is no dead time for the rules to work on
        return None if i is None else FOTDReading(float(np.abs(G[0]) * w0), 0.0, np.pi / (2.0 * float(omega[i])), True)
    if m > 1:
        return None
    K = float(np.abs(G[0]))
    if i is None:  # the phase never reaches -180 degrees: a lag with little delay
        j = int(np.argmin(np.abs(np.unwrap(np.angle(G)) + np.pi / 2)))
        T = 1.0 / float(omega[j])
        return FOTDReading(K, T, 0.02 * T, False)
    w180, g180 = float(omega[i]), float(np.abs(G[i]))
    T = float(np.sqrt(max((K / g180) ** 2 - 1.0, 0.0)) / w180)
    L = float((np.pi - np.arctan(w180 * T)) / w180)
    return FOTDReading(K, T, max(L, 1e-3 * max(T, 1.0 / w180)), False)


def _from_isa(name: str, Kc: float, Ti: float, Td: float, filter_order: int,
              dt: float | None) -> list[tuple[str, PIDController]]:
    """The rule's gains as starts: a PI as it is; a PID with a derivative filter of a tenth of ``Td`` and, a second
    start, of ``Td`` itself (the rules have none; the problem has a local optimum of each kind)."""
    if filter_order == 0:
        return [(name, PIDController(Kc, Kc / Ti, 0.0, 0.0, 0, dt))]
    return [(name if k == 0 else f"{name}, slow filter", PIDController(Kc, Kc / Ti, Kc * Td, max(f * Td, 1e-6 * Ti),
                                                                         filter_order, dt))
            for k, f in enumerate((0.1, 1.0))]


def rule_starts(reading: FOTDReading | None, filter_order: int, dt: float | None) -> list[tuple[str, PIDController]]:
    """AMIGO (PI or PID as ``filter_order`` asks) and SIMC PI (with a derivative of a quarter of the dead time for a
    PID) on the reading; none for an unstable plant."""
    if reading is None:
        return []
    form = "PI" if filter_order == 0 else "PID"
    out = []
    try:
        if reading.integrating:
            g = amigo_integrating(reading.K, reading.L_s, form)
            model = FOPDT(reading.K * 100.0 * reading.L_s, 100.0 * reading.L_s, reading.L_s, 0.0)  # SIMC's lag
        else:
            model = FOPDT(reading.K, reading.T_s, reading.L_s, 0.0)
            g = amigo(model, form)
        out += _from_isa("AMIGO", g.Kc, g.Ti_s, g.Td_s, filter_order, dt)
        s = simc(model, u_min_V=-1.0, u_max_V=1.0)
        out += _from_isa("SIMC", s.Kc, s.Ti_s, 0.25 * reading.L_s, filter_order, dt)
    except (InputError, ValueError):  # a reading the rules do not take (a zero time constant, ...)
        pass
    return out


def search_starts(plant: LinearPlant, omega: np.ndarray, G: np.ndarray, bounds: dict[str, float | None],
                  filter_order: int, dt: float | None, keep: int = 3) -> list[tuple[str, PIDController]]:
    """The best ``keep`` of a 24 x 24 (x 3 derivative times) log grid of gains around the reference frequency: the
    stabilising ones that meet every bound on the grid by the largest ``ki``, then the stabilising ones by the worst
    bound (Nyquist on the design grid: a coarse check; the result's is on a fine one)."""
    wr = reference_frequency(plant, omega)
    g_ref = float(np.abs(np.interp(np.log(wr), np.log(omega), np.abs(G))))
    kp = np.logspace(-3, 2, 24) / g_ref
    Ti = np.logspace(-1, 3, 24) / wr
    Td = [0.0] if filter_order == 0 else [0.0, 0.1 / wr, 0.4 / wr]
    P, Q, R = (a.ravel() for a in np.meshgrid(kp, Ti, Td, indexing="ij"))
    ki, kd = P / Q, P * R
    Tf = np.maximum(R / 10.0, 1e-3 / wr)
    re, im = controller_response(P[:, None], ki[:, None], kd[:, None], Tf[:, None], omega[None, :], filter_order, dt)
    C = np.asarray(re) + 1j * np.asarray(im)
    L = C * G[None, :]
    d = np.abs(1 + L)
    ratios = [1 / d / m if name == "Ms" else (np.abs(L) if name == "Mt" else np.abs(C)) / d / m
              for name, m in bounds.items() if m is not None]
    worst = np.max(np.stack([r.max(axis=1) for r in ratios]), axis=0) - 1.0 if ratios else np.zeros(P.size)
    phase = np.unwrap(np.angle(1 + L), axis=1)
    half = phase[:, -1] - phase[:, 0] - (np.angle(1 + L[:, -1]) if dt is None else 0.0)
    turns = (2 * half - (plant.integrators + 1) * np.pi) / (2 * np.pi)
    stable = np.round(plant.unstable_poles - turns) == 0
    if dt is None:
        stable &= np.abs(L[:, -1]) < 1.0
    order = sorted(np.flatnonzero(stable), key=lambda i: (worst[i] > 0, -ki[i] if worst[i] <= 0 else worst[i]))
    return [(f"search {n + 1}", PIDController(float(P[i]), float(ki[i]), float(kd[i]), float(Tf[i]) if kd[i] else 0.0,
                                              filter_order, dt)) for n, i in enumerate(order[:keep])]
