"""Preview and iterative learning control (ILC) of the preload force over a known, repeated reference.

**Preview.** A planned reference is known ahead. With a preview horizon ``P`` (``p`` samples)
the controller may start a change before it is due. What it can gain is bounded by the
argument :func:`~piezopreload.tuning.pid.tracking_floor` makes for a causal controller: the
force moves at most ``rate`` per second (the amplifier's slew times the steepest slope of
force over voltage), and it cannot leave its level before the command that knows of the
change has come through the delay. Without preview that is ``delay`` samples after the jump;
with preview ``p - delay`` samples *before* it. Over each jump the best force is then a ramp at
full rate from the best admissible start (centred on the jump when the preview allows), held
inside the force the voltage range reaches (:func:`~piezopreload.models.actuator.reach_N`
at the upper limit, the bolt preload at 0 V). :func:`preview_plan` computes that ramp per jump
by searching the start (the same argument as the causal floor, computed exactly on the sample
grid, not a convex program); its RMS error is the **preview floor** (with ``p = 0`` it is the
causal floor, to rounding). The steepest slope holds only far along a branch; the rig's own
branch at full slew (:func:`branch_ramps`: just after a reversal it is flat) gives each change's
fastest path, a tighter floor for the nominal plant and the **plan** the controller follows:
the setpoint becomes the plan, and the feedforward reads the plan ahead by the delay and the
amplifier's lag (:func:`preview_feedforward`), as a previewed ``ff_extra``. With preview a
change starts before its jump, so the plan itself scores where a score "outside 0.1 s after
each jump" counts (``plan_rms_after_change_N`` in :meth:`LearningResult.to_dict`).

**Learning.** A machining cycle repeats, so the error of one cycle can correct the next.
The learned signal ``u`` enters the loop as ``ff_extra`` (added to the feedforward, before
the clamp); the system it drives is the closed loop from ``ff_extra`` to the force, whose
lifted (trial-domain) matrix ``G`` is the lower-triangular Toeplitz matrix of its impulse
response :attr:`LearningModel.g`, taken from the one loop step linearised at a hold
(:func:`learning_model`). Two laws (Bristow, Tharayil, Alleyne 2006, "A survey of iterative
learning control", IEEE Control Systems 26(3), for both):

* Q-filtered P-type with phase lead: ``u_{k+1} = Q (u_k + gamma F e_k(t + delta))``; ``Q`` a
  zero-phase low-pass (a Butterworth filter run forward and backward from rest), ``F`` a
  PI-shaped learning filter (the PID's integral rejects ``ff_extra`` at low frequency, where a
  setpoint passes), ``delta`` the peak of the response through ``F`` and ``gamma`` half the
  largest gain that keeps ``|1 - gamma e^{j w delta} G F|`` at most 1 (:func:`tune_laws`).
  In the lifted domain ``u_{k+1} - u_inf = Q (I - L G)(u_k - u_inf)``, so
  ``||Q (I - L G)|| < 1`` gives monotone convergence (:meth:`LearningModel.contraction`).
* Norm-optimal (Amann, Owens, Rogers 1996): ``du = argmin ||e_k - G du||^2 + w ||du||^2``
  subject to the command's range and the amplifier's slew, a QP (cvxpy + Clarabel); the
  command after the update is predicted as the last trial's plus ``du``.

The error is read on the *measured* force, as a rig would (and not learned where the command
sat at a limit); the reported errors are of the true force. A divergence guard stops a plant's learning when its error grows past the best by
``grow_tol`` and keeps the best iterate.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray
from scipy.signal import butter, lfilter

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.learned import LearnedSignal, reference_sha256
from piezopreload.core.artifacts import read_artifact, write_artifact
from piezopreload.core.errors import InputError, InternalError
from piezopreload.models.actuator import Rig, RigParams, reach_N
from piezopreload.models.closedloop import ClosedLoopRun, Reference, simulate
from piezopreload.models.controller import Controller
from piezopreload.models.loop import step_function
from piezopreload.models.ops import NUMPY
from piezopreload.tuning.pid import tracking_floor, tuning_loop
from piezopreload.tuning.validate import DEFAULT_SPREAD

__all__ = ["METHODS", "LearningModel", "learning_model", "learning_model_over", "causal_floor", "ramp_plan", "advance", "zero_phase_lowpass", "PreviewPlan",
           "preview_plan", "branch_ramps", "default_preview_s", "feedforward_lead", "tune_laws", "preview_feedforward", "p_type_update", "norm_optimal_update",
           "Iteration", "LearningResult", "learn", "played_passes", "schedule_learner", "learn_from_run", "learn_from_log",
           "save_passes", "learned_by_reference", "named_reference", "AFTER_CHANGE_S"]

Array = NDArray[np.float64]

METHODS = ("p-type", "norm-optimal")
#: the transport after a jump the after-change error leaves out (as the validation's criteria)
AFTER_CHANGE_S = 0.1
# the planned ramps' share of the slew: on the paper's rig and trajectory 0.85 tracks best (whole-trajectory
# RMS after 10 P-type iterations 0.741 N at 1.0, 0.706 at 0.95, 0.678 at 0.9, 0.657 at 0.85, 0.690 at 0.75)
PLAN_SLEW_FRACTION = 0.85


# --------------------------------------------------------------------------------------
# signals
# --------------------------------------------------------------------------------------
def advance(x: Array, samples: int, fill: str = "hold") -> Array:
    """``x`` read ``samples`` ahead along its last axis (``y[k] = x[k + samples]``); past the end the last
    value is held (``fill="hold"``, a plan's last level) or 0 (``"zero"``, the lifted shift of the laws)."""
    x = np.asarray(x, float)
    if samples < 0:
        raise InputError(f"advance: samples must be >= 0, got {samples}")
    if samples == 0:
        return x.copy()
    m = min(samples, x.shape[-1])
    tail = np.repeat(x[..., -1:], m, axis=-1) if fill == "hold" else np.zeros(x.shape[:-1] + (m,))
    return np.concatenate([x[..., samples:], tail], axis=-1)[..., : x.shape[-1]]


def zero_phase_lowpass(x: Array, cutoff_Hz: float, dt_s: float, order: int = 2) -> Array:
    """The zero-phase low-pass ``Q`` of the P-type law: a Butterworth filter run forward, then backward.

    Both passes start at rest, so in the lifted domain ``Q = H^T H`` (``H`` the filter's lower
    triangular Toeplitz matrix): symmetric, with ``||Q|| <= max |H|^2 = 1``, which the
    convergence argument needs. ``cutoff_Hz`` at or above Nyquist leaves ``x`` as it is.
    """
    nyquist = 0.5 / dt_s
    if cutoff_Hz >= nyquist:
        return np.asarray(x, float).copy()
    b, a = butter(order, cutoff_Hz / nyquist)
    forward = lfilter(b, a, np.asarray(x, float), axis=-1)
    return np.asarray(lfilter(b, a, forward[..., ::-1], axis=-1)[..., ::-1], float)


# --------------------------------------------------------------------------------------
# the learning model: the loop from ff_extra to the force, linearised
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class LearningModel:
    """The closed loop from ``ff_extra`` to the force, linear, and the learning laws' settings.

    ``A, B, C`` are its state space (``x+ = A x + B u``, force ``C x``: read before the command
    is written, so the first response is a sample late); ``g`` its impulse response (N/V).
    The P-type law learns through a PI-shaped filter ``F`` (``sp_gain`` and the trapezoidal
    integral ``sp_integral_per_s``, the PID's ``Kc / Ti``: at low frequency the loop passes ``F u``
    to the force as it passes a setpoint, where ``ff_extra`` alone is rejected by the integral);
    ``delta`` and ``gamma`` set its lead and gain, ``q_cutoff_Hz`` its filter. ``u_range_V`` and
    ``slew_V_per_sample`` bound the norm-optimal law's command, ``weight`` its penalty on the
    change of the signal.
    """

    A: Array
    B: Array
    C: Array
    dt_s: float
    delta: int = 1
    gamma: float = 1.0
    q_cutoff_Hz: float = np.inf
    u_range_V: tuple[float, float] = (-np.inf, np.inf)
    slew_V_per_sample: float = np.inf
    weight: float = 0.0
    sp_gain: float = 1.0
    sp_integral_per_s: float = 0.0
    length: int = 3000
    range_contraction: float | None = None
    range_V: tuple[float, float] | None = None

    @property
    def g(self) -> Array:
        """Impulse response of ``ff_extra`` to the force, ``length`` samples."""
        g = np.zeros(self.length)
        s = self.B[:, 0].astype(float)
        for j in range(1, self.length):
            g[j] = float((self.C @ s).ravel()[0])
            s = self.A @ s
        return g

    def setpoint_path(self, x: Array) -> Array:
        """``F x`` along the last axis: ``sp_gain x + sp_integral`` times the trapezoidal integral of ``x``."""
        x = np.asarray(x, float)
        if not self.sp_integral_per_s:
            return self.sp_gain * x
        area = np.cumsum(x, axis=-1) - 0.5 * x - 0.5 * x[..., :1]  # trapezoids from the first sample
        return self.sp_gain * x + self.sp_integral_per_s * self.dt_s * area

    def lifted(self, n: int, learning: bool = False) -> Array:
        """The lifted matrix ``G`` (``n x n``, lower triangular Toeplitz), dense, for small ``n``;
        ``learning=True`` gives ``L G``'s factor ``G F`` (the loop through the setpoint path)."""
        g = self.g
        col = np.zeros(n)
        m = min(n, g.size)
        col[:m] = g[:m]
        idx = np.arange(n)[:, None] - np.arange(n)[None, :]
        G = np.where(idx >= 0, col[np.clip(idx, 0, n - 1)], 0.0)
        return G @ self.setpoint_path(np.eye(n).T).T if learning else G

    def frequency_response(self, omega: Array, learning: bool = False) -> Array:
        """``G(e^{j w dt})`` (rad/s) from the state space; ``learning=True``: ``G F``."""
        z = np.exp(1j * np.asarray(omega, float) * self.dt_s)
        n = self.A.shape[0]
        resolvent = np.linalg.solve(z[:, None, None] * np.eye(n) - self.A, np.broadcast_to(self.B, (z.size,) + self.B.shape))
        out = (self.C @ resolvent)[:, 0, 0]
        if learning:
            zi = 1.0 / z
            with np.errstate(divide="ignore", invalid="ignore"):
                out = out * (self.sp_gain + self.sp_integral_per_s * self.dt_s * 0.5 * (1 + zi) / (1 - zi))
        return out

    def q_response(self, omega: Array, order: int = 2) -> Array:
        """``|Q|`` at ``omega``: the digital Butterworth's magnitude squared (it runs forward and back)."""
        f = np.asarray(omega, float) / (2 * np.pi)
        if self.q_cutoff_Hz >= 0.5 / self.dt_s:
            return np.ones_like(f)
        ratio = np.tan(np.pi * f * self.dt_s) / np.tan(np.pi * self.q_cutoff_Hz * self.dt_s)
        return 1.0 / (1.0 + ratio ** (2 * order))

    def contraction(self, n_freq: int = 2000, loop: LearningModel | None = None) -> float:
        """``sup_w |Q(w)| |1 - gamma e^{j w delta} G(w) F(w)|`` over ``0 < w <= pi/dt``: below 1 the P-type
        law converges monotonically (the lifted operator's 2-norm for long trials); 1 at DC, where the
        PID's integral holds the error at 0 by itself. ``loop``: this law (``Q``, ``gamma``, ``delta``,
        ``F``) on another loop's ``G`` (the same loop linearised elsewhere, say)."""
        omega = np.linspace(0.0, np.pi / self.dt_s, n_freq + 1)[1:]
        lead = np.exp(1j * omega * self.delta * self.dt_s)
        G = (self if loop is None else replace(self, A=loop.A, B=loop.B, C=loop.C)).frequency_response(omega, learning=True)
        return float(np.max(self.q_response(omega) * np.abs(1.0 - self.gamma * lead * G)))


def learning_model(params: RigParams, controller: Controller, *, v0_V: float = 50.0,
                   q_cutoff_Hz: float | None = None, weight: float | None = None) -> LearningModel:
    """The learning model of a controller on a rig: the one loop step linearised at a hold at ``v0_V``.

    The loop is :func:`~piezopreload.tuning.pid.tuning_loop` (the rig's step with its corners
    rounded, the PID; the inverse-P-I feedforward depends on the setpoint alone and drops out of
    the response to ``ff_extra``) with the controller's gains; CasADi gives the Jacobians of its
    step at rest: the state space. The laws' settings follow from it (:func:`tune_laws`).
    """
    if params.batch_shape:
        raise InputError("learning_model: give one plant (the nominal), not a batch")
    gains = controller.gains
    c = Controller(gains, controller.dt_s, None)
    loop = tuning_loop(params, schedule_size=c.model.schedule_size)  # the PID with its gain schedule, if any
    plant_p = loop.plant.parameters(params)
    p = loop.parameters(plant_p, c.parameter_vector())
    x_rest = loop.start(NUMPY, p, 0.0, 0.0, v0_V)
    f0 = float(np.asarray(loop.plant.force(NUMPY, plant_p, x_rest[: loop.plant.state.size])))
    x0 = loop.start(NUMPY, p, f0, 0.0, v0_V)
    step = step_function(loop)
    x, u = ca.SX.sym("x", loop.state.size), ca.SX.sym("u")
    x_next, y = step(x, p, f0, 0.0, u)
    jac = ca.Function("pp_learning_jacobians", [x, u], [ca.jacobian(x_next, x), ca.jacobian(x_next, u),
                                                         ca.jacobian(y[0], x)])
    A, B, C = (np.asarray(m, float) for m in jac(x0, 0.0))
    dt = params.sample_period_s
    ki = 0.0 if not np.isfinite(gains.Ti_s) else gains.Kc / gains.Ti_s
    base = LearningModel(A, B, C, dt, u_range_V=(gains.u_min, gains.u_max),
                         slew_V_per_sample=float(params.slew_V_per_s) * dt, sp_gain=gains.Kc * gains.b,
                         sp_integral_per_s=ki)
    return tune_laws(base, q_cutoff_Hz=q_cutoff_Hz, weight=weight)


def learning_model_over(params: RigParams, controller: Controller, voltages_V: Any = None, *, v0_V: float = 50.0,
                        q_cutoff_Hz: float | None = None, weight: float | None = None) -> LearningModel:
    """The learning model whose P-type law contracts on the loop linearised at every one of ``voltages_V``.

    On a plant whose force per volt changes with the level (the designed plant's Hertzian nuts
    stiffen with the preload) one linearisation does not hold everywhere. The law tuned
    (:func:`tune_laws`) on the loop at ``v0_V`` (:func:`learning_model`'s) is checked on the loop at
    each of ``voltages_V`` (:meth:`LearningModel.contraction` with ``loop=``); where its largest
    contraction reaches 1, the law tuned at each of them is tried too and the one whose largest
    contraction is least is kept. :attr:`LearningModel.range_contraction` records that largest value
    (below 1: the law converges monotonically wherever along the range the loop sits).
    ``voltages_V`` defaults to five levels over the command's range from 0 V.
    """
    gains = controller.gains
    if voltages_V is None:
        voltages_V = np.linspace(max(gains.u_min, 0.0), gains.u_max, 5)
    v = np.unique(np.asarray(voltages_V, float).ravel())
    if v.size == 0 or not np.all(np.isfinite(v)):
        raise InputError(f"voltages_V: give finite voltages to linearise the loop at, got {voltages_V!r}")
    loops = [learning_model(params, controller, v0_V=float(x), q_cutoff_Hz=q_cutoff_Hz, weight=weight) for x in v]
    candidates = [learning_model(params, controller, v0_V=v0_V, q_cutoff_Hz=q_cutoff_Hz, weight=weight)]
    worst = [max(candidates[0].contraction(loop=lp) for lp in loops)]
    if worst[0] >= 1.0:  # the nominal law does not hold over the range: the law of each level, its worst case least
        candidates += loops
        worst += [max(c.contraction(loop=lp) for lp in loops) for c in loops]
    k = int(np.argmin(worst))
    return replace(candidates[k], range_contraction=float(worst[k]), range_V=(float(v[0]), float(v[-1])))


def tune_laws(model: LearningModel, *, q_cutoff_Hz: float | None = None, weight: float | None = None) -> LearningModel:
    """The P-type law's filter, lead, gain and Q, and the norm-optimal weight, from ``model``'s response.

    The learning filter is PI-shaped, ``F = k_p + k_i`` (trapezoidal integral), ``k_i`` the PID's
    ``Kc / Ti`` (so the law's low frequencies pass as a setpoint does) and ``k_p`` searched from the
    PID's ``Kc b`` up; for each, ``delta`` is the peak of the response through ``F`` and ``gamma``
    half the largest gain with ``|1 - gamma e^{j w delta} G F| <= 1`` at every frequency (a gain
    margin of 2, for the plants' spread and the hysteresis' slope). The ``k_p`` kept makes
    ``|1 - L G|`` smallest on average over 0.1-50 Hz. ``q_cutoff_Hz`` (when not given) is the
    highest frequency where ``|1 - L G| <= 0.95``: above it the law learns next to nothing and Q
    keeps the noise out. ``weight`` defaults to 5 % of ``||g||^2``.
    """
    dt = model.dt_s
    omega = np.linspace(0.0, np.pi / dt, 2001)[1:]
    G0 = model.frequency_response(omega)
    zi = np.exp(-1j * omega * dt)
    integ = model.sp_integral_per_s * dt * 0.5 * (1 + zi) / (1 - zi)
    band = (omega >= 2 * np.pi * 0.1) & (omega <= 2 * np.pi * 50.0)
    impulse = np.zeros(model.length)
    impulse[0] = 1.0
    g = model.g
    best: tuple[float, LearningModel] | None = None
    for factor in (1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0):
        kp = max(model.sp_gain, 1e-6) * factor
        trial = replace(model, sp_gain=kp)
        delta = int(np.argmax(np.convolve(g, trial.setpoint_path(impulse))[: model.length]))
        G = G0 * (kp + integ) * np.exp(1j * omega * delta * dt)
        re = G.real
        if np.any(re <= 0):  # no gain contracts at every frequency with this filter
            continue
        gamma = 0.5 * float(np.min(2.0 * re / np.abs(G) ** 2))
        score = float(np.mean(np.abs(1.0 - gamma * G[band])))
        if best is None or score < best[0]:
            best = (score, replace(trial, delta=delta, gamma=gamma))
    if best is None:
        raise InternalError("no learning gain makes the P-type law contract on this loop: its phase turns beyond "
                            "90 degrees whatever the lead")
    tuned = best[1]
    if q_cutoff_Hz is None:
        G = tuned.frequency_response(omega, learning=True) * np.exp(1j * omega * tuned.delta * dt)
        learns = np.abs(1.0 - tuned.gamma * G) <= 0.95
        q_cutoff_Hz = float(omega[np.flatnonzero(learns)[-1]] / (2 * np.pi)) if learns.any() else 0.5 / dt
    w = 0.05 * float(np.sum(g**2)) if weight is None else float(weight)
    return replace(tuned, q_cutoff_Hz=float(q_cutoff_Hz), weight=w)


# --------------------------------------------------------------------------------------
# the laws
# --------------------------------------------------------------------------------------
def p_type_update(model: LearningModel, u: Array, e: Array) -> Array:
    """``Q (u + gamma F e(t + delta))`` along the last axis (a batch of plants in the leading ones)."""
    step = model.gamma * model.setpoint_path(advance(e, model.delta, fill="zero"))
    return zero_phase_lowpass(np.asarray(u, float) + step, model.q_cutoff_Hz, model.dt_s)


def norm_optimal_update(model: LearningModel, u: Array, e: Array, command_V: Array) -> Array:
    """``u + du``, ``du`` minimising ``||e - G du||^2 + weight ||du||^2`` with the command ``command_V + du``
    inside the range and its change per sample inside the slew (one plant; cvxpy + Clarabel).

    ``G du`` is the state space's response, written as its equations (``x`` a decision variable
    per sample), so the QP stays sparse over a long trial. A command the last trial already had
    outside a limit is held where it was, not made worse.
    """
    import cvxpy as cp  # here, not at import: a second of start-up for every command that never solves this QP

    u, e, c = (np.asarray(a, float) for a in (u, e, command_V))
    n = u.size
    A, B, C = model.A, model.B, model.C
    du = cp.Variable(n)
    X = cp.Variable((A.shape[0], n))
    y = (C @ X).flatten(order="C") if hasattr(cp.Expression, "flatten") else cp.vec(C @ X)
    lo, hi = model.u_range_V
    slew = model.slew_V_per_sample
    cmd = c + du
    constraints = [X[:, 0] == 0, X[:, 1:] == A @ X[:, :-1] + B @ cp.reshape(du[:-1], (1, n - 1), order="C")]
    if np.isfinite(lo):
        constraints.append(cmd >= np.minimum(lo, c))
    if np.isfinite(hi):
        constraints.append(cmd <= np.maximum(hi, c))
    if np.isfinite(slew):
        constraints.append(cp.abs(cp.diff(cmd)) <= np.maximum(slew, np.abs(np.diff(c))))
    problem = cp.Problem(cp.Minimize(cp.sum_squares(e - y) + model.weight * cp.sum_squares(du)), constraints)
    try:
        problem.solve(solver=cp.CLARABEL)
    except cp.error.SolverError as exc:
        raise InternalError(f"the norm-optimal ILC step failed in Clarabel: {exc}") from exc
    if problem.status not in ("optimal", "optimal_inaccurate") or du.value is None:
        raise InternalError(f"the norm-optimal ILC step ended '{problem.status}' (Clarabel)")
    return u + np.asarray(du.value, float)


# --------------------------------------------------------------------------------------
# preview
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PreviewPlan:
    """The best force any controller with this preview reaches under the slew and voltage limits.

    ``force_N`` is the planned force per sample; ``rms_N`` its RMS error against the reference
    (scored from the first change, as :meth:`ClosedLoopRun.tracking_error`): the preview floor.
    ``starts`` is, per jump, the last sample at the old level relative to the jump.
    """

    t_s: Array
    force_N: Array
    rms_N: float
    rate_N_per_s: float
    preview_s: float
    lead_samples: int
    starts: list[int]
    reach_N: tuple[float, float]
    interpolation: str = "hold"

    @property
    def setpoint(self) -> Reference:
        """The plan as a reference the loop can follow (one level per sample; ramped between them for a
        ramped reference's plan)."""
        return Reference(self.t_s[:-1], self.force_N[:-1], float(self.t_s[-1]), self.interpolation)

    def to_dict(self) -> dict[str, Any]:
        return {"rms_N": self.rms_N, "rate_N_per_s": self.rate_N_per_s, "preview_s": self.preview_s,
                "lead_samples": self.lead_samples, "starts_samples": self.starts, "reach_N": list(self.reach_N)}


def default_preview_s(params: RigParams, reference: Reference) -> float:
    """The preview that plans every jump as well as any preview could: the delay and the amplifier's lag
    (the feedforward's lead, :func:`feedforward_lead`) plus the slew time of the largest jump; for a ramped
    reference the lead alone."""
    if reference.interpolation != "hold":  # a ramp: the lead alone (ramp_plan follows it exactly then)
        return feedforward_lead(params) * params.sample_period_s
    rate = tracking_floor(params, reference)["rate_N_per_s"]
    jump = float(np.max(np.abs(np.diff(reference.levels_N)))) if reference.levels_N.size > 1 else 0.0
    return feedforward_lead(params) * params.sample_period_s + jump / rate


def feedforward_lead(params: RigParams) -> int:
    """Samples the feedforward reads the plan ahead: the delay line, the D/A's sample and the amplifier's lag."""
    tau = 1.0 / (2.0 * np.pi * float(np.max(params.amp_bandwidth_Hz)))
    return int(params.delay_samples) + 1 + int(round(tau / params.sample_period_s))


def branch_ramps(params: RigParams, levels_N: Array, u_max_V: float = 110.0, slew_fraction: float = 1.0) -> list[Array]:
    """Per change of ``levels_N``, the fastest force path along the rig's own hysteresis branch.

    The quasi-static rig (:meth:`~piezopreload.models.actuator.Rig.quasi_static_loop`: the truth
    hysteresis, no creep, no amplifier lag) is driven from rest at 0 V through the levels with the
    voltage moving at the amplifier's slew, one sample at a time, until the force reaches each
    level (or the voltage its limit). Along a monotone branch the force is monotone in the
    voltage, so no command moves it faster: the path is the least-error ramp's shape for that
    change (just after a reversal the branch is flat, ``1 - alpha`` of the stroke's slope, so the
    ramp starts slowly). Returns one array per change: the force at each sample of its ramp,
    ending at the level (or where the voltage limit stops it). ``slew_fraction`` < 1 moves the voltage
    at that fraction of the slew: a path the loop can follow with authority to spare.
    """
    if not 0.0 < slew_fraction <= 1.0:
        raise InputError(f"slew_fraction must be in (0, 1], got {slew_fraction!r}")
    rig = Rig(params)
    step = float(params.slew_V_per_s) * params.sample_period_s * slew_fraction
    state, v = None, 0.0
    f_now = float(np.min(params.bolt_preload_N))
    ramps = []
    for target in np.asarray(levels_N, float)[1:]:
        direction = 1.0 if target > f_now else -1.0
        n_max = int(np.ceil(u_max_V / step)) + 1
        path = np.clip(v + direction * step * np.arange(1, n_max + 1), 0.0, u_max_V)
        f, _ = rig.quasi_static_loop(path, state)
        reached = np.flatnonzero((f - target) * direction >= 0)
        k = int(reached[0]) + 1 if reached.size else int(np.argmax(path == path[-1])) + 1
        f, state = rig.quasi_static_loop(path[:k], state)
        v = float(path[k - 1])
        ramp = np.concatenate([[f_now], f])
        ramp = np.clip(ramp, min(f_now, target), max(f_now, target))
        ramps.append(ramp[1:] if ramp.size > 1 else ramp)
        f_now = float(f[-1]) if not reached.size else float(target)
    return ramps


def preview_plan(params: RigParams, reference: Reference, preview_s: float, *, u_max_V: float = 110.0,
                 lead_samples: int | None = None, ramps: list[Array] | None = None,
                 after_change_weight: float = 0.0) -> PreviewPlan:
    """The preview floor and the planned force (see the module docstring).

    Per jump the force ramps at ``rate`` (:func:`~piezopreload.tuning.pid.tracking_floor`'s)
    from a last sample at the old level ``s`` samples after the jump, ``s`` searched over
    ``[lead - p, lead]`` (``p`` the preview in samples; ``lead`` the delay, the default, for the
    floor, or :func:`feedforward_lead` for the plan a controller can follow); the levels are held
    inside what the voltage range reaches. The jumps' ramps must not overlap (holds longer than a
    ramp and the preview). ``ramps`` (one force path per change, :func:`branch_ramps`) replaces
    the straight ramps at the one steepest rate by the rig's own branch at full slew.
    ``after_change_weight`` ``w`` places each ramp to least ``whole + w * outside``: the squared error
    of every sample plus ``w`` times that of the samples outside :data:`AFTER_CHANGE_S` after the
    jump (the after-change score). 0 is the whole-trajectory floor; a larger ``w`` starts the ramps
    later, trading whole-trajectory error for error after the jumps.
    """
    if not (np.isfinite(preview_s) and preview_s >= 0):
        raise InputError(f"preview_s must be a finite number >= 0, got {preview_s!r}")
    if not (np.isfinite(after_change_weight) and after_change_weight >= 0):
        raise InputError(f"after_change_weight must be a finite number >= 0, got {after_change_weight!r}")
    if reference.interpolation != "hold":
        return ramp_plan(params, reference, preview_s, u_max_V=u_max_V, lead_samples=lead_samples)
    dt = params.sample_period_s
    lead = int(params.delay_samples) if lead_samples is None else int(lead_samples)
    p = int(round(preview_s / dt))
    floor = tracking_floor(params, reference)
    n = int(round(reference.duration_s / dt)) + 1
    t = np.arange(n) * dt
    r = reference.at(t)
    lo, hi = float(np.min(params.bolt_preload_N)), float(np.min(reach_N(Rig(params), u_max_V)))
    levels = np.clip(reference.levels_N, lo, hi)
    force = np.full(n, levels[0])
    k_jumps = np.searchsorted(t, reference.times_s[1:] - 1e-12)
    after = int(round(AFTER_CHANGE_S / dt))
    starts = []
    prev_end = 0
    for j, k in enumerate(k_jumps):
        old, new = levels[j], levels[j + 1]
        size = abs(new - old)
        rho = floor["rate_N_per_s"] * dt
        if ramps is None:
            n_ramp = int(np.ceil(size / rho - 1e-12)) if size > 0 else 0
        else:  # the rig's own path: its samples, then the level (held where the voltage limit stopped it)
            path = ramps[j]
            n_ramp = path.size
            new = float(path[-1])
            size = abs(new - old)
        path = None if ramps is None else ramps[j]
        best: tuple[float, int] | None = None
        for s in range(lead - p, lead + 1):
            s0 = int(k) + s
            if s0 < prev_end:
                continue
            m = np.arange(max(min(s0, int(k)), 0), min(s0 + n_ramp + 1, n))  # from the jump when the ramp starts after it
            sq = (r[m] - _ramp(m, s0, old, new, rho, path)) ** 2
            err = float(np.sum(sq) + after_change_weight * np.sum(sq[(m < k) | (m >= k + after)]))
            if best is None or err < best[0]:
                best = (err, s)
        if best is None:
            raise InputError(f"the reference's change at {reference.times_s[j + 1]:g} s comes before the previous one's "
                             "ramp can end; hold each level longer than the slew time and the preview")
        s0 = int(k) + best[1]
        m = np.arange(max(s0, 0), n)  # to the end: the next jump's ramp overwrites from its start
        force[m] = _ramp(m, s0, old, new, rho, path)
        starts.append(best[1])
        prev_end = min(s0 + n_ramp + 1, n)
    scored = t >= reference.times_s[1] if reference.times_s.size > 1 else np.ones(n, bool)
    rms = float(np.sqrt(np.mean((r[scored] - force[scored]) ** 2)))
    return PreviewPlan(t, force, rms, floor["rate_N_per_s"], float(preview_s), lead, starts, (lo, hi))


def ramp_plan(params: RigParams, reference: Reference, preview_s: float, *, u_max_V: float = 110.0,
              lead_samples: int | None = None) -> PreviewPlan:
    """The plan and the preview floor of a ramped (piecewise linear) reference.

    A ramp has no jump to slew across: what the loop's delay costs is the lag at each change of
    slope. The force at sample ``k`` is decided by a command sent ``lead`` samples before it (the
    delay, the default, for the floor; :func:`feedforward_lead` for the plan a controller
    follows); with ``p`` samples of preview that command knows the reference up to ``k - lead + p``.
    Where the preview covers the lead (``p >= lead``) the plan is the reference itself; short of
    it, the best the loop can do is extrapolate the reference's last known slope over the
    ``d = lead - p`` samples it does not know, ``r[k - d] + d (r[k - d] - r[k - d - 1])``. The plan
    is held inside the force the voltage range reaches and, where the reference is steeper than
    :func:`~piezopreload.tuning.pid.tracking_floor`'s rate, moves toward it at that rate. Its RMS
    error against the reference (from the first point on, as ``tracking_error`` scores) is the
    floor; with ``p = 0`` the causal floor of a ramped reference (:func:`causal_floor`).
    """
    dt = params.sample_period_s
    lead = int(params.delay_samples) if lead_samples is None else int(lead_samples)
    p = int(round(preview_s / dt))
    d = max(lead - p, 0)
    n = int(round(reference.duration_s / dt)) + 1
    t = np.arange(n) * dt
    r = reference.at(t)
    # the steepest rate the force can move (tracking_floor's, which depends on the rig alone; one 1 N step asks it)
    rate = float(tracking_floor(params, Reference(np.array([0.0, dt]), np.array([0.0, 1.0]), 2 * dt))["rate_N_per_s"])
    known = np.concatenate([np.full(d, r[0]), r[: n - d]]) if d else r.copy()
    before = np.concatenate([np.full(d + 1, r[0]), r[: n - d - 1]])
    target = known + d * (known - before)
    lo, hi = float(np.min(params.bolt_preload_N)), float(np.min(reach_N(Rig(params), u_max_V)))
    target = np.clip(target, lo, hi)
    step = rate * dt
    force = target.copy()
    if np.any(np.abs(np.diff(target)) > step):  # steeper than the force can move: follow at the rate
        for k in range(1, n):
            force[k] = force[k - 1] + np.clip(target[k] - force[k - 1], -step, step)
    scored = t >= reference.times_s[1] if reference.times_s.size > 1 else np.ones(n, bool)
    rms = float(np.sqrt(np.mean((r[scored] - force[scored]) ** 2)))
    return PreviewPlan(t, force, rms, rate, float(preview_s), lead, [], (lo, hi), interpolation="linear")


def causal_floor(params: RigParams, reference: Reference) -> float:
    """The causal floor (RMS, N) of ``reference``: :func:`~piezopreload.tuning.pid.tracking_floor` over a
    held reference's jumps, the extrapolated slope's lag (:func:`ramp_plan` without preview) on a ramped one."""
    if reference.interpolation == "hold":
        return float(tracking_floor(params, reference)["rms_N"])
    return ramp_plan(params, reference, 0.0).rms_N


def _ramp(m: Array, s0: int, old: float, new: float, rho: float, path: Array | None) -> Array:
    """The force at samples ``m`` of a change from ``old`` to ``new`` whose last sample at ``old`` is ``s0``:
    a straight ramp of ``rho`` per sample, or ``path`` (the rig's own, sample by sample) then held."""
    if path is None:
        return old + np.sign(new - old) * np.minimum((m - s0) * rho, abs(new - old))
    return np.where(m <= s0, old, path[np.clip(m - s0 - 1, 0, path.size - 1)])


def preview_feedforward(controller: Controller, plan: Array, lead: int) -> Array:
    """The previewed ``ff_extra``: the inverse P-I of the plan read ``lead`` samples ahead, less the
    controller's own feedforward of the plan now (which it adds itself); 0 without a feedforward."""
    if controller.feedforward is None or lead == 0:
        return np.zeros_like(plan)
    inverse = controller.feedforward
    ahead = np.asarray(inverse(advance(plan, lead), inverse.initial_state()), float)
    now = np.asarray(inverse(plan, inverse.initial_state()), float)
    return ahead - now


# --------------------------------------------------------------------------------------
# learning
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Iteration:
    """One trial: the error of the true force (whole trajectory, and outside the transport after each
    jump) against the reference, and of the measured force against the plan (what the law sees).
    Arrays over the plants for a batch."""

    iteration: int
    tracking_rms_N: Any
    tracking_rms_after_change_N: Any
    measured_rms_N: Any

    def to_dict(self) -> dict[str, Any]:
        def plain(x: Any) -> Any:
            return float(x) if np.ndim(x) == 0 else np.asarray(x, float).tolist()
        return {"iteration": self.iteration, "tracking_rms_N": plain(self.tracking_rms_N),
                "tracking_rms_after_change_N": plain(self.tracking_rms_after_change_N),
                "measured_rms_N": plain(self.measured_rms_N)}


@dataclass(frozen=True, eq=False)
class LearningResult:
    """What :func:`learn` returns.

    ``ff_extra_V`` is the best iterate's learned signal (it starts as the previewed feedforward) per
    sample (``(plants, n)`` for a batch), ``setpoint_N`` the plan the controller follows,
    ``history`` the error per iteration, ``best`` the best iterate per plant (by the measured
    error, what a rig knows), ``run`` the best iterate's run scored against the reference,
    ``converged``/``diverged`` per plant, ``causal_floor_N`` and ``preview_floor_N`` the
    nominal plant's floors.
    """

    ff_extra_V: Array
    setpoint_N: Array
    history: list[Iteration]
    best: Array
    converged: Array
    diverged: Array
    run: ClosedLoopRun
    reference: Reference
    causal_floor_N: float
    preview_floor_N: float
    preview_s: float
    method: str
    model: LearningModel
    plants: int | None
    seconds: float
    info: dict[str, Any] = field(default_factory=dict)

    def _best(self, key: str) -> Array:
        rows = np.array([np.atleast_1d(getattr(h, key)) for h in self.history])  # (iterations, plants)
        return rows[np.asarray(self.best).reshape(-1), np.arange(rows.shape[1])]

    @property
    def tracking_rms_N(self) -> float:
        """The worst plant's whole-trajectory RMS of the true force at its best iterate."""
        return float(np.max(self._best("tracking_rms_N")))

    @property
    def tracking_rms_after_change_N(self) -> float:
        return float(np.max(self._best("tracking_rms_after_change_N")))

    def signal(self, gain_set_sha256: str | None, inputs: dict[str, Any] | None = None, plant: int = 0) -> LearnedSignal:
        """The learned signal as an artifact (of plant ``plant`` for a batch)."""
        u = self.ff_extra_V if self.ff_extra_V.ndim == 1 else self.ff_extra_V[plant]
        best = int(np.asarray(self.best).reshape(-1)[plant])
        return LearnedSignal(u, self.setpoint_N, float(self.model.dt_s), self.reference, gain_set_sha256, best,
                             self.preview_s, self.method, [h.to_dict() for h in self.history], dict(inputs or {}))

    def save(self, folder: str | Path, gain_set_sha256: str | None, inputs: dict[str, Any] | None = None) -> dict[str, Any]:
        """Write the learned signal (``learned.json``, :meth:`signal`) and the figure (``learning.png``) to ``folder``."""
        folder = Path(folder)
        saved = self.signal(gain_set_sha256, inputs).save(folder / "learned.json")
        self.plot().savefig(folder / "learning.png", dpi=120)
        return {"out": str(folder / "learned.json"), "content_sha256": saved.content_sha256}

    def to_dict(self) -> dict[str, Any]:
        span = float(np.ptp(self.reference.levels_N)) or 1.0
        return {
            "tracking_rms_N": self.tracking_rms_N, "tracking_rms_after_change_N": self.tracking_rms_after_change_N,
            "tracking_rms_pct_of_range": 100.0 * self.tracking_rms_N / span,
            # the whole trajectory scored from t = 0 (the score above starts at the first change, as the
            # causal floor's; a previewed ramp that starts before it is not counted there)
            "tracking_rms_from_start_N": float(np.max(self.run.tracking_error(0.0)["rms"])),
            "causal_floor_N": self.causal_floor_N, "preview_floor_N": self.preview_floor_N,
            "over_preview_floor_ratio": self.tracking_rms_N / self.preview_floor_N if self.preview_floor_N > 0 else None,
            "iterations": len(self.history) - 1, "converged": bool(np.all(self.converged)),
            "diverged_plants": int(np.sum(self.diverged)), "plants": self.plants,
            "best_iteration": np.asarray(self.best).reshape(-1).tolist(),
            "preview_s": self.preview_s, "method": self.method,
            "learning": {"delta_samples": self.model.delta, "gamma": self.model.gamma,
                         "q_cutoff_Hz": self.model.q_cutoff_Hz, "contraction": self.model.contraction(),
                         "contraction_over_range": self.model.range_contraction,
                         "range_V": None if self.model.range_V is None else list(self.model.range_V),
                         "weight": self.model.weight},
            "history": [h.to_dict() for h in self.history], "seconds": self.seconds, **self.info,
        }

    def plot(self) -> Any:
        """The error per iteration (left) and the best iterate's force against the reference (right): a Figure."""
        from matplotlib.figure import Figure

        fig = Figure(figsize=(9.0, 3.6), layout="constrained")
        a, b = fig.subplots(1, 2)
        it = [h.iteration for h in self.history]
        for key, label in (("tracking_rms_N", "whole trajectory"), ("tracking_rms_after_change_N", "outside 0.1 s after jumps")):
            a.semilogy(it, [float(np.max(np.atleast_1d(getattr(h, key)))) for h in self.history], "o-", label=label)
        a.axhline(self.preview_floor_N, color="0.4", ls="--", label="preview floor")
        a.axhline(self.causal_floor_N, color="0.7", ls=":", label="causal floor")
        a.set(xlabel="iteration", ylabel="RMS error of the true force (N)")
        a.legend(fontsize="small")
        run = self.run
        force = run.force_N if run.force_N.ndim == 1 else run.force_N.reshape(-1, run.t_s.size)[0]
        b.plot(run.t_s, run.reference_N, color="0.35", ls="--", label="reference")
        b.plot(run.t_s, self.setpoint_N, color="0.6", lw=0.8, label="plan")
        b.plot(run.t_s, force, lw=0.8, label="force")
        b.set(xlabel="time (s)", ylabel="force (N)")
        b.legend(fontsize="small")
        return fig


def _scored(run: ClosedLoopRun, reference: Reference) -> ClosedLoopRun:
    return replace(run, reference=reference, reference_N=reference.at(run.t_s))


def named_reference(reference: Reference | str, references: dict[str, Reference]) -> Reference:
    """``reference`` itself, or the one of ``references`` it names (``schedule`` is refused until a design's
    preload schedule reaches a study's references)."""
    if isinstance(reference, Reference):
        return reference
    if reference == "schedule":
        raise InputError("--reference schedule: the design's schedule is learned by the learn stage of 'piezopreload "
                         "run' (a study with [plant] from_design and a [learning] table); here give step, trajectory "
                         "or a time_s,force_N CSV (the system stage's system/reference.csv, say)")
    if reference not in references:
        raise InputError(f"reference must be one of {', '.join(references)} or a CSV, got {reference!r}")
    return references[reference]


def learn(controller: Controller, rig: Rig, reference: Reference, *, iterations: int = 10, preview_s: float | None = None,
          method: str = "p-type", plants: int | None = None, seed: int = 0, spread: dict[str, float] | None = None,
          model: LearningModel | None = None, grow_tol: float = 0.05, settle_tol: float = 0.05,
          after_change_weight: float = 0.0, slew_fraction: float = PLAN_SLEW_FRACTION,
          progress: Callable[[str], None] | None = None) -> LearningResult:
    """Learn a feedforward correction for ``controller`` on ``rig`` over ``reference``, with preview.

    Parameters
    ----------
    controller, rig, reference
        The loop and the repeated reference (``rig`` one plant: the nominal).
    iterations : int
        Learning updates (trials ``0..iterations``; trial 0 is the preview alone).
    preview_s : float or None
        The preview horizon; None for :func:`default_preview_s`, 0 for none.
    method : str
        ``"p-type"`` (Q-filtered, with lead) or ``"norm-optimal"`` (the constrained QP).
    plants : int or None
        Learn on that many Monte Carlo plants around ``rig`` (each its own learning, the nominal
        learning model); None learns on ``rig`` itself.
    seed : int
        Of the plants' draw and of the sensor noise (trial ``k`` uses ``seed + k``).
    grow_tol, settle_tol : float
        A plant stops learning when its measured error exceeds its best by ``grow_tol`` (diverged;
        the best iterate is kept); it has converged when it has not diverged and its last update
        changed the error by less than ``settle_tol`` of it.
    after_change_weight : float
        How the plan places each change (:func:`preview_plan`): 0 for the least whole-trajectory
        error; larger to start the ramps later, for less error outside 0.1 s after the jumps.
    slew_fraction : float
        The planned ramps move the voltage at this fraction of the slew (:func:`branch_ramps`): the
        rest is the loop's authority to correct (at the full slew nothing is left to correct with).
    """
    t0 = time.perf_counter()
    say = progress or (lambda _m: None)
    if method not in METHODS:
        raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if not (isinstance(iterations, int | np.integer) and iterations >= 0):
        raise InputError(f"iterations must be an integer >= 0, got {iterations!r}")
    if plants is not None and not (isinstance(plants, int | np.integer) and plants >= 1):
        raise InputError(f"plants must be a positive integer or None, got {plants!r}")
    params = rig.params
    if params.batch_shape:
        raise InputError("learn: give the nominal rig (one plant); plants=N draws the Monte Carlo batch")
    preview = default_preview_s(params, reference) if preview_s is None else float(preview_s)
    floor_plan = preview_plan(params, reference, preview, u_max_V=controller.gains.u_max)
    lead = feedforward_lead(params) if preview > 0 else 0
    # the rig's own branch per jump (a ramped reference has no jumps to slew across)
    ramps = branch_ramps(params, reference.levels_N, controller.gains.u_max) if reference.interpolation == "hold" else None
    branch_floor = floor_plan if ramps is None else preview_plan(params, reference, preview,
                                                                  u_max_V=controller.gains.u_max, ramps=ramps)
    plan = preview_plan(params, reference, preview, u_max_V=controller.gains.u_max,
                        lead_samples=max(lead, params.delay_samples),
                        ramps=None if ramps is None else branch_ramps(params, reference.levels_N,
                                                                      controller.gains.u_max, slew_fraction),
                        after_change_weight=after_change_weight)
    causal = causal_floor(params, reference)
    setpoint = plan.setpoint if preview > 0 else reference
    target = plan.force_N if preview > 0 else reference.at(plan.t_s)
    base = preview_feedforward(controller, target, lead)
    model = learning_model_over(params, controller) if model is None else model
    sim_rig = Rig(params.vary(plants, spread or DEFAULT_SPREAD, seed)) if plants else rig
    batch = sim_rig.params.batch_shape
    n = plan.t_s.size
    u = np.broadcast_to(base, batch + (n,)).copy()  # the learned signal starts as the previewed feedforward
    history: list[Iteration] = []
    best_err = np.full(batch, np.inf)
    best_u = u.copy()
    best_it = np.zeros(batch, int)
    active = np.ones(batch, bool)
    diverged = np.zeros(batch, bool)
    last_err = np.full(batch, np.nan)
    change = np.full(batch, np.inf)
    best_run: ClosedLoopRun | None = None
    for k in range(iterations + 1):
        run = simulate(sim_rig, controller, setpoint, seed=seed + k, ff_extra_V=np.moveaxis(u, -1, 0))
        scored = _scored(run, reference)
        whole = scored.tracking_error()["rms"]
        after = scored.tracking_error(after_change_s=AFTER_CHANGE_S)["rms"]
        e = target - run.measured_N
        # where the command sat at a limit the plant was out of the loop's authority: nothing to learn there
        # (learning on would wind the signal up against the limit, as an integral without anti-windup)
        lo, hi = controller.gains.u_min, controller.gains.u_max
        e_learn = np.where((run.command_V <= lo + 1e-9) | (run.command_V >= hi - 1e-9), 0.0, e)
        measured = np.sqrt(np.mean(e[..., plan.t_s >= reference.times_s[min(1, reference.times_s.size - 1)]] ** 2, axis=-1))
        history.append(Iteration(k, whole, after, measured))
        say(f"iteration {k}: {float(np.max(whole)):.4g} N RMS (true force), "
            f"{float(np.max(after)):.4g} N outside {AFTER_CHANGE_S:g} s after jumps")
        improved = active & (measured < best_err)
        best_err = np.where(improved, measured, best_err)
        best_it = np.where(improved, k, best_it)
        best_u[improved] = u[improved]
        if best_run is None:
            best_run = scored
        else:
            best_run = _merge_runs(best_run, scored, improved)
        grew = active & (measured > (1.0 + grow_tol) * best_err)
        diverged |= grew
        change = np.where(active & np.isfinite(last_err), np.abs(measured - last_err) / np.maximum(last_err, 1e-12), change)
        last_err = np.where(active, measured, last_err)
        active &= ~grew
        if k == iterations or not active.any():
            break
        if method == "p-type":
            u_next = p_type_update(model, u, e_learn)
        else:
            u_next = u.copy()
            cmd = run.command_V
            for i in np.ndindex(batch):
                u_next[i] = norm_optimal_update(model, u[i], e_learn[i], cmd[i])
        u = np.where(active[..., None], u_next, u)
    converged = ~diverged & (change <= settle_tol)
    # with preview a change starts before its jump: what the after-change score counts of the plan itself, and
    # the score outside whole transitions (from the preview before each jump to 0.1 s after it)
    plan_run = replace(best_run, force_N=plan.force_N, reference=reference, reference_N=reference.at(plan.t_s))
    plan_after = float(plan_run.tracking_error(after_change_s=AFTER_CHANGE_S)["rms"])
    shifted = Reference(np.concatenate([[0.0], np.maximum(reference.times_s[1:] - preview, 1e-9)]), reference.levels_N,
                        reference.duration_s) if preview > 0 and reference.interpolation == "hold" else reference
    outside = replace(best_run, reference=shifted).tracking_error(after_change_s=AFTER_CHANGE_S + preview)["rms"]
    if best_run is None:  # pragma: no cover - the loop runs at least once
        raise InternalError("learn: no trial ran")
    return LearningResult(ff_extra_V=best_u, setpoint_N=target, history=history, best=best_it,
                          converged=converged, diverged=diverged, run=best_run, reference=reference,
                          causal_floor_N=causal, preview_floor_N=floor_plan.rms_N, preview_s=preview, method=method,
                          model=model, plants=plants, seconds=time.perf_counter() - t0,
                          info={"plan_rms_N": plan.rms_N, "feedforward_lead_samples": lead,
                                "preview_floor_branch_N": branch_floor.rms_N, "plan_rms_after_change_N": plan_after,
                                "plan_slew_fraction": slew_fraction, "after_change_weight": after_change_weight,
                                "tracking_rms_outside_transitions_N": float(np.max(outside))})


def _merge_runs(old: ClosedLoopRun, new: ClosedLoopRun, take: Array) -> ClosedLoopRun:
    """Per plant, the new run's samples where ``take``, else the old's."""
    if not np.any(take):
        return old
    if old.force_N.ndim == 1:
        return new
    changes = {}
    for name in ("force_N", "measured_N", "command_V", "voltage_V", "p_V", "i_V", "d_V", "ff_V"):
        changes[name] = np.where(take[..., None], getattr(new, name), getattr(old, name))
    return replace(old, **changes)


def learn_from_log(signal: LearnedSignal, log: dict[str, Array], gain_set: GainSet, shown: str = "the learned signal") -> LearnedSignal:
    """:func:`learn_from_run` from a rig run log's columns (the controlled samples) of ``signal`` played with
    ``gain_set`` (whose plant and controller give the learning model); a signal of another gain set is refused."""
    signal.check(gain_set.content_sha256, None, shown)
    if gain_set.plant is None:
        raise InputError("the gain set names no plant to build the learning model on; write it again with 'tune'")
    keep = log["mode"] == 0
    model = learning_model_over(gain_set.plant, gain_set.controller())  # the law learn() uses
    return learn_from_run(signal, log["measured_N"][keep], log["command_V"][keep], model)


def learn_from_run(signal: LearnedSignal, measured_N: Array, command_V: Array, model: LearningModel) -> LearnedSignal:
    """One learning update from a rig run of ``signal``: its measured force (and command) per sample
    give the next iteration's signal."""
    y, c = np.asarray(measured_N, float), np.asarray(command_V, float)
    n = signal.ff_extra_V.size
    if y.shape != (n,) or c.shape != (n,):
        raise InputError(f"the run has {y.size} samples; the learned signal {n}: run the whole reference")
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(c))):
        raise InputError("the run's measured force or command is not finite everywhere (a tripped run?)")
    e = signal.setpoint_N - y
    lo, hi = model.u_range_V
    e = np.where((c <= lo + 1e-9) | (c >= hi - 1e-9), 0.0, e)  # no learning where the command sat at a limit
    if signal.method == "norm-optimal":
        u = norm_optimal_update(model, signal.ff_extra_V, e, c)
    else:
        u = p_type_update(model, signal.ff_extra_V, e)
    rms = float(np.sqrt(np.mean(e**2)))
    history = [*signal.history, {"iteration": signal.iteration, "measured_rms_N": rms, "source": "rig run"}]
    return replace(signal, ff_extra_V=u, iteration=signal.iteration + 1, history=history, content_sha256=None)


