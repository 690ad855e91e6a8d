"""Tune a PID for any linear plant under bounds on |S|, |T| and |KS|: the autotuner.

:func:`autotune` takes the user's loop as python-control gives it (a transfer function or state
space, continuous or discrete, stable, integrating or unstable, with an exact input delay; or a
measured frequency response; or a step response fitted by :func:`~piezopreload.tuning.plantfit.fit_plant`)
and tunes a PI, or a PID with its filter (:mod:`piezopreload.tuning.pidform`), for the largest
integral gain (``metric="IE"``: a unit load step at the plant input integrates to an error of
``1/ki``) or the least IAE of that load step (``metric="IAE"``, simulated as the controller step
runs it, :mod:`piezopreload.tuning.loadstep`), subject to ``|S| <= Ms``, ``|T| <= Mt`` and
``|KS| <= Mks`` (the constraints of :mod:`piezopreload.tuning.loopshape`, the rig tuner's too) and
a stable closed loop. After Hast, Åström, Bernhardsson and Boyd (2013), "PID design by convex-concave
optimization", and Garpinger, Hägglund and Åström (2012); the MIGO designs (Åström, Panagopoulos and
Hägglund 1998) are its PI special case.

The method:

1. the frequency grid is chosen from the plant (a hundredth of its lowest characteristic frequency
   to a hundred times its highest, 25 points a decade, and a point three decades on, where the
   controller's gain has levelled off) or given (``w``);
2. the starts: AMIGO and SIMC on a FOPDT reading of the plant, and the best stabilising gains of a
   coarse search (:mod:`piezopreload.tuning.starts`); each is solved with IPOPT, exact first and
   second derivatives from CasADi (:mod:`piezopreload.tuning.pidopt`); the closed loop of each is
   checked for stability (its poles, or the Nyquist criterion with a delay or measured data);
3. from the best stable feasible solution (a warm start), the bounds are checked on a grid ten
   times denser and a decade wider each side, their peaks located by a scalar search; where a
   bound is exceeded by more than 0.5 % the peaks join the grid and the problem is solved again,
   until every bound holds within 0.5 %;
4. if no start ends feasible, the least reachable worst bound is found and an
   :class:`~piezopreload.core.errors.InfeasibleError` names the bound and by how much.

With ``Ts`` (or a discrete plant) the controller is discrete: the plant is its zero-order-hold
equivalent at ``Ts`` and the controller the controller step at ``Ts``, so the constraints hold for
the loop as it will run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, NoReturn

import numpy as np

from piezopreload.artifacts.tuning import ActiveBound
from piezopreload.core.errors import InfeasibleError, InputError, InternalError
from piezopreload.tuning.autotune_result import AutotuneResult, StartRecord, achieved, margins_of, sensitivity_peaks
from piezopreload.tuning.loadstep import iae_function, load_response
from piezopreload.tuning.lti import LinearPlant, as_plant
from piezopreload.tuning.pidform import PIDController
from piezopreload.tuning.pidopt import TF_RANGE, X_MAX, PIDProblem, Scales, Solution
from piezopreload.tuning.plantfit import FittedPlant
from piezopreload.tuning.starts import fotd_of, reference_frequency, rule_starts, search_starts

__all__ = ["autotune", "METRICS", "FORMS", "SOLVERS", "TOLERANCE"]

METRICS = ("IE", "IAE")
#: IPOPT (exact derivatives); scipy's SLSQP with the same exact first derivatives, or with finite differences
SOLVERS = ("ipopt", "slsqp", "slsqp-fd")
FORMS = ("PI", "PID")
#: how far (relative) a bound may be exceeded on the dense grid
TOLERANCE = 0.005
#: how far the refinement goes (the grid gains the dense grid's peaks until they are within this)
_REFINE_TO = 1e-4
_REFINEMENTS = 8
_LOCAL_OPTIMA = 3  # the distinct local optima refined
_PER_DECADE = 25
_FEASIBLE = 1e-6  # |X| / M - 1 on the design grid


@dataclass(frozen=True)
class _Spec:
    bounds: dict[str, float | None]
    metric: str
    form: str
    filter_order: int
    dt: float | None
    Ts_sim: float | None
    horizon_s: float | None
    solver: str


def _positive(name: str, value: Any, minimum: float = 0.0) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or value <= minimum:
        raise InputError(f"{name} must be a finite number > {minimum:g}, got {value!r}")
    return float(value)


def _spec(Ms: Any, Mt: Any, Mks: Any, metric: str, form: str, Ts: Any, horizon_s: Any, filter_order: Any,
          solver: str) -> _Spec:
    bounds = {"Ms": _positive("Ms", Ms, 1.0), "Mt": _positive("Mt", Mt, 0.0), "Mks": _positive("Mks", Mks, 0.0)}
    if bounds["Ms"] is None:
        raise InputError("Ms is required: the largest |S| the loop may have (1.2 to 2; 1.4 is a common choice)")
    if metric not in METRICS:
        raise InputError(f"metric must be one of {', '.join(METRICS)}, got {metric!r}")
    if form not in FORMS:
        raise InputError(f"form must be one of {', '.join(FORMS)}, got {form!r}")
    order = (0 if form == "PI" else 1) if filter_order is None else filter_order
    if order not in (0, 1, 2) or (form == "PI") != (order == 0):
        raise InputError("filter_order must be 1 or 2 for a PID (0 is the PI's), "
                         f"got {filter_order!r} with form {form!r}")
    if metric == "IAE" and order == 2:
        raise InputError("metric='IAE' simulates the load step as the controller step runs it (a first-order filter "
                         "on the derivative); use filter_order=1")
    if solver not in SOLVERS:
        raise InputError(f"solver must be one of {', '.join(SOLVERS)}, got {solver!r}")
    dt = _positive("Ts", Ts)
    return _Spec(bounds, metric, form, order, dt, dt, _positive("horizon_s", horizon_s), solver)


def _far(plant: LinearPlant, omega: np.ndarray, decades: float, points: int) -> np.ndarray:
    """A continuous rational plant's grid continued ``decades`` beyond its end (``|KS|`` approaches its supremum
    ``|C(inf)|`` there); a discrete or measured plant's as it is."""
    if plant.discrete or not plant.rational:
        return omega
    return np.unique(np.append(omega, np.logspace(np.log10(omega[-1]), np.log10(omega[-1]) + decades, points)))


