"""Identification of P-I hysteresis models as a constrained least-squares QP (cvxpy + Clarabel).

Every model of :mod:`piezopreload.models.hysteresis` is linear in its weights once the
thresholds are fixed, so identification is ``min ||Phi x - y||^2`` subject to linear
inequalities: nonnegative weights (classical and the paper's asymmetric model), and for
Kuhnen's modified model the invertibility constraints of its dead-zone superposition. With
``creep=True`` the lags of a creep operator bank join the regressors and their weights the
decision variables, constrained nonnegative (see :class:`PIIdentifier`).

The QP never sees the samples: the least-squares term is compressed to the Cholesky factor
of the (column-scaled) Gram matrix, ``p x p`` with ``p`` the number of parameters, so its
size and solve time do not grow with the record length. After the interior-point solve the
active set is *polished* (the equality-constrained least-squares problem on the active
constraints is solved directly, and kept only if it is feasible with nonnegative multipliers),
which recovers exact weights to machine precision on noise-free data.

The paper's own method, cubic polynomials fitted to the ascending and descending branches
and weights read from their slopes (eq. (17)), is :func:`paper_branch_weights`: a baseline.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezopreload.artifacts.hysteresis import FitError
from piezopreload.core.errors import InputError, PiezopreloadError
from piezopreload.models.hysteresis import (
    AsymmetricPI,
    ClassicalPI,
    Creep,
    CreepPI,
    DeadZone,
    HysteresisModel,
    ModifiedPI,
    creep_lags,
    deadzone,
    lag_coefficients,
    log_spaced_time_constants,
    play,
    rising,
    uniform_thresholds,
)

__all__ = [
    "MODELS",
    "paper_baseline",
    "NotFittedError",
    "IdentificationError",
    "PIIdentifier",
    "fit_error",
    "paper_branch_weights",
    "straight_line",
]

MODELS: tuple[ModelName, ...] = ("classical", "paper-asymmetric", "modified")
ModelName = Literal["classical", "paper-asymmetric", "modified"]


class NotFittedError(PiezopreloadError, RuntimeError):
    """The estimator was used before :meth:`PIIdentifier.fit`."""


class IdentificationError(InputError):
    """The data cannot identify the requested model (too short, constant, solver failure)."""


# --------------------------------------------------------------------------------------
# error metrics
# --------------------------------------------------------------------------------------
def fit_error(predicted: ArrayLike, measured: ArrayLike, span: float, window_s: tuple[float, float] | None = None
              ) -> FitError:
    """RMS and largest absolute error as a percentage of ``span`` (the record's output span)."""
    e = np.asarray(predicted, float) - np.asarray(measured, float)
    return FitError(float(100.0 * np.sqrt(np.mean(e**2)) / span), float(100.0 * np.max(np.abs(e)) / span),
                    window_s, int(e.size))


def straight_line(v: ArrayLike, y: ArrayLike) -> tuple[float, float]:
    """Least-squares line ``y = slope * v + intercept``: what a model without hysteresis buys."""
    slope, intercept = np.polyfit(np.asarray(v, float), np.asarray(y, float), 1)
    return float(slope), float(intercept)


# --------------------------------------------------------------------------------------
# the compressed, polished QP
# --------------------------------------------------------------------------------------
@dataclass
class _QPResult:
    x: NDArray[np.float64]
    status: str
    solve_time_s: float
    iterations: int
    polished: bool


def _solve_constrained_lsq(
    phi: NDArray[np.float64],
    y: NDArray[np.float64],
    a_ineq: NDArray[np.float64],
    b_ineq: NDArray[np.float64],
    *,
    ridge: float,
    penalised: NDArray[np.bool_],
    solver_options: dict[str, Any],
) -> _QPResult:
    """``min ||phi x - y||^2 / N + ridge ||s * x||^2  s.t.  a_ineq x >= b_ineq``.

    Columns are scaled to unit RMS first (``s`` the scales), so ``ridge`` is dimensionless
    and the Gram matrix is as well conditioned as the data allow.
    """
    n_samples, p = phi.shape
    scale = np.sqrt(np.mean(phi**2, axis=0))
    scale[scale == 0] = 1.0
    y_scale = max(float(np.sqrt(np.mean(y**2))), 1e-300)
    a = phi / scale
    gram = a.T @ a / n_samples
    rhs = a.T @ (y / y_scale) / n_samples
    gram[np.diag_indices(p)] += ridge * penalised
    try:
        chol = np.linalg.cholesky(gram)
    except np.linalg.LinAlgError:
        jitter = 1e-12 * np.trace(gram) / p
        try:
            chol = np.linalg.cholesky(gram + jitter * np.eye(p))
        except np.linalg.LinAlgError:
            raise IdentificationError(
                "the regressors are linearly dependent (is an operator never moved by the input?); "
                "use fewer operators or a ridge term (--ridge)"
            ) from None
    target = np.linalg.solve(chol, rhs)
    a_scaled = a_ineq * (y_scale / scale)  # constraints on the scaled variable z = x * scale / y_scale

    import cvxpy as cp  # here, not at import: cvxpy (and the scipy.stats it loads) costs a second and a half

    z = cp.Variable(p)
    constraints = [a_scaled @ z >= b_ineq] if a_ineq.shape[0] else []
    problem = cp.Problem(cp.Minimize(cp.sum_squares(chol.T @ z - target)), constraints)
    t0 = time.perf_counter()
    try:
        problem.solve(solver=cp.CLARABEL, **solver_options)
    except cp.error.SolverError as exc:
        raise IdentificationError(f"the QP solver failed: {exc}") from None
    seconds = time.perf_counter() - t0
    status = str(problem.status)
    if status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) or z.value is None:
        why = {
            cp.INFEASIBLE: "the constraints cannot all hold",
            cp.UNBOUNDED: "the objective is unbounded",
        }.get(status, "the solver stopped without a solution")
        raise IdentificationError(f"the QP ended with status '{status}': {why}")
    zq = np.asarray(z.value, float)
    stats = problem.solver_stats
    iterations = int(stats.num_iters or 0) if stats is not None else 0

    # ---- polish: the equality-constrained problem on the active set, solved exactly --------
    polished = False
    if a_ineq.shape[0]:
        zp = _polish(gram, rhs, a_scaled, b_ineq, zq)
        if zp is not None:
            zq, polished = zp, True
    else:
        zq, polished = np.linalg.solve(gram, rhs), True
    return _QPResult(
        x=zq * y_scale / scale, status=status, solve_time_s=seconds, iterations=iterations, polished=polished
    )


