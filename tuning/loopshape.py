"""The loop in the frequency domain, defined once for both tuners: the PID's response and the bounds on |S|, |T|, |KS|.

Both the rig tuner (:func:`~piezopreload.tuning.pid.tune_pid`, Ms on the linearised compensated
loop of every plant variant) and the autotuner (:func:`~piezopreload.tuning.autotune.autotune`,
Ms, Mt and Mks on a user's plant) state their robustness constraints with :func:`bound_rows`
and check them with :func:`peaks`; the PID's frequency response comes from here too:

* :func:`discrete_pid_response`: the controller as the tool runs it at sample period ``dt``
  (:func:`~piezopreload.models.controller.pid_update`: trapezoidal integral, derivative through
  a backward-Euler first-order filter), ``C(e^{j w dt})``;
* :func:`continuous_pid_response`: ``kp + ki/s + kd s / (Tf s + 1)`` (the same controller in
  continuous time) or ``(kp + ki/s + kd s) / (1 + Tf s + (Tf s)^2 / 2)`` (a second-order
  filter on the whole controller, Garpinger, Hägglund and Åström 2012).

Every function is plain arithmetic on real and imaginary parts, so it takes numpy arrays and
CasADi expressions alike: the NLPs differentiate the very expressions the checks evaluate.

A bound ``|X| <= M`` with ``X`` one of ``S = 1/(1 + L)``, ``T = L/(1 + L)``, ``KS = C/(1 + L)``
is the row ``|N_X|^2 / M^2 - |1 + L|^2 <= 0`` with ``N_X`` the numerator ``1``, ``L`` or ``C``:
polynomial in the loop's response, so smooth wherever the loop is, and negative exactly where
the bound holds.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any

import casadi as ca
import numpy as np

__all__ = ["Bound", "BOUNDS", "omega_terms", "discrete_pid_response", "isa_pid_response", "continuous_pid_response",
           "loop_terms", "bound_rows", "bound_numerators", "peaks", "smooth_max"]

class Bound(StrEnum):
    """A bound a loop may carry, by its name (its value, as the results and their JSON write it): ``Ms`` on the
    sensitivity ``|S| = 1/|1 + L|``, ``Mt`` on the complementary sensitivity ``|T| = |L|/|1 + L|``, ``Mks`` on the
    noise sensitivity ``|KS| = |C|/|1 + L|``. Each member knows its magnitude and its numerator."""

    MS = "Ms"
    MT = "Mt"
    MKS = "Mks"

    @property
    def symbol(self) -> str:
        """The magnitude it bounds, as a message writes it: ``|S|``, ``|T|`` or ``|KS|``."""
        return {Bound.MS: "|S|", Bound.MT: "|T|", Bound.MKS: "|KS|"}[self]

    def numerator(self, C: Any, L: Any) -> Any:
        """``|N_X|``: 1 for ``S``, ``|L|`` for ``T``, ``|C|`` for ``KS`` (complex arrays)."""
        return {Bound.MS: 1.0, Bound.MT: np.abs(L), Bound.MKS: np.abs(C)}[self]

    def numerator_squared(self, c_re: Any, c_im: Any, l_re: Any, l_im: Any) -> Any:
        """``|N_X|^2`` from the parts of ``C`` and ``L`` (numbers or CasADi expressions)."""
        if self is Bound.MS:
            return 1.0
        return l_re**2 + l_im**2 if self is Bound.MT else c_re**2 + c_im**2

    def magnitude(self, C: np.ndarray, G: np.ndarray, d: np.ndarray | None = None) -> np.ndarray:
        """``|X|`` of the controller's and the plant's responses ``C`` and ``G``; ``d``: ``|1 + C G|`` where it is
        at hand (the three bounds share it)."""
        L = C * G
        return self.numerator(C, L) / (np.abs(1 + L) if d is None else d)


#: the bounds a loop may carry: maximum sensitivity, complementary sensitivity, noise sensitivity
BOUNDS = tuple(Bound)


def omega_terms(omega: np.ndarray, dt: float) -> np.ndarray:
    """Per frequency, the numbers the discrete controller's response is built from: ``(q_re, q_im, d_re,
    d_im, z_re, z_im)`` with ``z = e^{-j w dt}`` (``z^-1``), ``q = (1 + z) / (1 - z)`` the
    trapezoidal integrator's shape and ``d = 1 - z`` the backward difference; shape ``(6, n)``."""
    zi = np.exp(-1j * np.asarray(omega, float) * dt)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = (1 + zi) / (1 - zi)
    d = 1 - zi
    return np.array([q.real, q.imag, d.real, d.imag, zi.real, zi.imag])


def discrete_pid_response(kp: Any, ki: Any, kd: Any, Tf: Any, dt: Any, w: Any) -> tuple[Any, Any]:
    """Real and imaginary parts of the feedback path ``C(e^{j w dt})`` of the controller step
    (:func:`~piezopreload.models.controller.pid_update`) with parallel gains ``kp = Kc``,
    ``ki = Kc / Ti``, ``kd = Kc Td``, from :func:`omega_terms`' numbers ``w`` (numbers or CasADi
    expressions)."""
    q_re, q_im, d_re, d_im, z_re, z_im = (w[i] for i in range(6))
    alpha = Tf / (Tf + dt)
    # D = kd (1 - alpha) / dt * d / (1 - alpha z)
    den_re = 1 - alpha * z_re
    den_im = -alpha * z_im
    den2 = den_re**2 + den_im**2
    ratio_re = (d_re * den_re + d_im * den_im) / den2
    ratio_im = (d_im * den_re - d_re * den_im) / den2
    gd = kd * (1 - alpha) / dt
    re = kp + ki * dt / 2 * q_re + gd * ratio_re
    im = ki * dt / 2 * q_im + gd * ratio_im
    return re, im