def _grid(w: Any, plant: LinearPlant) -> np.ndarray:
    if w is None:
        return _far(plant, plant.grid(_PER_DECADE), 3.0, 2)
    w = np.asarray(w, float).ravel()
    if w.size < 8 or not (np.all(np.isfinite(w)) and np.all(w > 0) and np.all(np.diff(w) > 0)):
        raise InputError("w must hold at least 8 finite, positive, strictly increasing frequencies (rad/s)")
    if plant.dt is not None and w[-1] >= np.pi / plant.dt:
        raise InputError(f"w reaches {w[-1]:g} rad/s, at or beyond the Nyquist frequency {np.pi / plant.dt:g} rad/s "
                         f"of the sample period {plant.dt:g} s")
    return w


def _check_grid(plant: LinearPlant, omega: np.ndarray) -> np.ndarray:
    """Ten times denser than the design grid and a decade wider each side, and three decades further where a
    continuous controller's gain levels off (a measured response: every frequency)."""
    if plant.omega_data is not None:  # a measured response
        return plant.omega_data
    dense = plant.grid(10 * _PER_DECADE, widen=1.0)
    lo, hi = np.log10(omega.min()) - 1.0, np.log10(omega.max()) + 1.0
    if plant.dt is not None:
        hi = min(hi, np.log10(0.999 * np.pi / plant.dt))
    extra = np.logspace(lo, hi, int(np.ceil((hi - lo) * 10 * _PER_DECADE)) + 1)
    return _far(plant, np.unique(np.concatenate([dense, extra, omega])), 3.0, 31)


