"""The loop a learning law acts on, linearised, and the Q-filtered P-type law.

A learned signal ``u`` enters the loop as ``ff_extra`` (added to the feedforward, before the
clamp); the system it drives is the closed loop from ``ff_extra`` to the force. One loop step
(:func:`~piezopreload.tuning.horizon.tuning_loop`: the rig's step with its corners rounded, the PID;
the inverse-P-I feedforward depends on the setpoint alone and drops out of the response to
``ff_extra``) is linearised by CasADi at rest at a voltage (:func:`linearise_loop`, one
:class:`LoopLinearisation` per voltage and plant: the force and the command as outputs, and the
controller's bumpless start, which makes its integral take up the first sample's ``ff_extra``).

The **P-type** law (Bristow, Tharayil, Alleyne 2006, "A survey of iterative learning control",
IEEE Control Systems 26(3)) is ``u_{k+1} = Q (u_k + gamma F e_k(t + delta))``: ``Q`` a zero-phase
low-pass (a Butterworth filter run forward and backward from rest), ``F`` a PI-shaped learning
filter (the PID's integral rejects ``ff_extra`` at low frequency, where a setpoint passes),
``delta`` the peak of the response through ``F`` and ``gamma`` half the largest gain that keeps
``|1 - gamma e^{j w delta} G F|`` at most 1 (:func:`tune_laws`). In the lifted domain
``u_{k+1} - u_inf = Q (I - L G)(u_k - u_inf)``, so ``||Q (I - L G)|| < 1`` gives monotone
convergence (:meth:`LearningModel.contraction`). It needs the model only to set its lead and gain:
the model-free option beside the norm-optimal law (:mod:`piezopreload.tuning.norm_optimal`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import casadi as ca
import numpy as np

from piezopreload.artifacts.learned import LearningMethod
from piezopreload.core._typing import Array
from piezopreload.core.errors import InputError, InternalError
from piezopreload.models.actuator import Plant
from piezopreload.models.controller import Controller
from piezopreload.models.loop import LoopModel, step_function
from piezopreload.models.ops import NUMPY
from piezopreload.tuning.horizon import tuning_loop
from piezopreload.tuning.preview import advance

__all__ = ["METHODS", "LoopLinearisation", "linearise_loop", "LearningModel", "learning_model", "learning_model_over",
           "tune_laws", "zero_phase_lowpass", "p_type_update"]


#: the learning laws (:class:`~piezopreload.artifacts.learned.LearningMethod`); the first is the default
METHODS = tuple(LearningMethod)


def zero_phase_lowpass(x: Array, cutoff_Hz: float, dt_s: float, order: int = 2) -> Array:
    """The zero-phase low-pass ``Q`` of the P-type law: a Butterworth filter run forward, then backward.

    Both passes start at rest, so in the lifted domain ``Q = H^T H`` (``H`` the filter's lower
    triangular Toeplitz matrix): symmetric, with ``||Q|| <= max |H|^2 = 1``, which the
    convergence argument needs. ``cutoff_Hz`` at or above Nyquist leaves ``x`` as it is.
    """
    nyquist = 0.5 / dt_s
    if cutoff_Hz >= nyquist:
        return np.asarray(x, float).copy()
    from scipy.signal import butter, lfilter  # scipy.signal loads when a filter is first made, not on import

    b, a = butter(order, cutoff_Hz / nyquist)
    forward = lfilter(b, a, np.asarray(x, float), axis=-1)
    return np.asarray(lfilter(b, a, forward[..., ::-1], axis=-1)[..., ::-1], float)



# --------------------------------------------------------------------------------------
# the loop, linearised
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class LoopLinearisation:
    """The loop from ``ff_extra`` to the force and the command, linearised at rest at ``voltage_V``.

    ``x+ = A x + B u``; the force ``C x`` (read before the command is written, so the first
    response is a sample late), the command ``Cu x + Du u``, the amplifier's voltage ``Cv x``. ``E`` is the start
    state's change per
    volt of the first sample's ``ff_extra`` (the controller's bumpless start: its integral takes it
    up). ``force_N`` is the force at rest there.
    """

    A: Array
    B: Array
    C: Array
    Cu: Array
    Du: float
    Cv: Array
    E: Array
    voltage_V: float
    force_N: float


def _loop_of(params: Plant, controller: Controller) -> tuple[LoopModel, Controller]:
    """The loop the learning model linearises (the PID with its gain schedule, if any; no feedforward)."""
    c = Controller(controller.gains, controller.dt_s, None)
    return tuning_loop(params, schedule_size=c.model.schedule_size), c


def linearise_loop(params: Plant, controller: Controller, voltages_V: Any) -> list[LoopLinearisation]:
    """The loop of ``controller`` on the plant ``params`` linearised at rest at each of ``voltages_V``.

    One CasADi function of the step's Jacobians serves every voltage; the rest state at each
    voltage is the loop's own (:meth:`~piezopreload.models.loop.LoopModel.start`, creep settled,
    the controller's setpoint at the force there).
    """
    if params.batch_shape:
        raise InputError("linearise_loop: give one plant, not a batch (Plant.take(i) picks one)")
    v = np.atleast_1d(np.asarray(voltages_V, float))
    if v.size == 0 or not np.all(np.isfinite(v)):
        raise InputError(f"voltages_V: give finite voltages to linearise the loop at, got {voltages_V!r}")
    loop, c = _loop_of(params, controller)
    plant_p = loop.plant.parameters(params)
    p = loop.parameters(plant_p, c.parameter_vector())
    step = step_function(loop)
    x, u, r = ca.SX.sym("x", loop.state.size), ca.SX.sym("u"), ca.SX.sym("r")
    x_next, y = step(x, p, r, 0.0, u)
    jac = ca.Function("pp_learning_jacobians", [x, r, u], [ca.jacobian(x_next, x), ca.jacobian(x_next, u),
                                                           ca.jacobian(y[0], x), ca.jacobian(y[2], x),
                                                           ca.jacobian(y[2], u), ca.jacobian(y[3], x)])
    out = []
    for v0 in v:
        rest = loop.start(NUMPY, p, 0.0, 0.0, float(v0))
        f0 = float(np.asarray(loop.plant.force(NUMPY, plant_p, rest[: loop.plant.state.size])))
        x0 = np.asarray(loop.start(NUMPY, p, f0, 0.0, float(v0)), float)
        start = np.asarray(loop.start(NUMPY, p, f0, 1.0, float(v0)), float) - x0  # linear in ff_extra: exact
        A, B, C, Cu, Du, Cv = (np.asarray(m, float) for m in jac(x0, f0, 0.0))
        out.append(LoopLinearisation(A, B[:, 0], C[0], Cu[0], float(Du[0, 0]), Cv[0], start, float(v0), f0))
    return out


@dataclass(frozen=True, eq=False)
class LearningModel:
    """The closed loop from ``ff_extra`` to the force, linear, and the learning laws' settings.

    ``A, B, C`` are its state space (``x+ = A x + B u``, force ``C x``: read before the command
    is written, so the first response is a sample late); ``g`` its impulse response (N/V).
    The P-type law learns through a PI-shaped filter ``F`` (``sp_gain`` and the trapezoidal
    integral ``sp_integral_per_s``, the PID's ``Kc / Ti``: at low frequency the loop passes ``F u``
    to the force as it passes a setpoint, where ``ff_extra`` alone is rejected by the integral);
    ``delta`` and ``gamma`` set its lead and gain, ``q_cutoff_Hz`` its filter. ``u_range_V`` is the
    command's range (no learning where the command sat at a limit).
    """

    A: Array
    B: Array
    C: Array
    dt_s: float
    delta: int = 1
    gamma: float = 1.0
    q_cutoff_Hz: float = np.inf
    u_range_V: tuple[float, float] = (-np.inf, np.inf)
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
        resolvent = np.linalg.solve(z[:, None, None] * np.eye(n) - self.A,
                                    np.broadcast_to(self.B, (z.size,) + self.B.shape))
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
        G = (self if loop is None
             else replace(self, A=loop.A, B=loop.B, C=loop.C)).frequency_response(omega, learning=True)
        return float(np.max(self.q_response(omega) * np.abs(1.0 - self.gamma * lead * G)))

    def update(self, u: Array, e: Array, command_V: Array | None = None, voltage_V: Array | None = None) -> Array:
        """The next trial's signal, :func:`p_type_update` (the laws' interface; the command and voltage unused)."""
        return p_type_update(self, u, e)

    def to_dict(self) -> dict[str, Any]:
        return {"law": "p-type", "delta_samples": self.delta, "gamma": self.gamma, "q_cutoff_Hz": self.q_cutoff_Hz,
                "contraction": self.contraction(), "contraction_over_range": self.range_contraction,
                "range_V": None if self.range_V is None else list(self.range_V)}



def learning_model(params: Plant, controller: Controller, *, v0_V: float = 50.0,
                   q_cutoff_Hz: float | None = None) -> LearningModel:
    """The P-type law's model of a controller on a rig: the loop linearised at rest at ``v0_V``
    (:func:`linearise_loop`), the law's settings from it (:func:`tune_laws`)."""
    return _tuned(params, controller, linearise_loop(params, controller, [v0_V])[0], q_cutoff_Hz)


