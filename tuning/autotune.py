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

Which loop the bounds hold on (``loop``): ``"continuous"`` (the default for a continuous plant) is the
continuous controller on the plant, the reading a continuous-time peer uses; ``"sampled"`` is the loop
as it runs at the sample period ``Ts``: the plant behind a zero-order hold (its delay split into whole
samples and a fraction, exactly) and the controller step at ``Ts`` (a discrete plant's loop is always
this one). The two give different gains; the result, its repr and its gain set say which was tuned.

What the gains may do (deployable gains):

* with a sample period ``Ts`` the derivative filter's time constant is at least ``Ts``
  (:data:`TF_FLOOR_PER_TS` samples): the controller step's backward-Euler filter then has its pole
  at ``z >= 1/2`` and acts as the continuous filter it stands for; a faster one does not filter;
* where the user sets no ``Mks`` but gives the actuator's range ``u_min..u_max``, ``|KS|`` is bounded
  by the range's span per measured unit (:func:`default_mks`: one measured unit of noise may not
  move the command across more than its whole range);
* a result that sits on a bound the user did not set (the default ``Mks``; the filter's floor or the
  search's range with no ``Mks`` set; a gain at the search's end) says so (``leans_on``) and its gain
  set is a ``candidate``, not ``validated``, until the user sets that bound.

The method (:mod:`piezopreload.tuning.autosearch`): the frequency grid from the plant (its poles,
zeros, delay and resonances), analytic starts from the stabilising set of the ``(kp, ki)`` plane
cut by the bounds (:mod:`piezopreload.tuning.stabset`, the D-decomposition), a local SQP with exact
derivatives (:mod:`piezopreload.tuning.pidopt`) from the best of them, and a refinement on a grid ten
times denser until every bound holds within 0.5 %. A bound no controller of the form meets raises an
:class:`~piezopreload.core.errors.InfeasibleError` naming it and the least value reached (in closed
form where there is one: ``Mt >= 1`` and ``Mks >= 1/|G(0)|`` with integral action).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from piezopreload.artifacts.tuning import ActiveBound
from piezopreload.core.errors import InfeasibleError, InputError
from piezopreload.tuning.autosearch import TOLERANCE, Found, Search, bound_reach, design_grid
from piezopreload.tuning.autotune_result import LOOPS, AutotuneResult, achieved, margins_of
from piezopreload.tuning.loadstep import iae_function, load_response
from piezopreload.tuning.loopshape import Bound
from piezopreload.tuning.lti import LinearPlant, as_plant, nyquist_unstable
from piezopreload.tuning.pidform import PIDController
from piezopreload.tuning.pidopt import METHODS, TF_RANGE, X_MAX, Form, LoadStepIAE, Metric, Scales
from piezopreload.tuning.plantfit import FittedPlant

__all__ = ["autotune", "default_mks", "METRICS", "FORMS", "SOLVERS", "LOOPS", "TOLERANCE", "TF_FLOOR_PER_TS"]

METRICS = tuple(Metric)
#: the SQP (default), IPOPT (both exact derivatives); scipy's SLSQP with exact first derivatives, or with finite
#: differences
SOLVERS = METHODS
FORMS = tuple(Form)
#: the derivative filter's least time constant, in sample periods
TF_FLOOR_PER_TS = 1.0


@dataclass(frozen=True)
class _Spec:
    """The problem as asked: the bounds it holds (the user's and the defaults), the user's own, the defaults' record,
    metric, form, filter order, the loop, the sample period, the IAE's horizon, the solver, the actuator's range and
    the filter's floor."""

    bounds: dict[str, float | None]
    user_bounds: dict[str, float | None]
    defaults: dict[str, dict[str, Any]]
    metric: Metric
    form: Form
    filter_order: int
    loop: str
    Ts: float | None
    horizon_s: float | None
    solver: str
    u_range: tuple[float, float] | None
    Tf_min: float

    @property
    def dt(self) -> float | None:
        """The designed controller's period: ``Ts`` on the sampled loop, None (continuous) on the continuous one."""
        return self.Ts if self.loop == "sampled" else None


def _positive(name: str, value: Any, minimum: float = 0.0) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or value <= minimum:
        raise InputError(f"{name} must be a finite number > {minimum:g}, got {value!r}")
    return float(value)


def _finite(name: str, value: Any) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise InputError(f"{name} must be a finite number, got {value!r}")
    return float(value)