# --------------------------------------------------------------------------------------
# the optimisation
# --------------------------------------------------------------------------------------
@dataclass
class _State:
    """What the search has: the problem on its grid, the best solution, the records of the starts."""

    problem: PIDProblem
    best: Solution | None
    records: list[StartRecord]
    solutions: list[Solution]
    candidates: list[Solution] = field(default_factory=list)
    refinements: int = 0
    iterations: int = 0

    @property
    def found(self) -> Solution:
        """The best solution, once the starts have found one (the search refuses the plant where they found none)."""
        if self.best is None:
            raise InternalError("the search has no solution yet")
        return self.best


def _problem(plant: LinearPlant, omega: np.ndarray, sign: float, spec: _Spec, scales: Scales,
             objective: Any, iae_scale: float) -> PIDProblem:
    return PIDProblem(omega, sign * plant.response(omega), spec.bounds, scales, objective, iae_scale)


def _solve_starts(state: _State, plant: LinearPlant, sign: float, spec: _Spec,
                  starts: list[tuple[str, PIDController]]) -> None:
    scales = state.problem.scales
    for name, c in starts:
        sol = state.problem.solve(scales.x(c), spec.solver)
        state.iterations += sol.iterations
        ctrl = scales.controller(sol.x)
        stable = plant.closed_loop_stable(ctrl.scaled(sign))
        state.solutions.append(sol)
        if sol.violation <= _FEASIBLE and stable:
            state.candidates.append(sol)
        state.records.append(StartRecord(name, *ctrl.scaled(sign).parallel(), objective=sol.objective,
                                         violation=sol.violation, stable=stable, status=sol.status,
                                         iterations=sol.iterations, seconds=sol.seconds))
        if sol.violation <= _FEASIBLE and stable and (state.best is None or sol.objective < state.found.objective):
            state.best = sol


def _local_solve(problem: PIDProblem, previous: Solution, solver: str) -> Solution:
    """The solution near ``previous`` (a refined grid moves the optimum a little), warm-started from it and its
    multipliers: in a trust region of a third of each scaled gain (and half a unit of the filter's log), moved with
    the solution while it ends on the region's edge."""
    iterations, sol, x0 = 0, previous, previous.x
    for _ in range(6):
        width = np.maximum(np.abs(x0) / 3.0, 0.05)
        if x0.size == 4:
            width[3] = 0.5
        sol = problem.solve(x0, solver, (x0 - width, x0 + width), warm=sol)
        iterations += sol.iterations
        lo, hi = problem.scales.box()
        tol = 1e-6 * width
        edge = ((np.abs(sol.x - (x0 - width)) < tol) & (x0 - width > lo + tol)) | \
            ((np.abs(sol.x - (x0 + width)) < tol) & (x0 + width < hi - tol))  # on the region's edge, not the box's
        if not np.any(edge) or sol.violation > _FEASIBLE:
            break
        x0 = sol.x
    return replace(sol, iterations=iterations)


