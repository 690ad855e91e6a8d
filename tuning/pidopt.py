"""The autotuner's optimisation problem on one frequency grid: CasADi expressions, an SQP with exact derivatives.

Decision variables, scaled to O(1) (:class:`Scales`): ``kp = s_p x0``, ``ki = s_i x1`` and, with a
derivative, ``kd = s_d x2``, ``Tf = s_f exp(x3)`` (:class:`~piezopreload.tuning.pidform.PIDController`'s
forms). The objective: ``-ki / s_i`` (``IE``: the integrated error of a unit load step at the plant
input is ``1/ki``), or the load step's IAE (:func:`~piezopreload.tuning.loadstep.iae_function`).
The constraints: for each bound ``|X| <= M`` (``X`` one of ``S``, ``T``, ``KS``) and each grid
frequency, the row of :func:`~piezopreload.tuning.loopshape.bound_rows` divided by ``|1 + L|^2``,
``|X|^2 / M^2 - 1 <= 0`` (built from its numerators, :func:`~piezopreload.tuning.loopshape.bound_numerators`,
each slot's weight ``1/M^2`` given as a number: the fewest operations for the exact Hessian), one per
frequency, scaled alike. :meth:`PIDProblem.solve` runs CasADi's
``sqpmethod`` (exact Hessian of the Lagrangian, its negative eigenvalues reflected where it is
indefinite, each QP by DAQP, a dual active-set solver for small dense QPs: four variables, a few
hundred rows; where it stalls, IPOPT from the same start), or IPOPT (exact Hessian), or scipy's
SLSQP on the same functions and first derivatives (the benchmark's peer);
:meth:`PIDProblem.least_violation` the smallest ``max |X| / M`` any gains reach.

Why an SQP: with four variables and a few dozen inequality rows, started near the optimum (the
starts of :mod:`~piezopreload.tuning.stabset`), an active-set SQP converges in a handful of
iterations (four in the median on the benchmark batch), each a tiny dense QP; IPOPT's interior
point needs tens of iterations from any start (its barrier pushes the start off the active
bounds): with it as the local solver (``solver="ipopt"``) the whole search on Åström and
Hägglund's 31 processes took three times as long, for the same integral gains to 3e-4.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, TypeAlias, TypeVar

import casadi as ca
import numpy as np
from scipy.optimize import minimize

from piezopreload.core.errors import InputError, InternalError
from piezopreload.tuning.loopshape import (
    bound_numerators,
    continuous_pid_response,
    discrete_pid_response,
    loop_terms,
    omega_terms,
)
from piezopreload.tuning.pidform import PIDController

__all__ = ["Form", "Metric", "Scales", "PIDProblem", "Solution", "Objective", "IntegratedError", "LoadStepIAE",
           "IE", "TF_RANGE", "X_MAX", "METHODS"]

#: the derivative filter's range relative to its scale (``Tf = s_f exp(x3)``)
TF_RANGE = (1e-4, 1e4)
#: the largest scaled gain
X_MAX = 1e3
#: the smallest scaled proportional and integral gains (the ideal/ISA form needs them positive)
_X_MIN = (1e-6, 1e-8)
#: the local solvers :meth:`PIDProblem.solve` runs
METHODS = ("sqp", "ipopt", "slsqp", "slsqp-fd")
#: CasADi's ``sqpmethod`` as the SQP runs it: DAQP for the QPs; the Hessian's negative eigenvalues reflected (made
#: positive: DAQP needs a positive definite Hessian, and clipping them to a small margin left it so ill-conditioned
#: that the line search stalled on refined grids of the benchmark batch)
SQP_OPTIONS: dict[str, Any] = {"qpsol": "daqp", "qpsol_options": {"error_on_fail": False},
                               "convexify_strategy": "eigen-reflect", "tol_pr": 1e-9, "tol_du": 1e-8,
                               "min_step_size": 1e-12}
#: the SQP's iterations before IPOPT takes over from the same start (a start near the optimum needs a handful)
_SQP_ITERATIONS = 30
_SQP_DONE = ("Solve_Succeeded", "Search_Direction_Becomes_Too_Small")


class Form(StrEnum):
    """The controller's form (its value as the results and their JSON write it): a PI, two variables ``(kp, ki)``;
    a PID with its filter, four ``(kp, ki, kd, log Tf)``."""

    PI = "PI"
    PID = "PID"

    @classmethod
    def of(cls, filter_order: int) -> Form:
        """The form of a controller with filter order ``filter_order`` (0: no derivative, a PI)."""
        return cls.PI if filter_order == 0 else cls.PID

    @property
    def variables(self) -> int:
        """How many decision variables the form has."""
        return 2 if self is Form.PI else 4


@dataclass(frozen=True)
class Scales:
    """The gains' scales (``x = gain / scale``) and the controller's form: ``filter_order`` 0 (PI), 1 or 2; ``dt``
    a discrete controller's period (None: continuous); ``Tf_min`` the least filter time constant (s, 0: only the
    search range's :data:`TF_RANGE`)."""

    kp: float
    ki: float
    kd: float
    Tf: float
    filter_order: int
    dt: float | None
    Tf_min: float = 0.0

    def __post_init__(self) -> None:
        for name in ("kp", "ki", "kd", "Tf"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InputError(f"Scales.{name} must be finite and > 0, got {value!r}")

    @property
    def form(self) -> Form:
        """The controller's form."""
        return Form.of(self.filter_order)

    @property
    def n(self) -> int:
        """How many decision variables."""
        return self.form.variables

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
        lo = [_X_MIN[0], _X_MIN[1]] + ([0.0, self.tf_low] if self.n == 4 else [])
        hi = [X_MAX, X_MAX] + ([X_MAX, max(np.log(TF_RANGE[1]), self.tf_low)] if self.n == 4 else [])
        return np.array(lo), np.array(hi)

    @property
    def tf_low(self) -> float:
        """The lower end of the filter's scaled variable: the search range's, or the floor ``Tf_min`` above it."""
        floor = np.log(self.Tf_min / self.Tf) if self.Tf_min > 0 else -np.inf
        return float(max(np.log(TF_RANGE[0]), floor))

    @property
    def tf_floor_binds(self) -> bool:
        """Whether the floor ``Tf_min`` (not the search range) sets the filter's lower end."""
        return self.Tf_min > 0 and np.log(self.Tf_min / self.Tf) >= np.log(TF_RANGE[0])


@dataclass(frozen=True)
class Solution:
    """One solve: the variables, the objective, the worst bound's ``|X| / M - 1`` on the grid, the solver's word."""

    x: np.ndarray
    objective: float
    violation: float
    status: str
    iterations: int
    seconds: float
    lam_g: np.ndarray | None = None
    lam_x: np.ndarray | None = None


#: the grid's rows come in this many slots times a power of two, or one and a half times that (padding rows are
#: free: on the benchmark batch a third of the slots were padding with powers of two alone), so one compiled NLP
#: serves many grids
_BLOCK = 32


def _slots(rows: int) -> int:
    """The slots of the compiled problem that holds ``rows`` rows: the least :data:`_BLOCK` times ``2^k`` or
    ``1.5 * 2^k`` at or above it."""
    cap = _BLOCK
    while cap < rows:
        cap = cap * 3 // 2 if (cap & (cap - 1)) == 0 else cap * 4 // 3
    return cap


@dataclass(frozen=True, eq=False)
class _Compiled:
    """The NLP's CasADi functions for one structure: variables ``x``, numbers ``p`` (the scales, the sample period,
    then per grid slot the frequency's features, the plant's response and each bound's weight: ``1/M^2`` for the
    bound the slot holds, 0 for the others)."""

    x: Any
    p: Any
    f: Any
    g: Any
    fg: Any
    derivatives: Any
    features: int


_CACHE: dict[tuple[Any, ...], _Compiled] = {}
_SOLVERS: dict[tuple[Any, ...], dict[str, Any]] = {}


def _features(omega: np.ndarray, filter_order: int, dt: float | None) -> np.ndarray:
    """Per frequency, what the controller's response is built from (rows): the frequency (continuous), the discrete
    terms of :func:`~piezopreload.tuning.loopshape.omega_terms` (the controller step at ``dt``), or the frequency
    Tustin's map warps it to (a second-order filter at ``dt``)."""
    if dt is None:
        return omega[None, :]
    if filter_order < 2:
        return omega_terms(omega, dt)
    return (2.0 / dt * np.tan(omega * dt / 2.0))[None, :]


#: the symbols an NLP is built of: scalar expressions, or matrix ones where it calls a function (the IAE's simulation)
_Sym = TypeVar("_Sym", ca.SX, ca.MX)


def _set(bounds: dict[str, float | None], name: str) -> float:
    """The limit of a bound the problem holds (its names are those set)."""
    m = bounds[name]
    if m is None:
        raise InternalError(f"the bound {name} is not set")
    return m


@dataclass(frozen=True)
class IntegratedError:
    """The IE objective: ``-ki / s_i``, the scaled integral gain negated (a unit load step at the plant input
    integrates to an error of ``1/ki``). Its problem's functions are the same for every plant: built once."""

    #: a plain expression of the variables: CasADi's SX expands it
    expands = True

    def expression(self, x: Any, gains: Any) -> Any:
        """The objective's expression in the scaled variables ``x`` (``gains``: ``(kp, ki, kd, Tf)``)."""
        return -x[1]

    def value(self, solved: float, ki: float) -> float:
        """What is minimised, unscaled, at a solution whose objective is ``solved`` and integral gain ``ki``."""
        return -ki


@dataclass(frozen=True)
class LoadStepIAE:
    """The IAE of the load step: ``function``, a CasADi function ``(kp, ki, kd, Tf) -> IAE``
    (:func:`~piezopreload.tuning.loadstep.iae_function`), divided by ``scale``, its typical size (the IE optimum's)."""

    function: Any
    scale: float = 1.0
    #: a simulation: it stays a call in CasADi's MX, not an expansion
    expands = False

    def __post_init__(self) -> None:
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise InternalError(f"LoadStepIAE.scale must be a positive number, got {self.scale!r}")

    def scaled(self) -> LoadStepIAE:
        """The function divided by its scale, as one CasADi function (the problem's objective)."""
        g4 = ca.MX.sym("g4", 4)
        return LoadStepIAE(ca.Function("iae_scaled", [g4], [self.function(g4) / self.scale]))

    def expression(self, x: Any, gains: Any) -> Any:
        """The objective's expression: the function of the unscaled ``gains`` ``(kp, ki, kd, Tf)``."""
        return self.function(gains)

    def value(self, solved: float, ki: float) -> float:
        """What is minimised: the scaled IAE ``solved`` itself."""
        return float(solved)


class Metric(StrEnum):
    """What the autotuner is asked to minimise, by its name (as the command line and the results' JSON write it):
    the integrated error of a unit load step (:class:`IntegratedError`) or its IAE (:class:`LoadStepIAE`)."""

    IE = "IE"
    IAE = "IAE"


#: what the autotuner minimises: the integrated error or the load step's IAE
Objective: TypeAlias = IntegratedError | LoadStepIAE
#: the integrated error, the default objective
IE = IntegratedError()


def _compile(n: int, names: tuple[str, ...], filter_order: int, discrete: bool, objective: Objective) -> _Compiled:
    """The NLP for ``n`` slots, each one row: the bound its weights select (one of ``names``) at its frequency,
    ``|X|^2 / M^2 - 1`` (:func:`~piezopreload.tuning.loopshape.bound_rows` over ``|1 + L|^2``); a slot whose weights
    are all zero is a free row."""
    if objective.expands:
        return _build(ca.SX, n, names, filter_order, discrete, objective)
    return _build(ca.MX, n, names, filter_order, discrete, objective)  # the simulation stays a call, not an expansion


def _build(sym: type[_Sym], n: int, names: tuple[str, ...], filter_order: int, discrete: bool,
           objective: Objective) -> _Compiled:
    nf = 6 if discrete and filter_order < 2 else 1
    nx = Form.of(filter_order).variables
    nb = len(names)
    x = sym.sym("x", nx)
    p = sym.sym("p", 5 + n * (nf + 2 + nb))
    s_kp, s_ki, s_kd, s_tf, dt = (p[i] for i in range(5))
    kp, ki = s_kp * x[0], s_ki * x[1]
    kd, Tf = (0.0, 0.0) if filter_order == 0 else (s_kd * x[2], s_tf * ca.exp(x[3]))
    grid = ca.reshape(p[5:], nf + 2 + nb, n)
    if discrete and filter_order < 2:
        re, im = discrete_pid_response(kp, ki, kd, Tf, dt, [grid[i, :] for i in range(6)])
    else:
        re, im = continuous_pid_response(kp, ki, kd, Tf, grid[0, :], filter_order)
    g_re, g_im = grid[nf, :], grid[nf + 1, :]
    l_re, l_im, d = loop_terms(re, im, g_re, g_im)
    numerators = bound_numerators(re, im, l_re, l_im)
    # |X|^2 / M^2 - 1 of the bound the slot holds (its weight 1/M^2, the others' 0): bound_rows' row over |1 + L|^2
    g = sum((grid[nf + 2 + i, :] * numerators[name] for i, name in enumerate(names)), 0.0 * d) / d - 1.0 if nb \
        else sym(1, 0)
    f = objective.expression(x, ca.vertcat(kp, ki, kd, Tf))
    g = ca.cse(g.T) if sym is ca.SX else g.T  # the slots' shared subexpressions once: a quarter fewer operations
    return _Compiled(x, p, f, g, ca.Function("fg", [x, p], [f, g]),
                     ca.Function("dfg", [x, p], [ca.gradient(f, x), ca.jacobian(g, x)]), nf)


class PIDProblem:
    """The problem on the frequencies ``omega`` with the plant's response ``G`` there (see the module docstring).

    ``bounds`` maps ``Ms``, ``Mt``, ``Mks`` to limits (None: unbounded); ``which`` names the bound each entry of
    ``omega`` holds (None: every bound at every frequency, the entries repeated per bound); ``objective`` is
    :data:`IE` (None) or a :class:`LoadStepIAE` (a CasADi function ``(kp, ki, kd, Tf) -> IAE`` and its typical size).
    Each row is a slot of a compiled problem of :func:`_slots` slots (:data:`_BLOCK` times a power of two, or one and
    a half times that; the spare ones free rows), at least ``spare`` spare, so the IE problem's CasADi functions and
    solvers are built once per structure and size and kept.
    """

    def __init__(self, omega: np.ndarray, G: np.ndarray, bounds: dict[str, float | None], scales: Scales,
                 objective: Objective | None = None, max_iterations: int = 100, spare: int = 0,
                 which: Any = None) -> None:
        self.scales, self.bounds = scales, bounds
        self.names = tuple(name for name, m in bounds.items() if m is not None)
        omega, G = np.asarray(omega, float).ravel(), np.asarray(G, complex).ravel()
        if which is None:
            which = np.repeat(np.array(self.names, dtype=object), omega.size)
            omega, G = np.tile(omega, len(self.names)), np.tile(G, len(self.names))
        self.omega, self.which = omega, np.asarray(which, dtype=object)
        n = self.omega.size
        cap = _slots(n + spare)
        key = (cap, self.names, scales.filter_order, scales.dt is not None, max_iterations)
        objective = IE if objective is None else objective
        if isinstance(objective, IntegratedError):  # the same functions for every plant: built once, kept
            if key not in _CACHE:
                _CACHE[key] = _compile(cap, self.names, scales.filter_order, scales.dt is not None, objective)
            self.compiled = _CACHE[key]
            self._solvers = _SOLVERS.setdefault(key, {})
        else:  # the IAE: a function of this plant's, not kept
            self.compiled = _compile(cap, self.names, scales.filter_order, scales.dt is not None, objective.scaled())
            self._solvers = {}
        feats = _features(self.omega, scales.filter_order, scales.dt) if n else np.zeros((self.compiled.features, 0))
        select = np.array([(self.which == name) / float(_set(bounds, name)) ** 2 for name in self.names],
                          float).reshape(len(self.names), n)
        slots = np.zeros((self.compiled.features + 2 + len(self.names), cap))
        slots[:, :n] = np.vstack([feats, G.real[None, :], G.imag[None, :], select])
        if n:  # spare slots: the last frequency again, no bound selected (free rows)
            slots[:self.compiled.features + 2, n:] = slots[:self.compiled.features + 2, n - 1:n]
        else:
            slots[:self.compiled.features, :] = 1.0
        self.data = np.concatenate([[scales.kp, scales.ki, scales.kd, scales.Tf, scales.dt or 0.0],
                                    slots.ravel(order="F")])
        self.ubg = np.concatenate([np.zeros(n), np.full(cap - n, np.inf)])
        self.cap, self.max_iterations = cap, max_iterations
        self.x, self.f, self.g = self.compiled.x, self.compiled.f, self.compiled.g

    def fg(self, x: np.ndarray) -> tuple[Any, Any]:
        """The objective and the rows of the problem's entries (the spare slots left out)."""
        f, g = self.compiled.fg(x, self.data)
        return f, np.asarray(g, float).ravel()[:self.omega.size]

    def derivatives(self, x: np.ndarray) -> tuple[Any, Any]:
        df, dg = self.compiled.derivatives(x, self.data)
        return df, np.asarray(dg, float)[:self.omega.size, :]

    # ---- evaluation ----------------------------------------------------------------------------
    def evaluate(self, x: np.ndarray) -> tuple[float, float]:
        """The objective and the worst bound's ``|X| / M - 1`` (<= 0 met) at ``x``."""
        f, g = self.fg(x)
        g = np.asarray(g, float).ravel()
        worst = float(np.sqrt(max(1.0 + np.max(g, initial=-1.0), 0.0)) - 1.0)
        return float(f), worst

    def worst_by_bound(self, x: np.ndarray) -> dict[str, tuple[float, float]]:
        """Per bound, ``(max |X| / M, the frequency where)`` over the problem's entries."""
        g = np.asarray(self.fg(x)[1], float).ravel()
        out = {}
        for name in self.names:
            mine = np.flatnonzero(self.which == name)
            if mine.size:
                i = int(mine[np.argmax(g[mine])])
                out[name] = (float(np.sqrt(max(1.0 + g[i], 0.0))), float(self.omega[i]))
        return out

    # ---- solving -------------------------------------------------------------------------------
    def _solver(self, name: str = "ipopt") -> Any:
        if name in ("sqp", "least_violation_sqp") and name not in self._solvers:
            t = type(self.x).sym("t")
            nlp = ({"x": self.x, "p": self.compiled.p, "f": self.f, "g": self.g} if name == "sqp" else
                   {"x": ca.vertcat(self.x, t), "p": self.compiled.p, "f": t, "g": self.g - t})
            self._solvers[name] = ca.nlpsol(f"autotune_{name}", "sqpmethod", nlp, {**SQP_OPTIONS,
                "max_iter": min(self.max_iterations, _SQP_ITERATIONS), "print_header": False,
                "print_iteration": False, "print_status": False, "print_time": False, "error_on_fail": False})
        if name not in self._solvers:
            t = type(self.x).sym("t")
            nlp = ({"x": self.x, "p": self.compiled.p, "f": self.f, "g": self.g} if name != "least_violation" else
                   {"x": ca.vertcat(self.x, t), "p": self.compiled.p, "f": t, "g": self.g - t})
            warm: dict[str, str | float] = {
                "ipopt.warm_start_init_point": "yes", "ipopt.mu_init": 1e-8, "ipopt.warm_start_bound_push": 1e-9,
                "ipopt.warm_start_mult_bound_push": 1e-9, "ipopt.warm_start_slack_bound_push": 1e-9}
            self._solvers[name] = ca.nlpsol(f"autotune_{name}", "ipopt", nlp, {
                "ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.tol": 1e-9,
                "ipopt.constr_viol_tol": 1e-9, "ipopt.max_iter": self.max_iterations,
                # a small barrier to start with: the scaled problem's starts are near its optimum, and IPOPT's
                # default (0.1) pushes them off the active bounds into another local optimum's basin; a warm start
                # (the previous solution and its multipliers, a refined grid) starts at the barrier's end
                "ipopt.mu_init": 1e-4, **(warm if name == "ipopt_warm" else {})})
        return self._solvers[name]

    def _multipliers(self, warm: Solution) -> np.ndarray:
        """``warm``'s constraint multipliers in this problem's slots (its entries are this one's first)."""
        lam = np.zeros(self.cap)
        old = np.asarray(warm.lam_g, float).ravel()
        k = min(old.size, self.cap)
        lam[:k] = old[:k]
        return lam

    def solve(self, x0: np.ndarray, method: str = "ipopt", box: tuple[np.ndarray, np.ndarray] | None = None,
              warm: Solution | None = None) -> Solution:
        """Solve from ``x0`` with the SQP (``method="sqp"``, see the module docstring), IPOPT (exact first and second
        derivatives) or scipy's SLSQP (``method="slsqp"``: the same functions and exact first derivatives, a
        quasi-Newton Hessian; ``"slsqp-fd"``: finite-difference derivatives, as scipy takes a problem without them),
        in :meth:`Scales.box` or the narrower ``box`` (a trust region). ``warm``: a solution of a problem whose grid
        is this one's first frequencies (the SQP and IPOPT start from its multipliers too)."""
        lo, hi = self.scales.box()
        if box is not None:
            lo, hi = np.maximum(lo, box[0]), np.minimum(hi, box[1])
        x0 = np.clip(np.asarray(x0, float), lo, hi)
        t0 = time.perf_counter()
        lam: tuple[Any, Any] = (None, None)
        if method in ("slsqp", "slsqp-fd"):
            x, status, iterations = self._slsqp(x0, lo, hi, exact=method == "slsqp")
            f, worst = self.evaluate(np.clip(x, lo, hi))
        elif method in ("ipopt", "sqp"):
            x, status, iterations, lam, (f, worst) = self._casadi(method, x0, lo, hi, warm)
            if method == "sqp" and (status not in _SQP_DONE or worst > 1e-6):
                x, status2, more, lam, (f, worst) = self._casadi("ipopt", x0, lo, hi, warm)  # the SQP stalled: IPOPT
                status, iterations = f"{status}; ipopt: {status2}", iterations + more
        else:
            raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
        return Solution(np.clip(x, lo, hi), f, worst, status, iterations, time.perf_counter() - t0, *lam)

    def _casadi(self, method: str, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                warm: Solution | None) -> tuple[np.ndarray, str, int, tuple[np.ndarray, np.ndarray],
                                                tuple[float, float]]:
        """The solve, its status and iterations, its multipliers and ``(objective, worst |X| / M - 1)`` from the
        solver's own values (no second evaluation)."""
        use_warm = warm is not None and warm.lam_g is not None
        solver = self._solver(method if method == "sqp" or not use_warm else "ipopt_warm")
        extra = {"lam_g0": self._multipliers(warm), "lam_x0": warm.lam_x} if warm is not None and use_warm else {}
        sol = solver(x0=x0, p=self.data, lbx=lo, ubx=hi, lbg=-np.inf, ubg=self.ubg, **extra)
        stats = solver.stats()
        g = np.asarray(sol["g"], float).ravel()[:self.omega.size]
        worst = float(np.sqrt(max(1.0 + np.max(g, initial=-1.0), 0.0)) - 1.0)
        return (np.asarray(sol["x"], float).ravel(), str(stats.get("return_status")), int(stats.get("iter_count", 0)),
                (np.asarray(sol["lam_g"], float).ravel(), np.asarray(sol["lam_x"], float).ravel()),
                (float(sol["f"]), worst))

    def _slsqp(self, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, exact: bool) -> tuple[np.ndarray, str, int]:
        def fun(x: np.ndarray) -> float:
            return float(self.fg(x)[0])

        def grad(x: np.ndarray) -> np.ndarray:
            return np.asarray(self.derivatives(x)[0], float).ravel()

        def cons(x: np.ndarray) -> np.ndarray:
            return -np.asarray(self.fg(x)[1], float).ravel()

        def cons_jac(x: np.ndarray) -> np.ndarray:
            return -np.asarray(self.derivatives(x)[1], float)

        constraint: dict[str, Any] = {"type": "ineq", "fun": cons, **({"jac": cons_jac} if exact else {})}
        # scipy-stubs type a constraint dict's fun as scalar-valued; SLSQP takes a vector of inequalities
        res = minimize(fun, x0, jac=grad if exact else None, method="SLSQP",  # type: ignore[call-overload]
                       bounds=list(zip(lo, hi)), constraints=[constraint],
                       options={"maxiter": self.max_iterations, "ftol": 1e-12})
        return np.asarray(res.x, float), str(res.message), int(res.nit)

    def least_violation(self, x0: np.ndarray, method: str = "ipopt") -> Solution:
        """The gains with the smallest worst bound ``max |X| / M`` on the grid (the phase one of an infeasible
        problem): minimise ``t`` subject to every row ``<= t``; by the SQP (``method="sqp"``) or IPOPT (any other:
        SLSQP has no such problem of its own)."""
        lo, hi = self.scales.box()
        solver = self._solver("least_violation_sqp" if method == "sqp" else "least_violation")
        x0 = np.clip(np.asarray(x0, float), lo, hi)
        t0 = time.perf_counter()
        g0 = float(np.max(np.asarray(self.fg(x0)[1], float), initial=0.0))
        sol = solver(x0=np.append(x0, g0), p=self.data, lbx=np.append(lo, -1.0), ubx=np.append(hi, np.inf),
                     lbg=-np.inf, ubg=self.ubg)
        x = np.clip(np.asarray(sol["x"], float).ravel()[:-1], lo, hi)
        f, worst = self.evaluate(x)
        stats = solver.stats()
        return Solution(x, f, worst, str(stats.get("return_status")), int(stats.get("iter_count", 0)),
                        time.perf_counter() - t0)