def default_mks(u_min: float, u_max: float) -> tuple[float, str]:
    """The ``|KS|`` bound the tuner sets where the user sets none: the actuator's span per measured unit, and why."""
    span = u_max - u_min
    return span, (f"set from the actuator's range {u_min:g}..{u_max:g}: one measured unit of noise may move the "
                  f"command across at most its span ({span:g}); give Mks for your measurement's noise")


def _form_spec(metric: str, form: str, filter_order: Any, solver: str) -> int:
    if metric not in METRICS:
        raise InputError(f"metric must be one of {', '.join(METRICS)}, got {metric!r}")
    if form not in FORMS:
        raise InputError(f"form must be one of {', '.join(FORMS)}, got {form!r}")
    order = (0 if form == "PI" else 1) if filter_order is None else filter_order
    if order not in (0, 1, 2) or (form == "PI") != (order == 0):
        raise InputError("filter_order must be 1 or 2 for a PID (0 is the PI's), "
                         f"got {filter_order!r} with form {form!r}")
    if metric == "IAE" and order == 2:
        raise InputError("metric='IAE' simulates the load step with the first-order filter on the derivative only; "
                         "use filter_order=1")
    if solver not in SOLVERS:
        raise InputError(f"solver must be one of {', '.join(SOLVERS)}, got {solver!r}")
    return int(order)


def _loop_spec(loop: Any, Ts: float | None, plant: LinearPlant) -> tuple[str, float | None]:
    """The loop and the sample period, checked against the plant: a discrete plant's loop is the sampled one at its
    own period."""
    if loop is not None and loop not in LOOPS:
        raise InputError(f"loop must be one of {', '.join(LOOPS)}, got {loop!r}")
    if plant.discrete:
        if Ts is not None and abs(Ts - plant.sample_period()) > 1e-9 * plant.sample_period():
            raise InputError(f"Ts {Ts:g} s is not the discrete plant's sample period {plant.dt:g} s")
        if loop == "continuous":
            raise InputError(f"the plant is discrete (sample period {plant.dt:g} s): its loop is the sampled one; "
                             "give loop='sampled' or a continuous plant")
        return "sampled", plant.dt
    if loop == "sampled" and Ts is None:
        raise InputError("loop='sampled' holds the bounds on the loop as it runs at a sample period: give Ts")
    return loop or "continuous", Ts


def _spec(P: LinearPlant, Ms: Any, Mt: Any, Mks: Any, metric: str, form: str, Ts: Any, loop: Any, horizon_s: Any,
          filter_order: Any, solver: str, u_min: Any, u_max: Any) -> _Spec:
    user: dict[str, float | None] = {Bound.MS: _positive("Ms", Ms, 1.0), Bound.MT: _positive("Mt", Mt, 0.0),
                                     Bound.MKS: _positive("Mks", Mks, 0.0)}
    if user[Bound.MS] is None:
        raise InputError("Ms is required: the largest |S| the loop may have (1.2 to 2; 1.4 is a common choice)")
    order = _form_spec(metric, form, filter_order, solver)
    loop, dt = _loop_spec(loop, _positive("Ts", Ts), P)
    lo, hi = _finite("u_min", u_min), _finite("u_max", u_max)
    if (lo is None) != (hi is None) or (lo is not None and hi is not None and not lo < hi):
        raise InputError(f"the actuator's range needs u_min < u_max, both given; got u_min {u_min!r}, u_max {u_max!r}")
    u_range = None if lo is None or hi is None else (lo, hi)
    bounds, defaults = dict(user), dict[str, dict[str, Any]]()
    if user[Bound.MKS] is None and u_range is not None:
        bounds[Bound.MKS], reason = default_mks(*u_range)
        defaults[Bound.MKS] = {"value": bounds[Bound.MKS], "reason": reason}
    Tf_min = TF_FLOOR_PER_TS * dt if dt is not None and order > 0 else 0.0
    if Tf_min > 0:
        defaults["Tf_min_s"] = {"value": Tf_min, "reason": f"the derivative filter's floor at Ts {dt:g} s: a faster "
                                "filter does not filter in the controller step (its pole below z = 1/2)"}
    return _Spec(bounds, user, defaults, Metric(metric), Form(form), order, loop, dt, _positive("horizon_s", horizon_s),
                 solver, u_range, Tf_min)