def _refine(state: _State, plant: LinearPlant, sign: float, spec: _Spec, objective: Any, iae_scale: float) -> None:
    """From the best solution: check on the dense grid, add the peaks beyond the tolerance to the grid, solve again
    from the best (a warm start), until every bound holds within :data:`TOLERANCE`."""
    check = _check_grid(plant, state.problem.omega)
    bounded = {k: m for k, m in spec.bounds.items() if m is not None}
    for _ in range(_REFINEMENTS):
        ctrl = state.problem.scales.controller(state.found.x).scaled(sign)
        peaks = sensitivity_peaks(plant, ctrl, check, tuple(bounded),
                                  {k: m * (1.0 + _REFINE_TO) for k, m in bounded.items()})
        over = [w * f for k, found in peaks.items() for v, w in found if v / bounded[k] > 1.0 + _REFINE_TO
                for f in (0.995, 1.0, 1.005)]  # each peak and its neighbours: the peak moves as the gains do
        if not over:
            return
        # the peaks after the grid's frequencies (their slots, and so the warm start's multipliers, stay)
        omega = np.concatenate([state.problem.omega, np.setdiff1d(np.unique(over), state.problem.omega)])
        problem = _problem(plant, omega, sign, spec, state.problem.scales, objective, iae_scale)
        sol = _local_solve(problem, state.found, spec.solver)
        state.iterations += sol.iterations
        if sol.violation > _FEASIBLE or not plant.closed_loop_stable(problem.scales.controller(sol.x).scaled(sign)):
            break  # the refined problem did not solve: keep the last solution if it is within the tolerance
        state.problem, state.best, state.refinements = problem, sol, state.refinements + 1
    ctrl = state.problem.scales.controller(state.found.x).scaled(sign)
    peaks = sensitivity_peaks(plant, ctrl, check, tuple(bounded))
    worst = max(found[0][0] / bounded[k] for k, found in peaks.items())
    if worst > 1.0 + TOLERANCE:
        raise InternalError(f"after {state.refinements} refinements a bound is still {worst - 1:.2%} over its limit on "
                            "the dense grid; give a finer grid (w)")


def _infeasible(problem: PIDProblem, solutions: list[Solution], records: list[StartRecord], spec: _Spec) -> NoReturn:
    """Raise the :class:`InfeasibleError` that names the bound no gains meet and by how much."""
    least = problem.least_violation(min(solutions, key=lambda s: s.violation).x)
    worst = problem.worst_by_bound(least.x)
    if least.violation <= TOLERANCE:
        raise InfeasibleError("gains meeting every bound exist on the grid, but none that also stabilise the loop "
                              f"were found from {len(records)} starts; the closed loop the bounds allow is unstable")
    name, (ratio, w) = max(worst.items(), key=lambda kv: kv[1][0])
    what = {"Ms": "|S|", "Mt": "|T|", "Mks": "|KS|"}[name]
    bound = {k: m for k, m in spec.bounds.items() if m is not None}  # the bounds set: those worst_by_bound has
    others = "; ".join(f"{k} <= {bound[k]:g} at {v[0] * bound[k]:.4g}"
                       for k, v in worst.items() if k != name)
    raise InfeasibleError(f"{name} <= {bound[name]:g} cannot be met with a {spec.form} on this plant: the least "
                          f"largest {what} any gains reach is {ratio * bound[name]:.4g} "
                          f"(over by {ratio - 1:.1%}, at {w:.4g} rad/s)" + (f"; there, {others}" if others else "")
                          + ". Relax that bound, or tune the other form")


def _starts(design: LinearPlant, omega: np.ndarray, spec: _Spec) -> tuple[float, list[tuple[str, PIDController]]]:
    """The controller's sign and the starts for the plant of that sign: the low-frequency gain's sign; an unstable
    plant's is the one the coarse search finds stabilising gains for (its low-frequency gain may have the other)."""
    signs = [design.sign] + ([-design.sign] if design.unstable_poles else [])
    for sign in signs:
        G = sign * design.response(omega)
        starts = rule_starts(fotd_of(design, omega), spec.filter_order, spec.dt) if sign == design.sign else []
        starts += search_starts(design, omega, G, spec.bounds, spec.filter_order, spec.dt)
        if any(name.startswith("search") for name, _ in starts):
            return sign, starts
    raise InfeasibleError("no stabilising start was found for this plant (the coarse search over proportional and "
                          "integral gains found no stable loop of either sign); check the plant and its units")