def _polish(
    gram: NDArray, rhs: NDArray, a: NDArray, b: NDArray, z0: NDArray, max_rounds: int = 50
) -> NDArray | None:
    """Refine an interior-point solution of ``min z'Gz - 2 rhs'z s.t. a z >= b`` on its active set.

    Interior-point iterates stop short of the boundary. Starting from the constraints that are
    nearly active at ``z0``, solve the KKT system with those as equalities, add constraints the
    result violates, drop those whose multiplier is negative, and repeat: a primal-dual active-set
    refinement that usually ends in one or two rounds. Returns None when it does not settle on
    a feasible point with nonnegative multipliers that is at least as good as ``z0``.
    """
    p = gram.shape[0]
    row_norm = np.linalg.norm(a, axis=1)
    slack = a @ z0 - b
    active = slack <= 1e-4 * row_norm * max(float(np.max(np.abs(z0))), 1.0)
    objective = lambda z: z @ gram @ z - 2 * rhs @ z  # noqa: E731
    feas_tol = 1e-10 * np.maximum(row_norm, 1.0)
    dual_tol = 1e-10 * max(1.0, float(np.max(np.abs(rhs))))
    for _ in range(max_rounds):
        aa = a[active]
        k = aa.shape[0]
        kkt = np.block([[gram, aa.T], [aa, np.zeros((k, k))]])
        try:
            sol = np.linalg.solve(kkt, np.concatenate([rhs, b[active]]))
        except np.linalg.LinAlgError:
            return None
        z, mult = sol[:p], -sol[p:]  # stationarity: gram z - rhs = aa' mult, mult >= 0
        violated = a @ z - b < -feas_tol
        negative = mult < -dual_tol
        if not violated.any() and not negative.any():
            return z if objective(z) <= objective(z0) + 1e-12 * max(1.0, abs(objective(z0))) else None
        idx = np.flatnonzero(active)
        if negative.any():  # release the most negative multiplier first
            active[idx[np.argmin(mult)]] = False
        active |= violated
    return None


