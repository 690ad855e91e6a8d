"""Co-design test problems with published optima, solved simultaneously and nested in CasADi.

Combined plant-and-control design ("co-design") chooses a plant variable and the controller together.
Herber and Allison [HA19]_ state three test problems with known optima, used here to check the two
strategies the study's co-design uses before it is trusted on the ball screw:

* **simultaneous**: one NLP over the plant variable and the control (the open-loop control transcribed by
  Hermite-Simpson direct collocation);
* **nested**: the plant variable outside, the control problem inside (one compiled, parametric NLP solved
  for each plant); the outer gradient is the inner optimum's sensitivity to the plant, the multiplier of
  the parameter that IPOPT returns (``lam_p``), so the outer loop never differentiates through iterations.

TP1 (section 5.1): scalar plant ``xi' = -b xi + u`` with a static gain ``u = -K xi``; the cost is the
closed-form LQ integral ``w_c (q + r K^2) / (2 (b + K)) + w_p b``. TP2 (section 5.2): an oscillator
``xi1' = xi2``, ``xi2' = -k xi1 + u`` brought to rest at ``tf`` with least ``int u^2``; the inner value
has a closed form for every stiffness (:func:`tp2_closed_form`). TP3 (section 5.3): a strain-actuated
solar array, ``xi2' = (-k xi1 + u) / J`` with ``|u| <= u_max``, maximising ``xi1(tf)`` with
``xi2(tf) = 0``; its optimal control is bang-bang with one switch.

References
----------
.. [HA19] D. R. Herber and J. T. Allison, "Nested and simultaneous solution strategies for general
   combined plant and control design problems", J. Mech. Des. 141(1):011402, 2019,
   doi:10.1115/1.4040705.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np
from scipy import optimize

__all__ = [
    "CodesignProblemSolution",
    "TP1",
    "TP2",
    "TP3",
    "solve_tp1",
    "solve_tp2",
    "solve_tp3",
    "tp1_closed_form",
    "tp2_closed_form",
    "tp2_optimum",
    "hermite_simpson",
]

STRATEGIES = ("simultaneous", "nested")


# ---------------------------------------------------------------------------------------------------
# the problems' data and their closed forms
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TP1:
    """TP1 of [HA19]_ (section 5.1): weights and LQ costs of the scalar plant with a static gain."""

    q: float = 10.0
    r: float = 1.0
    w_c: float = 1.0
    w_p: float = 0.3

    def __post_init__(self) -> None:
        for name in ("q", "r", "w_c"):
            if not getattr(self, name) > 0:
                raise ValueError(f"TP1.{name} must be positive, got {getattr(self, name)!r}")
        if not 0 <= self.w_p < self.w_c * self.r:
            raise ValueError(f"TP1.w_p must be in [0, w_c r) for a finite optimum, got {self.w_p!r}")

    def cost(self, b: float, K: float) -> float:
        """``Psi(b, K) = w_c (q + r K^2) / (2 (b + K)) + w_p b``, the LQ integral for a static gain."""
        return self.w_c * (self.q + self.r * K**2) / (2.0 * (b + K)) + self.w_p * b


@dataclass(frozen=True)
class TP2:
    """TP2 of [HA19]_ (section 5.2): horizon ``tf_s`` and the initial state ``(x0, v0)``."""

    tf_s: float = 1.0
    x0: float = 1.0
    v0: float = 2.0

    def __post_init__(self) -> None:
        if not self.tf_s > 0:
            raise ValueError(f"TP2.tf_s must be positive, got {self.tf_s!r}")
        if self.x0 == 0 and self.v0 == 0:
            raise ValueError("TP2 needs a nonzero initial state (x0, v0); at rest the cost is zero for every k")


@dataclass(frozen=True)
class TP3:
    """TP3 of [HA19]_ (section 5.3): inertia ``J``, the control bound ``u_max`` and the horizon ``tf_s``."""

    J: float = 1.0
    u_max: float = 1.0
    tf_s: float = 2.0

    def __post_init__(self) -> None:
        for name in ("J", "u_max", "tf_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"TP3.{name} must be positive, got {getattr(self, name)!r}")

    def published_optimum(self) -> tuple[float, float]:
        """``(k*, xi1(tf)*)`` of [HA19]_'s general solution, scaled by ``J``, ``u_max`` and ``tf``."""
        return (3.41729159389659 * self.J / self.tf_s**2,
                0.3007828461568226 * self.u_max * self.tf_s**2 / self.J)