def _scales(starts: list[tuple[str, PIDController]], plant: LinearPlant, omega: np.ndarray, spec: _Spec) -> Scales:
    """The gains' scales from the coarse search's best start (``ki``; ``kp`` no less than ``ki`` over the
    reference frequency, ``kd`` no less than ``kp`` over it) and the reference frequency (``Tf``): the search
    box spans three decades above each."""
    wr = reference_frequency(plant, omega)
    c = next((c for name, c in starts if name.startswith("search")), starts[0][1])  # the search's best: stabilising
    ki = max(abs(c.ki), 1e-12)
    kp = max(abs(c.kp), ki / wr)
    kd = max(abs(c.kd), kp / wr)
    return Scales(kp=kp, ki=ki, kd=kd, Tf=1.0 / wr, filter_order=spec.filter_order, dt=spec.dt)


def _search(plant: LinearPlant, omega: np.ndarray, sign: float, spec: _Spec, starts: list[tuple[str, PIDController]],
            scales: Scales, objective: Any = "IE", iae_scale: float = 1.0) -> _State:
    state = _State(_problem(plant, omega, sign, spec, scales, objective, iae_scale), None, [], [])
    _solve_starts(state, plant, sign, spec, starts)
    if state.best is None:
        _infeasible(state.problem, state.solutions, state.records, spec)
    # the problem is not convex: each distinct local optimum (the best few) is refined on its own, and the best
    # after refinement kept (a warm-started refinement may leave its basin for a worse one)
    distinct: list[Solution] = []
    for sol in sorted(state.candidates, key=lambda c: c.objective):
        if all(np.max(np.abs(sol.x - d.x) / (np.abs(d.x) + 1e-3)) > 1e-3 for d in distinct):
            distinct.append(sol)
    refined: list[_State] = []
    for sol in distinct[:_LOCAL_OPTIMA]:
        if refined and sol.objective >= min(b.found.objective for b in refined):
            break  # a refined grid only adds constraints: this one cannot end better than one already refined
        branch = replace(state, best=sol, refinements=0, iterations=0)
        try:
            _refine(branch, plant, sign, spec, objective, iae_scale)
        except InternalError:
            continue
        refined.append(branch)
        state.iterations += branch.iterations
    if not refined:
        raise InternalError("no local optimum met the bounds on the dense grid after refinement; give a finer grid (w)")
    best = min(refined, key=lambda b: b.found.objective)
    return replace(state, problem=best.problem, best=best.found, refinements=best.refinements)


# --------------------------------------------------------------------------------------
# the IAE
# --------------------------------------------------------------------------------------
def _iae_setup(plant: LinearPlant, design: LinearPlant, ctrl: PIDController, spec: _Spec) -> tuple[LinearPlant, int]:
    """The plant the load step is simulated on and the samples: ``Ts`` (the design's, or a fiftieth of the IE
    optimum's crossover period) over ``horizon_s`` (default: eight times the longer of that period and ``Ti``)."""
    mg = margins_of(design, ctrl)
    wc = mg.crossover_rad_per_s or reference_frequency(design, design.grid(_PER_DECADE))
    horizon = spec.horizon_s or 8.0 * max(2 * np.pi / wc, abs(ctrl.kp / ctrl.ki))
    Ts = spec.dt or min(2 * np.pi / wc / 50.0, horizon / 500.0)
    n = int(np.ceil(horizon / Ts))
    if n > 20000:
        raise InputError(f"horizon_s {horizon:g} s at Ts {Ts:g} s is {n} samples; at most 20,000 (shorten the horizon "
                         "or give a longer Ts)")
    sim = design if design.discrete else plant.sampled(Ts)
    return sim, n