# --------------------------------------------------------------------------------------
# the estimator
# --------------------------------------------------------------------------------------
@dataclass
class PIIdentifier:
    """Identify a P-I model from a measured input/output record.

    Parameters
    ----------
    model : {"classical", "paper-asymmetric", "modified"}
        Eq. (15), eq. (18), or Kuhnen's modified P-I model.
    n_operators : int
        Number of play operators ``n`` (the paper uses 40).
    thresholds : {"range", "paper"} or array_like
        ``"range"``: ``r_k = (k-1)/n * max|v|`` over the whole record (operators start at rest,
        so every one of them moves); ``"paper"``: eq. (16), ``r_k = (k-1)/n * v_max``;
        or explicit thresholds starting at 0.
    ridge : float
        Dimensionless ridge weight on the column-scaled weights (0: none).
    n_deadzone : int
        Dead-zone operators on each side of the linear one (modified model only).
    min_slope : float
        Invertibility margin of the modified model: the smallest slope of its dead-zone
        superposition relative to the central slope of 1, and the smallest linear weight ``w_1``
        relative to the record's average slope ``ptp(y) / ptp(v)``; with ``invertible``, the
        same bound on ``w_1`` of the classical model.
    invertible : bool
        Classical model only: bound ``w_1`` away from 0 so the model has an inverse (eq. (20)
        divides by ``w_1``). A feedforward needs it; plain NNLS weights may put ``w_1 = 0``.
    solver_options : dict
        Passed to ``cvxpy.Problem.solve`` with ``solver=CLARABEL``.
    creep : bool
        Add a bank of linear creep operators on the input (:class:`~piezopreload.models.hysteresis.Creep`),
        identified with the hysteresis weights in the same QP; the model is then a
        :class:`~piezopreload.models.hysteresis.CreepPI`. :meth:`fit` needs ``sample_period_s``.
        The creep weights are constrained nonnegative: creep then only ever follows the input
        (a step up creeps up), the one-sample map's linear weight ``w_1 + beta`` stays at least
        ``w_1``, so the invertibility bound on ``w_1`` keeps the model invertible at every
        sample period, and the inverse's linear part (``w_1`` plus positive-real lags) has no
        zero outside the unit circle: the compensator is stable.
    creep_time_constants_s : "log" or array_like
        The lags' time constants. ``"log"``: one per decade from ``creep_shortest_s`` to the
        record's duration (:func:`~piezopreload.models.hysteresis.log_spaced_time_constants`);
        or explicit, strictly increasing values in s.
    creep_shortest_s : float
        The shortest time constant of the ``"log"`` bank.

    Attributes
    ----------
    model_ : HysteresisModel or CreepPI
        The identified model (every attribute ending in ``_`` is set by :meth:`fit`).
    thresholds_ : ndarray
        The play operators' thresholds.
    time_constants_s_ : ndarray or None
        The creep bank's time constants (creep only).
    status_ : str
        The solver's status.
    solve_time_s_ : float
        The QP's time.
    fit_time_s_ : float
        The whole fit's time: the operators, the compression and the QP.
    polished_ : bool
        Whether the active-set polish was accepted.
    n_train_ : int
        The samples used.
    """

    model: ModelName = "classical"
    n_operators: int = 40
    thresholds: str | ArrayLike = "range"
    ridge: float = 0.0
    n_deadzone: int = 3
    min_slope: float = 0.05
    invertible: bool = False
    solver_options: dict[str, Any] = field(default_factory=dict)
    creep: bool = False
    creep_time_constants_s: str | ArrayLike = "log"
    creep_shortest_s: float = 0.01

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"model must be one of {', '.join(MODELS)}, got {self.model!r}.")
        if int(self.n_operators) != self.n_operators or self.n_operators < 1:
            raise ValueError(f"n_operators must be a positive integer, got {self.n_operators!r}.")
        if not np.isfinite(self.ridge) or self.ridge < 0:
            raise ValueError(f"ridge must be >= 0, got {self.ridge!r}.")
        if int(self.n_deadzone) != self.n_deadzone or self.n_deadzone < 0:
            raise ValueError(f"n_deadzone must be a nonnegative integer, got {self.n_deadzone!r}.")
        if not 0 < self.min_slope <= 1:
            raise ValueError(f"min_slope must be in (0, 1], got {self.min_slope!r}.")
        if isinstance(self.thresholds, str) and self.thresholds not in ("range", "paper"):
            raise ValueError(f"thresholds must be 'range', 'paper' or an array, got {self.thresholds!r}.")
        if isinstance(self.creep_time_constants_s, str):
            if self.creep_time_constants_s != "log":
                raise InputError(
                    "creep_time_constants_s must be 'log' or an array of time constants in s, "
                    f"got {self.creep_time_constants_s!r}."
                )
        else:
            taus = np.asarray(self.creep_time_constants_s, dtype=np.float64)
            Creep(taus, np.zeros(taus.size), 1.0)  # validates
        if not (np.isfinite(self.creep_shortest_s) and self.creep_shortest_s > 0):
            raise InputError(f"creep_shortest_s must be a positive time in s, got {self.creep_shortest_s!r}.")

    # ---- helpers ---------------------------------------------------------------------
    def _thresholds(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        if isinstance(self.thresholds, str):
            reach = float(np.max(v)) if self.thresholds == "paper" else float(np.max(np.abs(v)))
            if reach <= 0:
                raise IdentificationError(
                    "the input never leaves 0 (or, with thresholds='paper', never goes positive): "
                    "the play operators cannot be excited"
                )
            return uniform_thresholds(self.n_operators, reach)
        r = np.asarray(self.thresholds, float)
        return ClassicalPI(r, np.ones_like(r)).thresholds

    def _time_constants(self, n_samples: int, dt: float) -> NDArray[np.float64]:
        if isinstance(self.creep_time_constants_s, str):
            duration = (n_samples - 1) * dt
            if duration <= self.creep_shortest_s:
                raise IdentificationError(
                    f"the record lasts {duration:.3g} s, no longer than the shortest creep time constant "
                    f"creep_shortest_s={self.creep_shortest_s} s; give a longer record or explicit time constants"
                )
            return log_spaced_time_constants(self.creep_shortest_s, duration)
        return np.asarray(self.creep_time_constants_s, float)

    # ---- fit ----------------------------------------------------------------------------
    def fit(
        self,
        v: ArrayLike,
        y: ArrayLike,
        train: ArrayLike | slice | None = None,
        state: ArrayLike | None = None,
        *,
        sample_period_s: float | None = None,
    ) -> PIIdentifier:
        """Identify the weights from input ``v`` and measured output ``y``; returns the estimator.

        The operators run over the whole record from ``state`` (at rest by default), so a
        training window that starts late still sees the right operator states; only the
        samples selected by ``train`` (boolean mask or slice; all by default) enter the fit.
        With ``creep``, ``sample_period_s`` is the record's sample period and ``state`` may
        hold the play operators' states (the lags then start at rest at 0) or a whole
        :class:`~piezopreload.models.hysteresis.CreepPI` state.

        Parameters
        ----------
        v : array_like
            The record's input (V for a stack), one value per sample.
        y : array_like
            The measured output (N), one value per sample.
        train : array_like, slice or None
            The samples that enter the fit: a boolean mask or a slice (None: all).
        state : array_like or None
            The operators' state at the first sample (None: at rest).
        sample_period_s : float or None
            The record's sample period, in s: needed with ``creep``.

        Returns
        -------
        PIIdentifier
            The estimator itself, fitted (its ``model_`` set).

        Raises
        ------
        IdentificationError
            Where the input is constant over the window, the window has too few samples for the weights, or
            the QP solver fails.
        """
        t0 = time.perf_counter()
        v, y, rows = _record(v, y, train)
        r = self._thresholds(v)
        play_state, creep = self._creep_columns(v, rows, r.size, state, sample_period_s)
        ops = play(v, r, play_state)[rows]
        if np.ptp(v[rows]) == 0:
            raise IdentificationError("the input is constant over the training window: nothing to identify")
        problem = _PROBLEMS[self.model](self, r, ops, rising(v)[rows], y[rows], v[rows])
        if creep is not None:
            problem = problem.with_creep(*creep)
        n_params = problem.phi.shape[1]
        if problem.target.size < 2 * n_params:
            raise IdentificationError(
                f"the training window has {problem.target.size} samples for {n_params} parameters; "
                f"give at least {2 * n_params} (a longer window or fewer operators)"
            )
        qp = _solve_constrained_lsq(
            problem.phi, problem.target, problem.a_ineq, problem.b_ineq, ridge=self.ridge,
            penalised=problem.penalised, solver_options=dict(self.solver_options),
        )
        self.model_: HysteresisModel | CreepPI = problem.build(qp.x)
        if creep is not None:
            self.time_constants_s_ = creep[1]
        self.thresholds_ = r
        self.status_ = qp.status
        self.solve_time_s_ = qp.solve_time_s
        self.iterations_ = qp.iterations
        self.polished_ = qp.polished
        self.n_train_ = int(problem.target.size)
        self.fit_time_s_ = time.perf_counter() - t0
        return self

    def _creep_columns(self, v: NDArray, rows: NDArray, n: int, state: ArrayLike | None,
                       sample_period_s: float | None) -> tuple[ArrayLike | None, tuple[NDArray, NDArray, float] | None]:
        """The play operators' initial state, and with creep the lags' columns, time constants and sample period."""
        if not self.creep:
            return state, None
        if sample_period_s is None or not (np.isfinite(sample_period_s) and sample_period_s > 0):
            raise IdentificationError(
                f"creep needs the record's sample period: pass sample_period_s (s), got {sample_period_s!r}"
            )
        dt_s = float(sample_period_s)
        taus = self._time_constants(v.size, dt_s)
        play_state, creep_state = state, None
        if state is not None:
            st = np.asarray(state, float)
            if st.shape not in ((n,), (n + taus.size,)):
                raise InputError(
                    f"state must have {n} (play operators) or {n + taus.size} (play operators and creep "
                    f"carries) entries, got shape {st.shape}"
                )
            play_state, creep_state = st[:n], (st[n:] if st.size > n else None)
        return play_state, (creep_lags(v, lag_coefficients(taus, dt_s), creep_state)[rows], taus, dt_s)

    # ---- the fitted estimator -------------------------------------------------------------
    def _check_fitted(self) -> HysteresisModel | CreepPI:
        if not hasattr(self, "model_"):
            raise NotFittedError(
                "this PIIdentifier is not fitted yet; call fit(v, y) before predict, score or inverse."
            )
        return self.model_

    def predict(self, v: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        """Model output for input ``v`` from ``state`` (at rest by default).

        With creep, ``state`` is the play operators' states (lags at rest at 0) or a whole
        :class:`~piezopreload.models.hysteresis.CreepPI` state, as in :meth:`fit`.

        Parameters
        ----------
        v : array_like
            The input, one value per sample.
        state : array_like or None
            The operators' state at the first sample (None: at rest).

        Returns
        -------
        ndarray
            The model's output, one value per sample.

        Raises
        ------
        NotFittedError
            Before :meth:`fit`.
        """
        model = self._check_fitted()
        if isinstance(model, CreepPI) and state is not None and np.shape(state)[-1] == model.n_operators:
            state = np.concatenate([np.asarray(state, float), np.zeros(model.n_lags)])
        return np.asarray(model(v, state), float)

    def score(self, v: ArrayLike, y: ArrayLike, rows: ArrayLike | slice | None = None) -> float:
        """The coefficient of determination ``R^2 = 1 - SS_res / SS_tot`` of :meth:`predict` on ``y``.

        The model runs over the whole record (its operators need the history); ``rows`` (a
        boolean mask or slice, all by default) selects the samples scored, as ``train`` does in
        :meth:`fit`. 1 is a perfect fit; a model no better than the mean scores 0.

        Parameters
        ----------
        v : array_like
            The input, one value per sample.
        y : array_like
            The measured output, one value per sample.
        rows : array_like, slice or None
            The samples scored: a boolean mask or a slice (None: all).

        Returns
        -------
        float
            ``R^2`` on the rows scored: 1 for a perfect fit, 0 for the mean's.

        Raises
        ------
        InputError
            Where the output is constant over the rows scored.
        """
        v, y, keep = _record(v, y, rows)
        e = (self.predict(v) - y)[keep]
        total = float(np.sum((y[keep] - np.mean(y[keep])) ** 2))
        if total == 0:
            raise InputError("the output is constant over the scored samples: R^2 is not defined there")
        return 1.0 - float(np.sum(e**2)) / total

    def inverse(self) -> Any:
        """The fitted model's inverse: the feedforward (output -> input, eqs. (19)-(20); with creep,
        one sample at a time).

        Returns
        -------
        InverseClassicalPI, InverseAsymmetricPI, InverseModifiedPI or InverseCreepPI
            A callable from the output to the input.

        Raises
        ------
        NotFittedError
            Before :meth:`fit`.
        """
        return self._check_fitted().inverse()


def _record(v: ArrayLike, y: ArrayLike, rows: ArrayLike | slice | None) -> tuple[NDArray, NDArray, NDArray]:
    """A record's input and output (1-D, finite, of equal length) and the mask of ``rows``."""
    v = np.asarray(v, float)
    y = np.asarray(y, float)
    if v.ndim != 1 or v.shape != y.shape:
        raise ValueError(f"v and y must be 1-D of equal length, got shapes {v.shape} and {y.shape}.")
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(y))):
        raise ValueError("v and y must be finite.")
    return v, y, _mask(v.size, rows)