def _closed_form_limits(P: LinearPlant, spec: _Spec) -> None:
    """The bounds no controller with integral action meets, in closed form: ``T(0) = 1``, so ``|T| >= 1``; and
    ``KS(0) = 1/G(0)``, so ``|KS| >= 1/|G(0)|`` for a plant without integrators (its static gain, which a zero-order
    hold keeps)."""
    mt = spec.bounds[Bound.MT]
    if mt is not None and mt < 1.0:
        raise InfeasibleError(f"Mt <= {mt:g} cannot be met with a {spec.form}: with integral action "
                              "T = 1 at zero frequency, so the least largest |T| any such controller reaches is 1 "
                              "(give Mt >= 1)")
    mks = spec.bounds[Bound.MKS]
    if mks is None or P.integrators > 0 or P.unstable_poles:
        return
    g0 = _dc_gain(P) if P.rational else float(np.abs(P.measured_response()[1][0]))
    least = 1.0 / g0 if g0 > 0 else np.inf
    if mks < least * (1.0 - 1e-9):
        who = "the default bound " if Bound.MKS in spec.defaults else ""
        raise InfeasibleError(f"Mks <= {mks:g} ({who}|KS|) cannot be met with a {spec.form}: with integral action "
                              f"KS = 1/G(0) at zero frequency, so the least largest |KS| any such controller reaches "
                              f"is at least 1/|G(0)| = {least:.4g} (give Mks >= {least:.4g})")


def _dc_gain(P: LinearPlant) -> float:
    num, den = np.asarray(P.num, float), np.asarray(P.den, float)
    at = 1.0 if P.discrete else 0.0
    d = np.polyval(den, at)
    return float(np.abs(np.polyval(num, at) / d)) if d != 0 else np.inf


def _grid(w: Any, plant: LinearPlant, bounds: dict[str, float | None]) -> np.ndarray:
    if w is None:
        return design_grid(plant, upto=bound_reach(plant, bounds))
    w = np.asarray(w, float).ravel()
    if w.size < 8 or not (np.all(np.isfinite(w)) and np.all(w > 0) and np.all(np.diff(w) > 0)):
        raise InputError("w must hold at least 8 finite, positive, strictly increasing frequencies (rad/s)")
    if plant.dt is not None and w[-1] >= np.pi / plant.dt:
        raise InputError(f"w reaches {w[-1]:g} rad/s, at or beyond the Nyquist frequency {np.pi / plant.dt:g} rad/s "
                         f"of the sample period {plant.dt:g} s")
    return w


