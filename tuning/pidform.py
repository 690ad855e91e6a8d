"""The autotuner's controller: a PID in parallel form with its filter, in continuous time or as
the controller step runs it.

:class:`PIDController` holds ``kp, ki, kd, Tf`` of one of three forms (``filter_order``):

* 0: ``C = kp + ki/s``, a PI;
* 1: ``C = kp + ki/s + kd s / (Tf s + 1)``, the derivative filtered: the form the controller step
  (:func:`~piezopreload.models.controller.pid_update`) and every export run, so it maps exactly
  onto the ideal/ISA gains ``Kc = kp``, ``Ti = kp/ki``, ``Td = kd/kp`` (:meth:`PIDController.isa`);
  it is also ``(kp' + ki/s + kd' s) / (Tf s + 1)`` with ``kp' = kp + ki Tf``, ``kd' = kd + kp Tf``
  (:meth:`PIDController.parallel`): a first-order filter on the whole controller whose derivative
  gain is at least ``Tf`` times its proportional gain;
* 2: ``C = (kp + ki/s + kd s) F(s)``, ``F = 1 / (1 + Tf s + (Tf s)^2 / 2)`` (Garpinger, Hägglund and
  Åström 2012): a second-order filter on the whole controller; the controller step runs it as the ideal/ISA gains
  ``Kc = kp``, ``Ti = kp/ki``, ``Td = kd/kp`` on the measurement through ``F`` (``filter_order`` 2 of
  :class:`~piezopreload.models.controller.PIDGains`), which from the measurement to the output is ``C``.

With ``dt`` the controller is discrete: forms 0 and 1 as the controller step runs them at ``dt``
(trapezoidal integral, backward-Euler filtered derivative), form 2 by Tustin's map, which is how the controller
step runs it too (:func:`~piezopreload.models.controller.measurement_filter2` and the trapezoidal integral).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import control
import numpy as np

from piezopreload.core.errors import InputError
from piezopreload.models.controller import PIDGains
from piezopreload.tuning.loopshape import continuous_pid_response, discrete_pid_response, omega_terms

__all__ = ["PIDController", "controller_response", "UNLIMITED_V"]

#: the output range of gains given without one (the controller step clamps to a finite range)
UNLIMITED_V = 1e9


def controller_response(kp: Any, ki: Any, kd: Any, Tf: Any, omega: np.ndarray, filter_order: int,
                        dt: float | None) -> tuple[Any, Any]:
    """Real and imaginary parts of ``C`` at ``omega`` (numbers or CasADi expressions of the gains): continuous, or
    at ``dt`` as the controller step runs it (forms 0, 1) or by Tustin's map (form 2)."""
    if dt is None:
        return continuous_pid_response(kp, ki, kd, Tf, omega, filter_order)
    if filter_order < 2:
        return discrete_pid_response(kp, ki, kd, Tf if filter_order else 0.0, dt, omega_terms(omega, dt))
    warped = 2.0 / dt * np.tan(np.asarray(omega, float) * dt / 2.0)
    return continuous_pid_response(kp, ki, kd, Tf, warped, 2)