def _mask(n: int, rows: ArrayLike | slice | None) -> NDArray[np.bool_]:
    """The mask over ``n`` samples of ``rows``: a slice, indices or a mask (None: every sample)."""
    mask = np.zeros(n, bool)
    mask[slice(None) if rows is None else rows if isinstance(rows, slice) else np.asarray(rows)] = True
    return mask


# --------------------------------------------------------------------------------------
# the QP of each model: regressors, constraints and how the solution becomes the model
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _Problem:
    """``min ||phi x - target||^2 s.t. a_ineq x >= b_ineq`` and how ``x`` becomes the model."""

    phi: NDArray[np.float64]
    target: NDArray[np.float64]
    a_ineq: NDArray[np.float64]
    b_ineq: NDArray[np.float64]
    penalised: NDArray[np.bool_]
    build: Callable[[NDArray[np.float64]], HysteresisModel | CreepPI]

    def with_creep(self, lags: NDArray[np.float64], taus: NDArray[np.float64], dt_s: float) -> _Problem:
        """The creep lags' columns last, with nonnegative weights (see :class:`PIIdentifier`)."""
        m_c = lags.shape[1]
        a = self.a_ineq
        build = self.build

        def with_bank(x: NDArray[np.float64]) -> CreepPI:
            model = build(x[:-m_c])
            if isinstance(model, CreepPI):  # not reached: each model's build makes a plain model
                raise IdentificationError("a creep model inside a creep model")
            return CreepPI(model, Creep(taus, np.maximum(x[-m_c:], 0.0), dt_s))

        return _Problem(np.column_stack([self.phi, lags]), self.target,
                        np.block([[a, np.zeros((a.shape[0], m_c))], [np.zeros((m_c, a.shape[1])), np.eye(m_c)]]),
                        np.r_[self.b_ineq, np.zeros(m_c)], np.r_[self.penalised, np.ones(m_c, bool)], with_bank)