def isa_pid_response(gains: Any, dt: Any, w: Any) -> tuple[Any, Any]:
    """:func:`discrete_pid_response` of the ideal/ISA gains ``(Kc, Ti, Td, Tf)`` (numbers or expressions)."""
    Kc, Ti, Td, Tf = gains[0], gains[1], gains[2], gains[3]
    return discrete_pid_response(Kc, Kc / Ti, Kc * Td, Tf, dt, w)


def continuous_pid_response(kp: Any, ki: Any, kd: Any, Tf: Any, omega: Any, filter_order: int = 1) -> tuple[Any, Any]:
    """Real and imaginary parts of the continuous PID's ``C(j w)``.

    ``filter_order`` 1: ``kp + ki/s + kd s / (Tf s + 1)`` (the derivative filtered, the form the
    controller step runs; ``Tf = 0`` unfiltered); 2: ``(kp + ki/s + kd s) F(s)`` with
    ``F = 1 / (1 + Tf s + (Tf s)^2 / 2)`` on the whole controller; 0: ``kp + ki/s`` (a PI).
    """
    if filter_order == 0:
        return kp + 0.0 * omega, -ki / omega
    if filter_order == 1:
        den = 1 + (Tf * omega) ** 2
        return kp + kd * Tf * omega**2 / den, -ki / omega + kd * omega / den
    if filter_order != 2:
        raise ValueError(f"filter_order must be 0, 1 or 2, got {filter_order!r}")
    n_re, n_im = kp, kd * omega - ki / omega
    f_re, f_im = 1 - (Tf * omega) ** 2 / 2, Tf * omega  # 1 / F
    den = f_re**2 + f_im**2
    return (n_re * f_re + n_im * f_im) / den, (n_im * f_re - n_re * f_im) / den


def loop_terms(c_re: Any, c_im: Any, g_re: Any, g_im: Any) -> tuple[Any, Any, Any]:
    """``(L_re, L_im, |1 + L|^2)`` of the loop ``L = C G`` from the parts of ``C`` and ``G``."""
    l_re = c_re * g_re - c_im * g_im
    l_im = c_re * g_im + c_im * g_re
    return l_re, l_im, (1 + l_re) ** 2 + l_im**2


def bound_rows(c_re: Any, c_im: Any, g_re: Any, g_im: Any, bounds: dict[str, Any]) -> dict[str, Any]:
    """The rows ``|N_X|^2 / M_X^2 - |1 + L|^2`` (``<= 0`` exactly where ``|X| <= M_X``) of each bound given.

    ``bounds`` maps ``Ms``, ``Mt``, ``Mks`` (:data:`BOUNDS`) to their limits (numbers or CasADi
    parameters; None: not bounded); the rows are per frequency, in the shape of the parts given.
    """
    unknown = set(bounds) - set(BOUNDS)
    if unknown:
        raise ValueError(f"unknown bound(s) {sorted(unknown)}; expected {', '.join(BOUNDS)}")
    l_re, l_im, d = loop_terms(c_re, c_im, g_re, g_im)
    numerators = bound_numerators(c_re, c_im, l_re, l_im)
    return {name: numerators[name] / m**2 - d for name, m in bounds.items() if m is not None}


def bound_numerators(c_re: Any, c_im: Any, l_re: Any, l_im: Any) -> dict[str, Any]:
    """``|N_X|^2`` of each bound (:data:`BOUNDS`), ``|X| = |N_X| / |1 + L|``: 1 for ``S``, ``|L|^2`` for ``T``,
    ``|C|^2`` for ``KS``, from the parts of ``C`` and ``L``."""
    return {b: b.numerator_squared(c_re, c_im, l_re, l_im) for b in Bound}


def peaks(c: np.ndarray, g: np.ndarray) -> dict[str, float]:
    """The largest ``|S|``, ``|T|`` and ``|KS|`` over the frequencies of the complex responses ``c`` and ``g``."""
    c, g = np.asarray(c, complex), np.asarray(g, complex)
    loop = c * g
    d = np.abs(1 + loop)
    with np.errstate(divide="ignore"):
        return {b: float(np.max(b.numerator(c, loop) / d)) for b in Bound}


def smooth_max(g: Any, rho: float) -> Any:
    """Kreisselmeier-Steinhauser smooth maximum of the entries of ``g`` (CasADi): an upper bound.

    ``max(g) <= KS(g) <= max(g) + log(n) / rho``; in practice only the entries within a few
    ``1/rho`` of the maximum add anything, so the bound is tight where it matters.
    """
    m = ca.mmax(g)
    return m + ca.log(ca.sum1(ca.vec(ca.exp(rho * (g - m))))) / rho