def tp1_closed_form(problem: TP1 = TP1()) -> tuple[float, float, float]:
    """``(b*, K*, Psi*)`` of TP1 in closed form ([HA19]_, section 5.1).

    The best gain for a plant is ``K(b) = sqrt(b^2 + q/r) - b``; with ``a = 1 - w_p/(w_c r)`` the best
    plant is ``b* = a sqrt(q/r) / sqrt(1 - a^2)`` and ``Psi* = w_c sqrt(q r (1 - a^2))``.
    """
    a = 1.0 - problem.w_p / (problem.w_c * problem.r)
    b = a * math.sqrt(problem.q / problem.r) / math.sqrt(1.0 - a * a)
    K = math.sqrt(b * b + problem.q / problem.r) - b
    return b, K, problem.w_c * math.sqrt(problem.q * problem.r * (1.0 - a * a))


def tp2_closed_form(k: float, problem: TP2 = TP2()) -> float:
    """The least ``int_0^tf u^2 dt`` that brings TP2's oscillator of stiffness ``k > 0`` to rest.

    The inner (control) problem of TP2 is a minimum-energy transfer of a linear system, solved by its
    controllability Gramian; [HA19]_ (section 5.2) states the result in closed form, used here.
    """
    if k <= 0:
        if k == 0:
            f, x0, v0 = problem.tf_s, problem.x0, problem.v0
            return 4.0 * (3 * x0**2 + f**2 * v0**2 + 3 * f * v0 * x0) / f**3
        raise ValueError(f"tp2_closed_form: k must be >= 0, got {k!r}")
    f, x0, v0 = problem.tf_s, problem.x0, problem.v0
    s = math.sqrt(k)
    num = (f * (2 * k * v0**2 + 2 * k**2 * x0**2) + k**1.5 * x0**2 * math.sin(2 * f * s)
           - s * v0**2 * math.sin(2 * f * s) + 4 * f**2 * k**2 * v0 * x0)
    return num / (k * f**2 - math.sin(f * s) ** 2) - 4 * k * v0 * x0


# ---------------------------------------------------------------------------------------------------
# Hermite-Simpson direct collocation, written once for both strategies
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Transcription:
    w: ca.SX            # the collocation unknowns: states at nodes and midpoints, controls at both
    p: ca.SX            # the plant variables (a decision variable or a parameter)
    defects: ca.SX      # the Hermite-Simpson defects (== 0)
    quadrature: ca.SX   # Simpson quadrature of the running cost
    x_nodes: ca.SX      # (nx, N+1) states at the nodes
    u_all: ca.SX        # (nu, 2N+1) controls at nodes and midpoints, in time order
    N: int
    tf_s: float