def _classical(est: PIIdentifier, r: NDArray, ops: NDArray, p: NDArray, y: NDArray, v: NDArray) -> _Problem:
    """Eq. (15): nonnegative weights, an offset; with ``invertible`` ``w_1`` bounded away from 0."""
    n = r.size
    b_ineq = np.zeros(n)
    if est.invertible:  # w_1 bounded away from 0, relative to the average slope
        b_ineq[0] = est.min_slope * float(np.ptp(y) / np.ptp(v))
    return _Problem(np.column_stack([ops, np.ones(y.size)]), y, np.hstack([np.eye(n), np.zeros((n, 1))]), b_ineq,
                    np.r_[np.ones(n, bool), False], lambda x: ClassicalPI(r, np.maximum(x[:n], 0.0), x[n]))


def _asymmetric(est: PIIdentifier, r: NDArray, ops: NDArray, p: NDArray, y: NDArray, v: NDArray) -> _Problem:
    """Eq. (18): the rising and the falling weights, each nonnegative, and an offset."""
    n = r.size
    q = p[:, None]
    return _Problem(np.column_stack([ops * q, ops * ~q, np.ones(y.size)]), y,
                    np.hstack([np.eye(2 * n), np.zeros((2 * n, 1))]), np.zeros(2 * n),
                    np.r_[np.ones(2 * n, bool), False],
                    lambda x: AsymmetricPI(r, np.maximum(x[:n], 0.0), np.maximum(x[n:2 * n], 0.0), x[2 * n]))