def _tuned(params: Plant, controller: Controller, lin: LoopLinearisation, q_cutoff_Hz: float | None) -> LearningModel:
    gains = controller.gains
    dt = params.sample_period_s
    ki = 0.0 if not np.isfinite(gains.Ti_s) else gains.Kc / gains.Ti_s
    base = LearningModel(lin.A, lin.B[:, None], lin.C[None, :], dt, u_range_V=(gains.u_min_V, gains.u_max_V),
                         sp_gain=gains.Kc * gains.b, sp_integral_per_s=ki)
    return tune_laws(base, q_cutoff_Hz=q_cutoff_Hz)


def learning_model_over(params: Plant, controller: Controller, voltages_V: Any = None, *, v0_V: float = 50.0,
                        q_cutoff_Hz: float | None = None) -> LearningModel:
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
        voltages_V = np.linspace(max(gains.u_min_V, 0.0), gains.u_max_V, 5)
    v = np.unique(np.asarray(voltages_V, float).ravel())
    lins = linearise_loop(params, controller, np.concatenate([v, [v0_V]]))
    loops = [_tuned(params, controller, lin, q_cutoff_Hz) for lin in lins[:-1]]
    candidates = [_tuned(params, controller, lins[-1], q_cutoff_Hz)]
    worst = [max(candidates[0].contraction(loop=lp) for lp in loops)]
    if worst[0] >= 1.0:  # the nominal law does not hold over the range: the law of each level, its worst case least
        candidates += loops
        worst += [max(c.contraction(loop=lp) for lp in loops) for c in loops]
    k = int(np.argmin(worst))
    return replace(candidates[k], range_contraction=float(worst[k]), range_V=(float(v[0]), float(v[-1])))