# --------------------------------------------------------------------------------------
# the entry point
# --------------------------------------------------------------------------------------
def autotune(plant: Any, *, Ms: float, Mt: float | None = None, Mks: float | None = None, metric: str = "IE",
             form: str = "PID", Ts: float | None = None, horizon_s: float | None = None, delay_s: float = 0.0,
             w: Any = None, filter_order: int | None = None, solver: str = "ipopt") -> AutotuneResult:
    """Tune a PI or PID for ``plant`` under ``|S| <= Ms``, ``|T| <= Mt``, ``|KS| <= Mks``; see the module docstring.

    Parameters
    ----------
    plant : control.TransferFunction, control.StateSpace, control.FrequencyResponseData or FittedPlant
        The loop from the controller's output to its measurement (continuous or discrete).
    Ms, Mt, Mks : float
        The largest ``|S|`` (required, > 1), ``|T|`` and ``|KS|`` (optional; ``KS`` in the controller's output
        per measured unit) on the frequency axis.
    metric : {"IE", "IAE"}
        Maximise the integral gain, or minimise the IAE of a unit load step at the plant input.
    form : {"PI", "PID"}
        The controller; a PID has a filter whose time constant is tuned too (``filter_order`` 1, the default: on
        the derivative, the form the controller step runs; 2: second order on the whole controller).
    Ts : float, optional
        The controller's sample period: the loop is tuned as it runs (zero-order hold, the controller step at
        ``Ts``); also the IAE's. A discrete plant's period by default.
    horizon_s : float, optional
        The IAE's simulation horizon.
    delay_s : float
        An input delay (s), exact in the frequency response.
    w : array_like, optional
        The design grid (rad/s) instead of the plant's.
    solver : {"ipopt", "slsqp", "slsqp-fd"}
        IPOPT with exact derivatives; ``slsqp`` runs scipy's SLSQP on the same problem with the same exact first
        derivatives, ``slsqp-fd`` with finite differences (for comparison).

    Returns
    -------
    AutotuneResult

    Raises
    ------
    InputError
        A malformed plant or argument.
    InfeasibleError
        No gains meet the bounds: the message names the bound and by how much.
    """
    t0 = time.perf_counter()
    if isinstance(plant, FittedPlant):
        plant, delay_s = plant.transfer_function(), plant.delay_s + float(delay_s)
    P = as_plant(plant, delay_s)
    spec = _spec(Ms, Mt, Mks, metric, form, Ts, horizon_s, filter_order, solver)
    if P.dt is not None:
        if spec.dt is not None and abs(spec.dt - P.dt) > 1e-9 * P.dt:
            raise InputError(f"Ts {spec.dt:g} s is not the discrete plant's sample period {P.dt:g} s")
        spec = _Spec(spec.bounds, spec.metric, spec.form, spec.filter_order, P.dt, P.dt, spec.horizon_s, spec.solver)
    if spec.metric == "IAE" and not P.rational:
        raise InputError("metric='IAE' simulates the load step on a time-domain model; a measured frequency response "
                         "has none: fit one to a step response (fit_plant) or give a transfer function")
    design = P if spec.dt is None or P.discrete else P.sampled(spec.dt)
    omega = _grid(w, design)
    sign, starts = _starts(design, omega, spec)
    scales = _scales(starts, design, omega, spec)
    state = _search(design, omega, sign, spec, starts, scales)
    iae = None
    if spec.metric == "IAE":
        ie_ctrl = scales.controller(state.found.x)
        sim, n = _iae_setup(P, design, ie_ctrl.scaled(sign), spec)
        fn = iae_function(sim, n, sign)
        scale = float(fn(np.array([ie_ctrl.kp, ie_ctrl.ki, ie_ctrl.kd, ie_ctrl.Tf])))
        records = state.records
        iae_starts = [("IE optimum", ie_ctrl)] + [(n, c) for n, c in starts if n.startswith(("AMIGO", "SIMC"))]
        state = _search(design, state.problem.omega, sign, spec, iae_starts, scales, objective=fn, iae_scale=scale)
        state.records = records + state.records
        best = scales.controller(state.found.x)
        iae = (float(fn(np.array([best.kp, best.ki, best.kd, best.Tf]))), sim.dt, n)
    return _result(P, design, sign, spec, state, iae, time.perf_counter() - t0)