def hermite_simpson(dynamics: Callable[[ca.SX, ca.SX, ca.SX], ca.SX], nx: int, nu: int, n_p: int,
                    N: int, tf_s: float,
                    running_cost: Callable[[ca.SX, ca.SX, ca.SX], ca.SX] | None = None) -> _Transcription:
    """Transcribe ``x' = f(x, u, p)`` on ``[0, tf]`` by separated Hermite-Simpson collocation.

    On each of the ``N`` equal intervals of width ``h``: the midpoint state
    ``x_m = (x_k + x_k+1)/2 + h/8 (f_k - f_k+1)`` and the Simpson step
    ``x_k+1 = x_k + h/6 (f_k + 4 f_m + f_k+1)``; the running cost is integrated by Simpson's rule with the
    same nodes. The control is a decision at each node and midpoint.
    """
    if N < 1:
        raise ValueError(f"hermite_simpson: N must be a positive integer, got {N!r}")
    h = tf_s / N
    X = ca.SX.sym("x", nx, N + 1)
    Xm = ca.SX.sym("xm", nx, N)
    U = ca.SX.sym("u", nu, 2 * N + 1)
    p = ca.SX.sym("p", n_p)
    defects = []
    quad: ca.SX = ca.SX(0)
    for k in range(N):
        xk, xk1, xm = X[:, k], X[:, k + 1], Xm[:, k]
        uk, um, uk1 = U[:, 2 * k], U[:, 2 * k + 1], U[:, 2 * k + 2]
        fk, fm, fk1 = dynamics(xk, uk, p), dynamics(xm, um, p), dynamics(xk1, uk1, p)
        defects.append(xm - (0.5 * (xk + xk1) + h / 8.0 * (fk - fk1)))
        defects.append(xk1 - (xk + h / 6.0 * (fk + 4.0 * fm + fk1)))
        if running_cost is not None:
            quad += h / 6.0 * (running_cost(xk, uk, p) + 4.0 * running_cost(xm, um, p)
                               + running_cost(xk1, uk1, p))
    w = ca.vertcat(ca.vec(X), ca.vec(Xm), ca.vec(U))
    return _Transcription(w=w, p=p, defects=ca.vertcat(*defects), quadrature=quad, x_nodes=X,
                          u_all=U, N=N, tf_s=tf_s)


# ---------------------------------------------------------------------------------------------------
# the result
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CodesignProblemSolution:
    """One strategy's answer to one test problem, beside the published optimum.

    Attributes
    ----------
    problem : str
        ``"TP1"``, ``"TP2"`` or ``"TP3"``.
    strategy : str
        ``"simultaneous"`` or ``"nested"``.
    plant : float
        The plant variable found (``b`` for TP1, the stiffness ``k`` for TP2 and TP3).
    objective : float
        The objective at the answer (TP3: ``xi1(tf)``, maximised).
    published_objective : float
        The optimum [HA19]_ states (recomputed in closed form where one exists).
    control : tuple of float
        TP1: the gain ``(K,)``; TP2/TP3: the control at the collocation nodes and midpoints.
    success : bool
        Whether every NLP the strategy solved converged.
    solves : int
        NLP solves spent (1 for simultaneous; the inner solves for nested).
    time_s : float
        Wall time of the solve.
    """

    problem: str
    strategy: str
    plant: float
    objective: float
    published_objective: float
    control: tuple[float, ...] = field(repr=False)
    success: bool
    solves: int
    time_s: float

    def __post_init__(self) -> None:
        if self.strategy not in STRATEGIES:
            raise ValueError(f"strategy must be one of {STRATEGIES}, got {self.strategy!r}")
        if not (math.isfinite(self.objective) and math.isfinite(self.plant)):
            raise ValueError(f"{self.problem} ({self.strategy}): non-finite answer "
                             f"plant={self.plant!r}, objective={self.objective!r}")

    @property
    def objective_ratio(self) -> float:
        """``objective / published_objective`` (1.0 is the published optimum)."""
        return self.objective / self.published_objective


_IPOPT: dict[str, Any] = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.tol": 1e-10}


def _check_strategy(strategy: str) -> None:
    if strategy not in STRATEGIES:
        raise ValueError(f"strategy must be one of {STRATEGIES}, got {strategy!r}")