def tune_laws(model: LearningModel, *, q_cutoff_Hz: float | None = None) -> LearningModel:
    """The P-type law's filter, lead, gain and Q from ``model``'s response.

    The learning filter is PI-shaped, ``F = k_p + k_i`` (trapezoidal integral), ``k_i`` the PID's
    ``Kc / Ti`` (so the law's low frequencies pass as a setpoint does) and ``k_p`` searched from the
    PID's ``Kc b`` up; for each, ``delta`` is the peak of the response through ``F`` and ``gamma``
    half the largest gain with ``|1 - gamma e^{j w delta} G F| <= 1`` at every frequency (a gain
    margin of 2, for the plants' spread and the hysteresis' slope). The ``k_p`` kept makes
    ``|1 - L G|`` smallest on average over 0.1-50 Hz. ``q_cutoff_Hz`` (when not given) is the
    highest frequency where ``|1 - L G| <= 0.95``: above it the law learns next to nothing and Q
    keeps the noise out.
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
    return replace(tuned, q_cutoff_Hz=float(q_cutoff_Hz))



def p_type_update(model: LearningModel, u: Array, e: Array) -> Array:
    """``Q (u + gamma F e(t + delta))`` along the last axis (a batch of plants in the leading ones)."""
    step = model.gamma * model.setpoint_path(advance(e, model.delta, fill="zero"))
    return zero_phase_lowpass(np.asarray(u, float) + step, model.q_cutoff_Hz, model.dt_s)