def _modified(est: PIIdentifier, r: NDArray, ops: NDArray, p: NDArray, y: NDArray, v: NDArray) -> _Problem:
    """Kuhnen's model in its inverse form: ``Gamma[v] + bias = g(y - y_ref)``, ``g`` a dead-zone superposition
    with central weight 1; linear in ``(w, bias, g)`` and so a QP. Its inverse gives the forward model."""
    n, m = r.size, int(est.n_deadzone)
    y_ref = 0.5 * (np.max(y) + np.min(y))
    up = (np.max(y) - y_ref) * np.arange(1, m + 1) / (m + 1)
    down = (np.min(y) - y_ref) * np.arange(m, 0, -1) / (m + 1)
    dz = DeadZone(np.concatenate([down, [0.0], up]), np.ones(2 * m + 1)).thresholds
    d_all = deadzone(y - y_ref, dz)
    n_g = 2 * m
    # slopes outward from the centre: 1 + partial sums of g >= min_slope
    a_g = np.zeros((n_g, n_g))
    for j in range(m):  # positive side, g indices m..2m-1 in the order of the columns left
        a_g[j, m : m + j + 1] = 1.0
        a_g[m + j, m - 1 - j : m] = 1.0  # negative side, g indices m-1 down to 0
    a_ineq = np.block([[np.eye(n), np.zeros((n, 1)), np.zeros((n, n_g))], [np.zeros((n_g, n + 1)), a_g]])
    # the play part must be invertible too: its first slope w_1 bounded away from 0, relative to
    # the record's average slope (y is in the output units of Gamma here)
    mean_slope = float(np.ptp(y) / np.ptp(v))
    b_ineq = np.r_[est.min_slope * mean_slope, np.zeros(n - 1), np.full(n_g, est.min_slope - 1.0)]

    def build(x: NDArray[np.float64]) -> ModifiedPI:
        shaper = DeadZone(dz, np.insert(x[n + 1 :], m, 1.0)).inverse()
        return ModifiedPI(r, np.maximum(x[:n], 0.0), shaper.thresholds, shaper.weights, bias=x[n], offset=y_ref)

    return _Problem(np.column_stack([ops, np.ones(y.size), -np.delete(d_all, m, axis=1)]), d_all[:, m], a_ineq,
                    b_ineq, np.r_[np.ones(n, bool), False, np.ones(n_g, bool)], build)