# --------------------------------------------------------------------------------------
# learning over a schedule's passes (the whole system's learn stage)
# --------------------------------------------------------------------------------------
def save_passes(passes: list[LearningResult], folder: str | Path, gain_set_sha256: str | None,
                inputs: dict[str, Any]) -> dict[str, Path]:
    """Write the learning of each pass of a schedule (one per margin the schedule was planned with) into ``folder``.

    ``learned-pass<k>.json`` holds pass ``k``'s learned signal (tied to ``gain_set_sha256`` and that
    pass's reference); ``learning.json`` (kind ``learning``) the error per iteration of every pass
    and, at its top level, the last pass's: its best error (``tracking_rms_N``, and in % of the
    reference's range), the error before learning (trial 0: the tuned loop with its feedforward and
    the preview, no learned correction), the contraction over the range, the floors. Returns the
    paths by label: ``learning``, ``learned`` (the last pass's signal, what the rig plays), ``pass<k>``.
    """
    if not passes:
        raise InputError("save_passes: no pass was learned (the schedule's tracking ran without learning)")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for stale in folder.glob("learned-pass*.json"):  # a pass the schedule no longer needs
        stale.unlink()
    paths: dict[str, Path] = {}
    records = []
    for k, result in enumerate(passes, start=1):
        path = folder / f"learned-pass{k}.json"
        result.signal(gain_set_sha256, {**inputs, "pass": k}).save(path)
        paths[f"pass{k}"] = path
        d = result.to_dict()
        span = float(np.ptp(result.reference.levels_N)) or 1.0
        records.append({"pass": k, "signal": path.name, "reference_sha256": reference_sha256(result.reference),
                        "before_learning_rms_N": float(np.max(result.history[0].tracking_rms_N)),
                        "before_learning_pct_of_range": 100.0 * float(np.max(result.history[0].tracking_rms_N)) / span,
                        **{key: d[key] for key in ("tracking_rms_N", "tracking_rms_pct_of_range", "iterations",
                                                   "converged", "best_iteration", "causal_floor_N", "preview_floor_N",
                                                   "preview_s", "method", "learning", "history")}})
    last = records[-1]
    paths["learned"] = paths[f"pass{len(passes)}"]
    paths["learning"] = folder / "learning.json"
    write_artifact(paths["learning"], "learning", {
        "pass_records": records, "passes": len(records),
        **{key: last[key] for key in ("tracking_rms_N", "tracking_rms_pct_of_range", "before_learning_rms_N",
                                      "before_learning_pct_of_range", "iterations", "converged", "causal_floor_N",
                                      "preview_floor_N", "preview_s", "method", "history")},
        "contraction_over_range": last["learning"]["contraction_over_range"], "learned": paths["learned"].name,
        "inputs": inputs})
    return paths