# --------------------------------------------------------------------------------------
# the entry point
# --------------------------------------------------------------------------------------
def autotune(plant: Any, *, Ms: float, Mt: float | None = None, Mks: float | None = None, metric: str = "IE",
             form: str = "PID", Ts: float | None = None, loop: str | None = None, u_min: float | None = None,
             u_max: float | None = None, horizon_s: float | None = None, delay_s: float = 0.0, w: Any = None,
             filter_order: int | str | None = None, solver: str = "sqp") -> AutotuneResult:
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
        The sample period the controller runs at: the sampled loop's (``loop="sampled"``), the derivative filter's
        floor, the gain set's period, the IAE's. A discrete plant's period by default.
    loop : {"continuous", "sampled"}, optional
        Which loop the bounds hold on (see the module docstring): ``"continuous"`` by default for a continuous
        plant; ``"sampled"`` (needs ``Ts``) for the loop as it runs; a discrete plant's is ``"sampled"``.
    u_min, u_max : float, optional
        The actuator's range (the controller's output): the default ``Mks`` where none is given, and the gain
        set's output range.
    horizon_s : float, optional
        The IAE's simulation horizon.
    delay_s : float
        An input delay (s), exact in the frequency response.
    w : array_like, optional
        The design grid (rad/s) instead of the plant's.
    filter_order : {1, 2, "auto"}, optional
        A PID's filter: first order on the derivative (1, the default) or second order on the whole controller (2);
        ``"auto"``: both tuned, the one of larger integral gain kept (the second order gains where the plant's
        resonance lies above the crossover: a two-inertia plant measured on its load). Either exports: the second
        order as the controller step's second-order filter on the measurement (Tustin's rule, the map its sampled
        loop is tuned and checked with).
    solver : {"sqp", "ipopt", "slsqp", "slsqp-fd"}
        The local solver: the SQP (exact derivatives, DAQP for its QPs), IPOPT (exact derivatives), scipy's SLSQP
        with the same exact first derivatives, or with finite differences (for comparison).

    Returns
    -------
    AutotuneResult

    Raises
    ------
    InputError
        A malformed plant or argument.
    InfeasibleError
        No gains meet the bounds: the message names the bound and the least value reached.
    """
    if filter_order == "auto":
        if form != "PID" or metric != "IE":
            raise InputError("filter_order='auto' compares a PID's two filters by their integral gain: give "
                             f"form='PID' and metric='IE' (got form {form!r}, metric {metric!r})")
        kw = dict(Ms=Ms, Mt=Mt, Mks=Mks, metric=metric, form=form, Ts=Ts, loop=loop, u_min=u_min, u_max=u_max,
                  horizon_s=horizon_s, delay_s=delay_s, w=w, solver=solver)
        tuned = []
        for order in (1, 2):
            try:
                tuned.append(autotune(plant, filter_order=order, **kw))
            except InfeasibleError as exc:
                last = exc
        if not tuned:
            raise last
        return max(tuned, key=lambda r: r.ki)
    t0 = time.perf_counter()
    if isinstance(plant, FittedPlant):
        plant, delay_s = plant.transfer_function(), plant.delay_s + float(delay_s)
    P = as_plant(plant, delay_s)
    spec = _spec(P, Ms, Mt, Mks, metric, form, Ts, loop, horizon_s, filter_order, solver, u_min, u_max)
    if spec.metric is Metric.IAE and not P.rational:
        raise InputError("metric='IAE' simulates the load step on a time-domain model; a measured frequency response "
                         "has none: fit one to a step response (fit_plant) or give a transfer function")
    _closed_form_limits(P, spec)
    design = P if spec.loop == "continuous" or P.discrete or spec.Ts is None else P.sampled(spec.Ts)
    search = Search(design, _grid(w, design, spec.bounds), spec.bounds, spec.filter_order, spec.dt, spec.Tf_min,
                    spec.solver, w)
    found = search.run()
    iae = None
    if spec.metric is Metric.IAE:
        found, iae = _iae(P, design, search, found, spec)
    return _result(P, design, search, found, spec, iae, t0)


def _iae(P: LinearPlant, design: LinearPlant, search: Search, found: Found, spec: _Spec) -> tuple[Found, Any]:
    """The IAE's search: from the IE optimum, on its refined grid, the load step simulated at ``Ts``."""
    ie = found.controller
    sim, n = _iae_setup(P, design, ie.scaled(found.sign), spec)
    fn = iae_function(sim, n, found.sign)
    scale = float(fn(np.array([ie.kp, ie.ki, ie.kd, ie.Tf])))
    iae_found = search.run(LoadStepIAE(fn, scale), seeds=[("IE optimum", ie)], sign=found.sign)
    iae_found.records = found.records + iae_found.records
    best = iae_found.controller
    return iae_found, (float(fn(np.array([best.kp, best.ki, best.kd, best.Tf]))), sim.dt, n)


def _iae_setup(plant: LinearPlant, design: LinearPlant, ctrl: PIDController, spec: _Spec) -> tuple[LinearPlant, int]:
    """The plant the load step is simulated on and the samples: ``Ts`` (the given one, or a fiftieth of the IE
    optimum's crossover period; a loop without one: of the plant's middle frequency's) over ``horizon_s`` (default:
    eight times the longer of that period and ``Ti``)."""
    mg = margins_of(design, ctrl)
    wc = mg.crossover_rad_per_s or float(np.exp(np.mean(np.log(design.characteristic_frequencies()))))
    horizon = spec.horizon_s or 8.0 * max(2 * np.pi / wc, abs(ctrl.kp / ctrl.ki))
    Ts = spec.Ts or min(2 * np.pi / wc / 50.0, horizon / 500.0)
    n = int(np.ceil(horizon / Ts))
    if n > 20000:
        raise InputError(f"horizon_s {horizon:g} s at Ts {Ts:g} s is {n} samples; at most 20,000 (shorten the horizon "
                         "or give a longer Ts)")
    sim = design if design.discrete else plant.sampled(Ts)
    return sim, n