_PROBLEMS: dict[str, Callable[..., _Problem]] = {
    "classical": _classical, "paper-asymmetric": _asymmetric, "modified": _modified}


# --------------------------------------------------------------------------------------
# the paper's method, eq. (17): weights from slopes of cubic fits to the branches
# --------------------------------------------------------------------------------------
def _turning_points(v: NDArray, fraction: float = 0.1) -> list[int]:
    """Indices of the input's reversals, ignoring wiggles smaller than ``fraction`` of its range."""
    tol = fraction * float(np.ptp(v))
    turns = [0]
    extreme, direction = 0, 0
    for i in range(1, v.size):
        if direction >= 0 and v[i] >= v[extreme] or direction <= 0 and v[i] <= v[extreme]:
            if direction == 0 and abs(v[i] - v[0]) > tol:
                direction = 1 if v[i] > v[0] else -1
            extreme = i if direction else extreme
        elif abs(v[i] - v[extreme]) > tol:
            turns.append(extreme)
            direction, extreme = -direction, i
    turns.append(extreme)
    return turns


def _last_branch(v: NDArray, rising: bool) -> slice:
    """The last complete monotone branch, reversal to reversal, of ``v``."""
    turns = _turning_points(v)
    branches = [
        slice(a, b + 1) for a, b in zip(turns[1:-2], turns[2:-1]) if (v[b] > v[a]) == rising
    ]
    if not branches:
        raise IdentificationError(
            f"no complete {'ascending' if rising else 'descending'} branch (reversal to reversal) "
            "in the training window for the paper's branch-slope method"
        )
    return branches[-1]