def _nested_outer(inner: Callable[[float], tuple[float, float, np.ndarray, bool]], start: float,
                  bounds: tuple[float, float]) -> tuple[float, float, np.ndarray, bool, int]:
    """Minimise ``psi(p) = min_u J(p, u)`` over the scalar plant ``p`` with the inner optimum's gradient.

    ``inner(p)`` returns ``(psi, dpsi/dp, u*, converged)``; the gradient is the inner NLP's parameter
    sensitivity, so the outer quasi-Newton (L-BFGS-B, bounded) sees the true derivative of ``psi``.
    """
    cache: dict[float, tuple[float, float, np.ndarray, bool]] = {}
    ok = [True]

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        key = float(x[0])
        if key not in cache:
            cache[key] = inner(key)
            ok[0] = ok[0] and cache[key][3]
        psi, grad, _, _ = cache[key]
        return psi, np.array([grad])

    res = optimize.minimize(fun, np.array([start]), jac=True, method="L-BFGS-B", bounds=[bounds],
                            options={"ftol": 1e-14, "gtol": 1e-9, "maxiter": 200})
    p = float(res.x[0])
    psi, _, u, conv = cache[p] if p in cache else inner(p)
    return p, psi, u, bool(res.success and ok[0] and conv), len(cache)


# ---------------------------------------------------------------------------------------------------
# TP1
# ---------------------------------------------------------------------------------------------------
@lru_cache(maxsize=4)
def _tp1_functions(problem: TP1) -> tuple[ca.Function, ca.Function]:
    b, K = ca.SX.sym("b"), ca.SX.sym("K")
    psi = problem.w_c * (problem.q + problem.r * K**2) / (2 * (b + K)) + problem.w_p * b
    both = ca.nlpsol("tp1_simultaneous", "ipopt", {"x": ca.vertcat(b, K), "f": psi}, _IPOPT)
    inner = ca.nlpsol("tp1_inner", "ipopt", {"x": K, "p": b, "f": psi}, _IPOPT)
    return both, inner


def solve_tp1(strategy: str, problem: TP1 = TP1(), start: tuple[float, float] = (0.0, 1.0)) -> CodesignProblemSolution:
    """Solve TP1 (plant ``b``, static gain ``K``) by ``strategy``; ``start`` is ``(b, K)``.

    Simultaneous: one NLP over ``(b, K)``. Nested: the outer loop over ``b``, the best gain for each
    ``b`` inside, the outer gradient from the inner optimum's sensitivity to ``b``.
    """
    _check_strategy(strategy)
    both, inner = _tp1_functions(problem)
    published = tp1_closed_form(problem)[2]
    t0 = time.perf_counter()
    if strategy == "simultaneous":
        sol = both(x0=list(start), lbx=[0.0, 0.0], ubx=[ca.inf, ca.inf])
        ok = both.stats()["success"]
        b, K = (float(v) for v in np.asarray(sol["x"]).ravel())
        return CodesignProblemSolution("TP1", strategy, b, problem.cost(b, K), published, (K,), bool(ok), 1,
                                       time.perf_counter() - t0)
    K_last = [max(start[1], 1e-3)]

    def solve_inner(b: float) -> tuple[float, float, np.ndarray, bool]:
        sol = inner(x0=K_last[0], p=b, lbx=0.0, ubx=ca.inf)
        K_last[0] = float(sol["x"])
        # lam_p is the multiplier of the parameter: d psi*/d b = -lam_p
        return float(sol["f"]), -float(sol["lam_p"]), np.array([K_last[0]]), bool(inner.stats()["success"])

    b, psi, gain, ok, n = _nested_outer(solve_inner, start[0], (0.0, 1e3))
    return CodesignProblemSolution("TP1", strategy, b, psi, published, (float(gain[0]),), ok, n,
                                   time.perf_counter() - t0)


# ---------------------------------------------------------------------------------------------------
# TP2
# ---------------------------------------------------------------------------------------------------
def _tp2_dynamics(x: ca.SX, u: ca.SX, p: ca.SX) -> ca.SX:
    return ca.vertcat(x[1], -p[0] * x[0] + u[0])