def _active_bounds(x: np.ndarray, scales: Scales) -> tuple[ActiveBound, ...]:
    out = []
    lo, hi = scales.box()
    gains = ("kp", "ki", "kd", "Tf")
    for i in range(scales.n):
        value = scales.gains(np.asarray(x, float))[i]
        if i == 2 and x[2] <= 1e-9:
            out.append(ActiveBound("kd", "lower", 0.0, "no derivative action: the controller is a PI"))
        elif i == 3 and x[3] <= lo[3] + 1e-6:
            out.append(ActiveBound("Tf", "lower", float(scales.Tf * TF_RANGE[0]),
                                   "the filter is as fast as the search allows: bound |KS| (Mks) to set it"))
        elif i == 3 and x[3] >= hi[3] - 1e-6:
            out.append(ActiveBound("Tf", "upper", float(scales.Tf * TF_RANGE[1]), "the filter is as slow as allowed"))
        elif i < 3 and x[i] >= X_MAX * (1 - 1e-6):
            out.append(ActiveBound(gains[i], "upper", float(value), "the optimum may lie beyond the search range"))
        elif i == 0 and x[0] <= lo[0] * (1 + 1e-3):
            out.append(ActiveBound("kp", "lower", float(value),
                                   "almost no proportional action: an integral controller"))
    return tuple(out)


def _result(P: LinearPlant, design: LinearPlant, sign: float, spec: _Spec, state: _State, iae: Any,
            seconds: float) -> AutotuneResult:
    scales = state.problem.scales
    ctrl = scales.controller(state.found.x)
    bounds = _active_bounds(state.found.x, scales)
    if any(b.gain == "kd" and b.side == "lower" for b in bounds):  # a derivative on its lower bound: a PI
        ctrl = PIDController(ctrl.kp, ctrl.ki, 0.0, 0.0, ctrl.filter_order, ctrl.dt)
    check = _check_grid(design, state.problem.omega)
    final = ctrl.scaled(sign)
    peaks = achieved(design, final, check)
    margins = margins_of(design, final, peaks)
    response = None
    if design.rational or P.rational:
        response = _load_response(P, design, ctrl, sign, spec, iae, margins)
    return AutotuneResult(
        controller_=final, plant=P, design_plant=design, form=spec.form, metric=spec.metric,
        bounds=dict(spec.bounds), margins=margins, peaks=peaks,
        stable=design.closed_loop_stable(final), iae=None if iae is None else iae[0],
        iae_Ts=None if iae is None else iae[1], starts=tuple(state.records), active_bounds=bounds,
        grid_points=int(state.problem.omega.size), check_points=int(check.size), refinements=state.refinements,
        iterations=state.iterations, seconds=seconds, solver=spec.solver, load_response=response)


def _load_response(P: LinearPlant, design: LinearPlant, ctrl: PIDController, sign: float, spec: _Spec, iae: Any,
                   margins: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """The load step's response for the plot: on the IAE's simulation, or sampled at a fiftieth of the crossover
    period over five times the longer of that period and Ti (None where the plant has no time-domain model)."""
    if not P.rational and not design.rational:
        return None
    wc = margins.crossover_rad_per_s or 1.0
    if design.dt is not None:
        sim, Ts = design, design.dt
    else:
        Ts = iae[1] if iae is not None else 2 * np.pi / wc / 50.0
        sim = P.sampled(Ts)
    n = int(min(np.ceil(5.0 * max(2 * np.pi / wc, abs(ctrl.kp / ctrl.ki)) / Ts), 20000))
    try:
        t, y = load_response(sim, PIDController(ctrl.kp, ctrl.ki, ctrl.kd, ctrl.Tf, ctrl.filter_order, sim.dt), n, sign)
    except InputError:  # a biproper plant without delay: no sampled response
        return None
    return t, y * sign