def paper_branch_weights(
    v: ArrayLike, y: ArrayLike, thresholds: ArrayLike, rising: bool
) -> NDArray[np.float64]:
    """Weights from the slopes of a cubic fitted to one branch: eq. (17) of the paper.

    On a branch that starts at a reversal, operator ``k`` starts to move when the input has
    travelled ``2 r_k``, so the branch's slope between ``2 r_k`` and ``2 r_{k+1}`` is
    ``w_1 + ... + w_k``. The paper fits cubic polynomials to the (normalised) ascending and
    descending branches and reads the slopes off them; operators whose ``2 r_k`` lies beyond
    the branch never move on it and get weight 0.
    """
    v = np.asarray(v, float)
    y = np.asarray(y, float)
    r = np.asarray(thresholds, float)
    br = _last_branch(v, rising)
    sign = 1.0 if rising else -1.0
    s = sign * (v[br] - v[br][0])
    o = sign * (y[br] - y[br][0])
    poly = np.polynomial.Polynomial.fit(s, o, 3)  # normalises the domain itself
    length = float(np.max(s))
    edges = np.minimum(np.append(2 * r, np.inf), length)
    lo, hi = edges[:-1], edges[1:]
    slopes = np.where(hi > lo, (poly(hi) - poly(lo)) / np.where(hi > lo, hi - lo, 1.0), np.nan)
    # operators that never move on this branch: the partial sum stays where it was
    for k in range(1, slopes.size):
        if np.isnan(slopes[k]):
            slopes[k] = slopes[k - 1]
    return np.diff(slopes, prepend=0.0)


def paper_baseline(
    v: ArrayLike, y: ArrayLike, thresholds: ArrayLike, train: ArrayLike | slice | None = None
) -> AsymmetricPI:
    """The paper's identification (eqs. (17)-(18)): branch-slope weights, offset by least squares."""
    v = np.asarray(v, float)
    y = np.asarray(y, float)
    rows = _mask(v.size, train)
    r = np.asarray(thresholds, float)
    w_rise = paper_branch_weights(v[rows], y[rows], r, rising=True)
    w_fall = paper_branch_weights(v[rows], y[rows], r, rising=False)
    model = AsymmetricPI(r, w_rise, w_fall, 0.0)
    offset = float(np.mean(y[rows] - model(v)[rows]))
    return AsymmetricPI(r, w_rise, w_fall, offset)