@lru_cache(maxsize=8)
def _tp2_functions(problem: TP2, N: int) -> tuple[ca.Function, ca.Function, int]:
    tr = hermite_simpson(_tp2_dynamics, 2, 1, 1, N, problem.tf_s, lambda x, u, p: u[0] ** 2)
    X = tr.x_nodes
    bc = ca.vertcat(X[:, 0] - ca.DM([problem.x0, problem.v0]), X[:, -1])
    g = ca.vertcat(tr.defects, bc)
    both = ca.nlpsol("tp2_simultaneous", "ipopt", {"x": ca.vertcat(tr.p, tr.w), "f": tr.quadrature, "g": g},
                     _IPOPT)
    inner = ca.nlpsol("tp2_inner", "ipopt", {"x": tr.w, "p": tr.p, "f": tr.quadrature, "g": g}, _IPOPT)
    return both, inner, int(tr.w.numel())


def _controls(w: np.ndarray, nx: int, N: int) -> tuple[float, ...]:
    return tuple(float(v) for v in w[nx * (2 * N + 1):])


def _tp2_scan(problem: TP2, bounds: tuple[float, float]) -> tuple[float, float, float]:
    """The best stiffness on a log-spaced grid of the exact inner value, and its two grid neighbours.

    This is the start that escapes TP2's local minima; its bracket refines the closed-form optimum.
    """
    grid = np.concatenate([[bounds[0]], np.geomspace(max(bounds[0], 1e-2), bounds[1], 400)])
    values = [tp2_closed_form(float(k), problem) for k in grid]
    i = int(np.argmin(values))
    return float(grid[i]), float(grid[max(i - 1, 0)]), float(grid[min(i + 1, len(grid) - 1)])


def tp2_optimum(problem: TP2 = TP2(), bounds: tuple[float, float] = (0.0, 200.0)) -> tuple[float, float]:
    """``(k*, Psi*)`` of TP2 from its closed-form inner value: a grid scan, then a bounded 1-D refinement."""
    k0, lo, hi = _tp2_scan(problem, bounds)
    res = optimize.minimize_scalar(lambda k: tp2_closed_form(k, problem), bounds=(lo, hi), method="bounded",
                                   options={"xatol": 1e-12})
    if res.fun < tp2_closed_form(k0, problem):
        return float(res.x), float(res.fun)
    return k0, tp2_closed_form(k0, problem)


def solve_tp2(strategy: str, problem: TP2 = TP2(), N: int = 100, start: float | None = None,
              bounds: tuple[float, float] = (0.0, 200.0)) -> CodesignProblemSolution:
    """Solve TP2 (stiffness ``k`` and the open-loop control) by ``strategy`` with ``N`` Hermite-Simpson intervals.

    ``start=None`` takes the best stiffness of a grid scan of the closed-form inner value (TP2's
    ``(2, 0, -1)`` case has local minima near 12, 26 and 44 that a start at 8, 15 or 30 ends in); a given
    ``start`` is used as it is, so the trap can be shown.
    """
    _check_strategy(strategy)
    both, inner, nw = _tp2_functions(problem, N)
    published = tp2_optimum(problem, bounds)[1]
    k0 = _tp2_scan(problem, bounds)[0] if start is None else float(start)
    t0 = time.perf_counter()
    lbg = ubg = 0.0
    if strategy == "simultaneous":
        sol = both(x0=np.concatenate([[k0], np.zeros(nw)]), lbx=[bounds[0]] + [-ca.inf] * nw,
                   ubx=[bounds[1]] + [ca.inf] * nw, lbg=lbg, ubg=ubg)
        x = np.asarray(sol["x"]).ravel()
        return CodesignProblemSolution("TP2", strategy, float(x[0]), float(sol["f"]), published,
                                       _controls(x[1:], 2, N), bool(both.stats()["success"]), 1,
                                       time.perf_counter() - t0)
    w_last = [np.zeros(nw)]

    def solve_inner(k: float) -> tuple[float, float, np.ndarray, bool]:
        sol = inner(x0=w_last[0], p=k, lbg=lbg, ubg=ubg)
        w_last[0] = np.asarray(sol["x"]).ravel()
        return float(sol["f"]), -float(sol["lam_p"]), w_last[0], bool(inner.stats()["success"])

    k, psi, w, ok, n = _nested_outer(solve_inner, k0, bounds)
    return CodesignProblemSolution("TP2", strategy, k, psi, published, _controls(w, 2, N), ok, n,
                                   time.perf_counter() - t0)