# --------------------------------------------------------------------------------------
# the result
# --------------------------------------------------------------------------------------
def _active_bounds(x: np.ndarray, scales: Scales) -> tuple[ActiveBound, ...]:
    out = []
    lo, hi = scales.box()
    gains = ("kp", "ki", "kd", "Tf")
    for i in range(scales.n):
        value = scales.gains(np.asarray(x, float))[i]
        if i == 2 and x[2] <= 1e-9:
            out.append(ActiveBound("kd", "lower", 0.0, "no derivative action: the controller is a PI"))
        elif i == 3 and x[3] <= lo[3] + 1e-6:
            floor = scales.tf_floor_binds
            out.append(ActiveBound("Tf", "lower", float(scales.Tf * np.exp(lo[3])),
                                   "the filter at the floor the sample period sets" if floor else
                                   "the filter is as fast as the search allows: bound |KS| (Mks) to set it"))
        elif i == 3 and x[3] >= hi[3] - 1e-6:
            out.append(ActiveBound("Tf", "upper", float(scales.Tf * TF_RANGE[1]), "the filter is as slow as allowed"))
        elif i < 3 and x[i] >= X_MAX * (1 - 1e-6):
            out.append(ActiveBound(gains[i], "upper", float(value), "the optimum may lie beyond the search range"))
        elif i == 0 and x[0] <= lo[0] * (1 + 1e-3):
            out.append(ActiveBound("kp", "lower", float(value),
                                   "almost no proportional action: an integral controller"))
    return tuple(out)


def _leans_on(spec: _Spec, peaks: dict[str, tuple[float, float]], active: tuple[ActiveBound, ...]) -> tuple[str, ...]:
    """The bounds the user did not set that the result sits on, in sentences."""
    out = []
    mks = spec.bounds[Bound.MKS]
    if Bound.MKS in spec.defaults and mks is not None and peaks[Bound.MKS][0] >= mks * (1.0 - 1e-3):
        out.append(f"|KS| reaches the default Mks {spec.bounds['Mks']:g} ({spec.defaults['Mks']['reason']})")
    for b in active:
        if b.gain == "Tf" and b.side == "lower" and spec.user_bounds[Bound.MKS] is None:
            out.append(f"the filter sits at its least time constant {b.bound:.4g} s ({b.note}) and no Mks of yours "
                       "bounds the noise gain: give Mks")
        elif b.side == "upper" and b.gain != "Tf":
            out.append(f"{b.gain} is at the end of the search range ({b.bound:.4g}): the bounds set do not limit it; "
                       "give Mks or tighter bounds")
    return tuple(out)


def _result(P: LinearPlant, design: LinearPlant, search: Search, found: Found, spec: _Spec, iae: Any,
            t0: float) -> AutotuneResult:
    scales = found.problem.scales
    x = found.solution.x
    ctrl = found.controller
    active = _active_bounds(x, scales)
    if any(b.gain == "kd" and b.side == "lower" for b in active):  # a derivative on its lower bound: a PI
        ctrl = PIDController(ctrl.kp, ctrl.ki, 0.0, 0.0, ctrl.filter_order, ctrl.dt)
    final = ctrl.scaled(found.sign)
    peaks = achieved(design, final, search.check, search.G_check)
    resolved = design.resolved_loop(lambda w: final.response(w))
    margins = margins_of(design, final, peaks, resolved)
    stable = _stable(design, final, resolved)
    load = None
    if P.rational:
        def load() -> tuple[np.ndarray, np.ndarray] | None:
            return _load_response(P, design, ctrl, found.sign, iae, margins)
    return AutotuneResult(
        controller_=final, plant=P, design_plant=design, form=spec.form, metric=spec.metric,
        bounds=dict(spec.bounds), margins=margins, peaks=peaks, stable=stable, iae=None if iae is None else iae[0],
        iae_Ts=None if iae is None else iae[1], starts=tuple(found.records), active_bounds=active,
        grid_points=int(search.omega.size), check_points=int(search.check.size),
        refinements=found.refinements, iterations=found.iterations, seconds=time.perf_counter() - t0,
        solver=spec.solver, loop=spec.loop, sample_period_s=spec.Ts, user_bounds=dict(spec.user_bounds),
        defaults={k: dict(v) for k, v in spec.defaults.items()}, leans_on=_leans_on(spec, peaks, active),
        u_range=spec.u_range, load_step=load)


def _stable(design: LinearPlant, c: PIDController, resolved: tuple[np.ndarray, np.ndarray]) -> bool:
    """The loop's stability: from its poles where it is rational without a delay, else by the Nyquist criterion on
    the resolved loop (the one the margins come from)."""
    if design.rational and design.delay_s == 0.0:
        return design.closed_loop_stable(c)
    omega, loop = resolved
    return nyquist_unstable(omega, loop, design.unstable_poles, design.integrators + c.integrators, design.dt) == 0


def _load_response(P: LinearPlant, design: LinearPlant, ctrl: PIDController, sign: float, iae: Any,
                   margins: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """The load step's response for the plot: on the IAE's simulation, or sampled at a fiftieth of the crossover
    period over five times the longer of that period and Ti (None where the plant has no time-domain model)."""
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