def played_passes(learning_path: str | Path, gain_set_sha256: str | None) -> tuple[Callable[[Reference], Array],
                                                                                  dict[str, Any]]:
    """From a schedule's ``learning.json`` (:func:`save_passes`): the learned signal for each pass's
    reference (:func:`learned_by_reference`) and the figures before learning, for the tracking's summary."""
    record = read_artifact(learning_path, "learning")
    folder = Path(learning_path).parent
    return (learned_by_reference([folder / p["signal"] for p in record["pass_records"]], gain_set_sha256),
            {"tracking_rms_N_before_learning": record["before_learning_rms_N"],
             "tracking_rms_pct_of_range_before_learning": record["before_learning_pct_of_range"],
             "learning_iterations": record["iterations"]})


def schedule_learner(params: RigParams, controller: Controller, *, iterations: int, preview_s: float | None,
                     method: str, seed: int, progress: Callable[[str], None] | None = None
                     ) -> tuple[Callable[[Reference], Array], list[LearningResult]]:
    """A learner for each pass of a schedule on one plant (``params``): called with a pass's repeated
    reference it learns on it (:func:`learn`, one law for every pass: :func:`learning_model_over`) and
    returns the best signal; the list collects each pass's :class:`LearningResult`."""
    model = learning_model_over(params, controller)
    results: list[LearningResult] = []

    def learned(reference: Reference) -> Array:
        results.append(learn(controller, Rig(params), reference, iterations=iterations, model=model,
                             preview_s=preview_s, method=method, seed=seed, progress=progress))
        return results[-1].ff_extra_V

    return learned, results


def learned_by_reference(paths: list[Path], gain_set_sha256: str | None) -> Callable[[Reference], Array]:
    """``ff_extra_V`` for a reference from the learned signals at ``paths`` (:func:`save_passes`'): the one learned on
    that very reference, for that gain set. A reference none was learned on is refused (the learning is stale)."""
    signals = {}
    for path in paths:
        signal = LearnedSignal.load(path)
        signal.check(gain_set_sha256, None, str(path))
        signals[signal.reference_sha256] = signal

    def ff_extra(reference: Reference) -> Array:
        key = reference_sha256(reference)
        if key not in signals:
            raise InputError(f"no learned signal was learned on reference {key} (learned on: {', '.join(signals)}); "
                             "run the learn stage again ('piezopreload run --force')")
        return signals[key].ff_extra_V

    return ff_extra