# ---------------------------------------------------------------------------------------------------
# TP3
# ---------------------------------------------------------------------------------------------------
@lru_cache(maxsize=8)
def _tp3_functions(problem: TP3, N: int) -> tuple[ca.Function, ca.Function, int, int]:
    def f(x: ca.SX, u: ca.SX, p: ca.SX) -> ca.SX:
        return ca.vertcat(x[1], (-p[0] * x[0] + u[0]) / problem.J)

    tr = hermite_simpson(f, 2, 1, 1, N, problem.tf_s)
    X = tr.x_nodes
    g = ca.vertcat(tr.defects, X[:, 0], X[1, -1])
    objective = -X[0, -1]  # maximise xi1(tf)
    both = ca.nlpsol("tp3_simultaneous", "ipopt", {"x": ca.vertcat(tr.p, tr.w), "f": objective, "g": g},
                     _IPOPT)
    inner = ca.nlpsol("tp3_inner", "ipopt", {"x": tr.w, "p": tr.p, "f": objective, "g": g}, _IPOPT)
    n_states = 2 * (N + 1) + 2 * N
    return both, inner, int(tr.w.numel()), n_states


def solve_tp3(strategy: str, problem: TP3 = TP3(), N: int = 100, start: float | None = None,
              k_max: float | None = None) -> CodesignProblemSolution:
    """Solve TP3 (stiffness ``k``, bounded open-loop torque) by ``strategy`` with ``N`` Hermite-Simpson intervals.

    The objective is flat in ``k``, and an unbounded stiffness can drift far (a large ``k`` is a second,
    poorer optimum): ``k`` is bounded to ``[0, k_max]`` (default ``10 J / tf^2``, about three times the
    optimum) and starts at ``start`` (default ``J / tf^2``).
    """
    _check_strategy(strategy)
    both, inner, nw, n_states = _tp3_functions(problem, N)
    published = problem.published_optimum()[1]
    k0 = problem.J / problem.tf_s**2 if start is None else float(start)
    kmax = 10.0 * problem.J / problem.tf_s**2 if k_max is None else float(k_max)
    lbw = np.concatenate([np.full(n_states, -ca.inf), np.full(nw - n_states, -problem.u_max)])
    ubw = np.concatenate([np.full(n_states, ca.inf), np.full(nw - n_states, problem.u_max)])
    w0 = np.zeros(nw)
    t0 = time.perf_counter()
    if strategy == "simultaneous":
        sol = both(x0=np.concatenate([[k0], w0]), lbx=np.concatenate([[0.0], lbw]),
                   ubx=np.concatenate([[kmax], ubw]), lbg=0.0, ubg=0.0)
        x = np.asarray(sol["x"]).ravel()
        return CodesignProblemSolution("TP3", strategy, float(x[0]), -float(sol["f"]), published,
                                       _controls(x[1:], 2, N), bool(both.stats()["success"]), 1,
                                       time.perf_counter() - t0)
    w_last = [w0]

    def solve_inner(k: float) -> tuple[float, float, np.ndarray, bool]:
        sol = inner(x0=w_last[0], p=k, lbx=lbw, ubx=ubw, lbg=0.0, ubg=0.0)
        w_last[0] = np.asarray(sol["x"]).ravel()
        return float(sol["f"]), -float(sol["lam_p"]), w_last[0], bool(inner.stats()["success"])

    k, psi, w, ok, n = _nested_outer(solve_inner, k0, (0.0, kmax))
    return CodesignProblemSolution("TP3", strategy, k, -psi, published, _controls(w, 2, N), ok, n,
                                   time.perf_counter() - t0)
