"""The autotuner's optimisation problem on one frequency grid: CasADi expressions, IPOPT with exact derivatives.

Decision variables, scaled to O(1) (:class:`Scales`): ``kp = s_p x0``, ``ki = s_i x1`` and, with a
derivative, ``kd = s_d x2``, ``Tf = s_f exp(x3)`` (:class:`~piezopreload.tuning.pidform.PIDController`'s
forms). The objective: ``-ki / s_i`` (``IE``: the integrated error of a unit load step at the plant
input is ``1/ki``), or the load step's IAE (:func:`~piezopreload.tuning.loadstep.iae_function`).
The constraints: for each bound ``|X| <= M`` (``X`` one of ``S``, ``T``, ``KS``) and each grid
frequency, the row of :func:`~piezopreload.tuning.loopshape.bound_rows` divided by ``|1 + L|^2``,
``|X|^2 / M^2 - 1 <= 0``: one per frequency, scaled alike. :meth:`PIDProblem.solve` runs IPOPT
(exact Hessian), or scipy's SLSQP on the same functions and first derivatives (the benchmark's
peer); :meth:`PIDProblem.least_violation` the smallest ``max |X| / M`` any gains reach.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from scipy.optimize import minimize

from piezopreload.core.errors import InputError
from piezopreload.tuning.loopshape import bound_rows, loop_terms
from piezopreload.tuning.pidform import PIDController, controller_response

__all__ = ["Scales", "PIDProblem", "Solution", "TF_RANGE", "X_MAX"]

#: the derivative filter's range relative to its scale (``Tf = s_f exp(x3)``)
TF_RANGE = (1e-3, 1e2)
#: the largest scaled gain
X_MAX = 1e3
#: the smallest scaled proportional and integral gains (the ideal/ISA form needs them positive)
_X_MIN = (1e-6, 1e-8)


@dataclass(frozen=True)
class Scales:
    """The gains' scales (``x = gain / scale``) and the controller's form: ``filter_order`` 0 (PI), 1 or 2; ``dt``
    a discrete controller's period (None: continuous)."""

    kp: float
    ki: float
    kd: float
    Tf: float
    filter_order: int
    dt: float | None

    def __post_init__(self) -> None:
        for name in ("kp", "ki", "kd", "Tf"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InputError(f"Scales.{name} must be finite and > 0, got {value!r}")

    @property
    def n(self) -> int:
        return 2 if self.filter_order == 0 else 4

    def gains(self, x: Any) -> tuple[Any, Any, Any, Any]:
        """``(kp, ki, kd, Tf)`` of the scaled variables (numbers or CasADi expressions)."""
        if self.filter_order == 0:
            return self.kp * x[0], self.ki * x[1], 0.0, 0.0
        return self.kp * x[0], self.ki * x[1], self.kd * x[2], self.Tf * (np.exp(x[3]) if isinstance(
            x, np.ndarray) else ca.exp(x[3]))

    def controller(self, x: np.ndarray) -> PIDController:
        kp, ki, kd, Tf = (float(v) for v in self.gains(np.asarray(x, float)))
        return PIDController(kp, ki, kd, Tf, self.filter_order, self.dt)

    def x(self, c: PIDController) -> np.ndarray:
        """The scaled variables of ``c`` (clipped into :meth:`box`)."""
        lo, hi = self.box()
        if self.filter_order == 0:
            x = np.array([c.kp / self.kp, c.ki / self.ki])
        else:
            x = np.array([c.kp / self.kp, c.ki / self.ki, c.kd / self.kd, np.log(max(c.Tf, 1e-300) / self.Tf)])
        return np.clip(x, lo, hi)

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of the scaled variables."""
        lo = [_X_MIN[0], _X_MIN[1]] + ([0.0, np.log(TF_RANGE[0])] if self.n == 4 else [])
        hi = [X_MAX, X_MAX] + ([X_MAX, np.log(TF_RANGE[1])] if self.n == 4 else [])
        return np.array(lo), np.array(hi)


@dataclass(frozen=True)
class Solution:
    """One solve: the variables, the objective, the worst bound's ``|X| / M - 1`` on the grid, the solver's word."""

    x: np.ndarray
    objective: float
    violation: float
    status: str
    iterations: int
    seconds: float


class PIDProblem:
    """The problem on the grid ``omega`` with the plant's response ``G`` there (see the module docstring).

    ``bounds`` maps ``Ms``, ``Mt``, ``Mks`` to limits (None: unbounded); ``objective`` is ``"IE"`` or a CasADi
    function ``(kp, ki, kd, Tf) -> IAE`` with ``iae_scale`` its typical size.
    """

    def __init__(self, omega: np.ndarray, G: np.ndarray, bounds: dict[str, float | None], scales: Scales,
                 objective: Any = "IE", iae_scale: float = 1.0, max_iterations: int = 300) -> None:
        self.omega, self.scales, self.bounds = np.asarray(omega, float), scales, bounds
        x = ca.SX.sym("x", scales.n)
        kp, ki, kd, Tf = scales.gains(x)
        re, im = controller_response(kp, ki, kd, Tf, self.omega, scales.filter_order, scales.dt)
        G = np.asarray(G, complex)
        rows = bound_rows(re, im, G.real, G.imag, bounds)
        _, _, d = loop_terms(re, im, G.real, G.imag)
        self.names = [name for name in rows]
        g = ca.vertcat(*[rows[name] / d for name in self.names]) if rows else ca.SX(0, 1)
        if isinstance(objective, str):
            f = -x[1]
        else:
            f = objective(ca.vertcat(kp, ki, kd, Tf)) / iae_scale
        self.x, self.f, self.g = x, f, g
        self.fg = ca.Function("fg", [x], [f, g])
        self.derivatives = ca.Function("dfg", [x], [ca.gradient(f, x), ca.jacobian(g, x)])
        self.max_iterations = max_iterations
        self._ipopt: Any = None
        self._phase_one: Any = None

    # ---- evaluation ----------------------------------------------------------------------------
    def evaluate(self, x: np.ndarray) -> tuple[float, float]:
        """The objective and the worst bound's ``|X| / M - 1`` (<= 0 met) at ``x``."""
        f, g = self.fg(x)
        g = np.asarray(g, float).ravel()
        worst = float(np.sqrt(max(1.0 + np.max(g, initial=-1.0), 0.0)) - 1.0)
        return float(f), worst

    def worst_by_bound(self, x: np.ndarray) -> dict[str, tuple[float, float]]:
        """Per bound, ``(max |X| / M, the frequency where)`` on the grid."""
        g = np.asarray(self.fg(x)[1], float).ravel().reshape(len(self.names), -1)
        out = {}
        for name, row in zip(self.names, g):
            i = int(np.argmax(row))
            out[name] = (float(np.sqrt(max(1.0 + row[i], 0.0))), float(self.omega[i]))
        return out

    # ---- solving -------------------------------------------------------------------------------
    def _solver(self) -> Any:
        if self._ipopt is None:
            self._ipopt = ca.nlpsol("autotune", "ipopt", {"x": self.x, "f": self.f, "g": self.g}, {
                "ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.tol": 1e-9,
                "ipopt.constr_viol_tol": 1e-9, "ipopt.max_iter": self.max_iterations,
                # a small barrier to start with: the scaled problem's starts are near its optimum, and IPOPT's
                # default (0.1) pushes them off the active bounds into another local optimum's basin
                "ipopt.mu_init": 1e-4})
        return self._ipopt

    def solve(self, x0: np.ndarray, method: str = "ipopt", box: tuple[np.ndarray, np.ndarray] | None = None) -> Solution:
        """Solve from ``x0`` with IPOPT (exact first and second derivatives) or scipy's SLSQP (``method="slsqp"``:
        the same functions and exact first derivatives, a quasi-Newton Hessian), in :meth:`Scales.box` or the
        narrower ``box`` (a trust region)."""
        lo, hi = self.scales.box()
        if box is not None:
            lo, hi = np.maximum(lo, box[0]), np.minimum(hi, box[1])
        x0 = np.clip(np.asarray(x0, float), lo, hi)
        t0 = time.perf_counter()
        if method == "slsqp":
            x, status, iterations = self._slsqp(x0, lo, hi)
        elif method == "ipopt":
            solver = self._solver()
            sol = solver(x0=x0, lbx=lo, ubx=hi, lbg=-np.inf, ubg=0.0)
            stats = solver.stats()
            x, status, iterations = (np.asarray(sol["x"], float).ravel(), str(stats.get("return_status")),
                                     int(stats.get("iter_count", 0)))
        else:
            raise InputError(f"method must be 'ipopt' or 'slsqp', got {method!r}")
        x = np.clip(x, lo, hi)
        f, worst = self.evaluate(x)
        return Solution(x, f, worst, status, iterations, time.perf_counter() - t0)

    def _slsqp(self, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, str, int]:
        def fun(x: np.ndarray) -> float:
            return float(self.fg(x)[0])

        def grad(x: np.ndarray) -> np.ndarray:
            return np.asarray(self.derivatives(x)[0], float).ravel()

        def cons(x: np.ndarray) -> np.ndarray:
            return -np.asarray(self.fg(x)[1], float).ravel()

        def cons_jac(x: np.ndarray) -> np.ndarray:
            return -np.asarray(self.derivatives(x)[1], float)

        res = minimize(fun, x0, jac=grad, method="SLSQP", bounds=list(zip(lo, hi)),
                       constraints=[{"type": "ineq", "fun": cons, "jac": cons_jac}],
                       options={"maxiter": self.max_iterations, "ftol": 1e-12})
        return np.asarray(res.x, float), str(res.message), int(res.nit)

    def least_violation(self, x0: np.ndarray) -> Solution:
        """The gains with the smallest worst bound ``max |X| / M`` on the grid (the phase one of an infeasible
        problem): minimise ``t`` subject to every row ``<= t``."""
        lo, hi = self.scales.box()
        t = ca.SX.sym("t")
        if self._phase_one is None:
            self._phase_one = ca.nlpsol("autotune_least_violation", "ipopt",
                                        {"x": ca.vertcat(self.x, t), "f": t, "g": self.g - t},
                                        {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                                         "ipopt.max_iter": self.max_iterations})
        x0 = np.clip(np.asarray(x0, float), lo, hi)
        t0 = time.perf_counter()
        g0 = float(np.max(np.asarray(self.fg(x0)[1], float), initial=0.0))
        sol = self._phase_one(x0=np.append(x0, g0), lbx=np.append(lo, -1.0), ubx=np.append(hi, np.inf), lbg=-np.inf,
                              ubg=0.0)
        x = np.clip(np.asarray(sol["x"], float).ravel()[:-1], lo, hi)
        f, worst = self.evaluate(x)
        stats = self._phase_one.stats()
        return Solution(x, f, worst, str(stats.get("return_status")), int(stats.get("iter_count", 0)),
                        time.perf_counter() - t0)