@dataclass(frozen=True)
class PIDController:
    """A tuned PID (see the module docstring): gains in the form ``filter_order`` names, continuous or at ``dt``."""

    kp: float
    ki: float
    kd: float = 0.0
    Tf: float = 0.0
    filter_order: int = 1
    dt: float | None = None

    def __post_init__(self) -> None:
        if self.filter_order not in (0, 1, 2):
            raise InputError(f"filter_order must be 0 (PI), 1 or 2, got {self.filter_order!r}")
        for name in ("kp", "ki", "kd", "Tf"):
            if not np.isfinite(getattr(self, name)):
                raise InputError(f"PIDController.{name} must be finite, got {getattr(self, name)!r}")

    @property
    def integrators(self) -> int:
        return 1 if self.ki != 0.0 else 0

    def response(self, omega: np.ndarray, dt: float | None = None) -> np.ndarray:
        """``C`` at ``omega`` (rad/s), complex; ``dt`` is the plant's and must be the controller's."""
        re, im = controller_response(self.kp, self.ki, self.kd, self.Tf, np.asarray(omega, float), self.filter_order,
                                     self.dt)
        return np.asarray(re, float) + 1j * np.asarray(im, float)

    def _continuous(self) -> tuple[np.ndarray, np.ndarray]:
        kp, ki, kd, Tf = self.kp, self.ki, self.kd, self.Tf
        if self.filter_order == 0:
            return np.array([kp, ki]), np.array([1.0, 0.0])
        if self.filter_order == 1:
            return np.array([kp * Tf + kd, kp + ki * Tf, ki]), np.array([Tf, 1.0, 0.0])
        return np.array([kd, kp, ki]), np.array([Tf**2 / 2.0, Tf, 1.0, 0.0])

    def num_den(self, dt: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Numerator and denominator in ``s`` (continuous) or ``z`` (discrete), descending powers."""
        if self.dt is None:
            return self._continuous()
        if self.filter_order == 2:
            tf = control.sample_system(control.tf(*self._continuous()), self.dt, method="tustin")
            return np.asarray(tf.num[0][0], float), np.asarray(tf.den[0][0], float)
        kp, ki, dt_ = self.kp, self.ki, self.dt
        alpha = self.Tf / (self.Tf + dt_) if self.filter_order else 0.0
        gd = self.kd * (1.0 - alpha) / dt_ if self.filter_order else 0.0
        zm1, zma, zp1 = np.array([1.0, -1.0]), np.array([1.0, -alpha]), np.array([1.0, 1.0])
        num = (kp * np.polymul(zm1, zma) + ki * dt_ / 2.0 * np.polymul(zp1, zma) + gd * np.polymul(zm1, zm1))
        return num, np.polymul(zm1, zma)

    def transfer_function(self) -> control.TransferFunction:
        """The controller as a python-control transfer function (continuous, or at its ``dt``)."""
        num, den = self.num_den()
        return control.tf(num, den, 0 if self.dt is None else self.dt)

    def parallel(self) -> tuple[float, float, float, float]:
        """``(kp, ki, kd, Tf)`` of ``C = (kp + ki/s + kd s) F(s)``: the filter on the whole controller."""
        if self.filter_order == 1:
            return self.kp + self.ki * self.Tf, self.ki, self.kd + self.kp * self.Tf, self.Tf
        return self.kp, self.ki, self.kd, self.Tf

    def isa(self, u_min_V: float = -UNLIMITED_V, u_max_V: float = UNLIMITED_V, b: float = 1.0) -> PIDGains:
        """The ideal/ISA gains ``Kc, Ti, Td, Tf`` the controller step runs (a PI has ``Td = Tf = 0``; form 2 keeps its
        filter, ``filter_order`` 2 of the gains: the measurement through ``F``), with the output range
        ``u_min_V..u_max_V`` (default :data:`UNLIMITED_V`: none)."""
        if self.filter_order == 2:
            if not (self.kp > 0 and self.ki > 0 and self.Tf > 0):
                raise InputError(f"the ideal/ISA form of a second-order filter needs kp > 0, ki > 0 and Tf > 0, got "
                                 f"kp {self.kp!r}, ki {self.ki!r}, Tf {self.Tf!r}")
            return PIDGains(Kc=self.kp, Ti_s=self.kp / self.ki, Td_s=self.kd / self.kp, Tf_s=self.Tf, b=b,
                            u_min_V=u_min_V, u_max_V=u_max_V, filter_order=2)
        if not (self.kp > 0 and self.ki > 0):
            raise InputError(f"the ideal/ISA form needs kp > 0 and ki > 0, got kp {self.kp!r}, ki {self.ki!r}")
        td = self.kd / self.kp if self.filter_order else 0.0
        return PIDGains(Kc=self.kp, Ti_s=self.kp / self.ki, Td_s=td, Tf_s=self.Tf if td > 0 else 0.0, b=b,
                        u_min_V=u_min_V, u_max_V=u_max_V)

    def scaled(self, sign: float) -> PIDController:
        """The controller with its gains times ``sign`` (for a plant of negative gain)."""
        return PIDController(sign * self.kp, sign * self.ki, sign * self.kd, self.Tf, self.filter_order, self.dt)
