"""PID tuning with CasADi around the P-I-compensated plant.

The plant the PID sees is the rig with the identified inverse-P-I feedforward in front: the
feedforward turns the reference into a voltage, the PID adds its correction, and what is left
for the feedback to do is the model error (hysteresis residual, creep, the amplifier's lag and
slew, the delay). :func:`tune_pid` finds ``Kc, Ti, Td, Tf`` (and optionally the setpoint weight)
that minimise a time-weighted absolute error (the weight ramps up over ``TuningSpec.ramp_s``
after each change of the reference) over the paper's step and trajectory on several plant
variants at once, subject to

* no overshoot of the step beyond the error band (kept a margin inside it, for the sensor
  noise), on every variant;
* a maximum sensitivity ``Ms`` of the linearised loop on a frequency grid (Astrom-Hagglund
  MIGO; Garpinger-Hagglund), per variant and at both ends of the hysteresis' local slope;
* a bound on the controller's gain at the Nyquist frequency (noise amplification).

The command stays inside its range because the tuning model clamps it as the controller
does (with its conditional integration): the loop in the NLP is
:func:`~piezopreload.models.controller.pid_update`, the same function the simulation and the
generated C code run. The closed loop is unrolled over the references (single shooting with
``mapaccum``), so IPOPT gets exact first and second derivatives with respect to the gains;
every constraint family enters as one smooth maximum (Kreisselmeier-Steinhauser) per
variant, so the NLP has five variables and some twenty constraints.

The tuning model (:func:`tuning_step`) is the rig of :mod:`piezopreload.models.actuator` with
the Bouc-Wen ``|.|`` smoothed through ``sqrt(x^2 + eps^2)`` and integrated explicitly per
sample (the rig integrates it exactly) and the slew clip's corners rounded; the output clamp
stays the controller's (a kink, active only when the command reaches its limits). No noise,
no quantisation. The validation
(:mod:`piezopreload.tuning.validate`) then runs the gains on the rig itself.

The starting point and the baseline is SIMC (Skogestad 2003) on a first-order-plus-dead-time
fit of the compensated plant's response to a voltage step.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import casadi as ca
import numpy as np
from scipy.optimize import least_squares

from piezopreload.core.errors import InfeasibleError
from piezopreload.models.actuator import Rig, RigParams
from piezopreload.models.closedloop import PAPER_BAND_N, Reference
from piezopreload.models.controller import CASADI_OPS, PIDGains, pid_update
from piezopreload.models.hysteresis import InverseClassicalPI

__all__ = [
    "TuningSpec",
    "FOPDT",
    "fit_fopdt",
    "simc",
    "tuning_step",
    "plant_variants",
    "TuningResult",
    "TuningInfeasible",
    "tune_pid",
    "loop_frequency_response",
    "minimum_time",
    "tracking_floor",
]

_EPS_ABS = 1e-3  # smoothing of |x| (V) in the Bouc-Wen rate


class TuningInfeasible(InfeasibleError):
    """The specification cannot be met; the message names the binding constraints."""


@dataclass(frozen=True)
class TuningSpec:
    """What the tuned loop must do.

    Parameters
    ----------
    band_N : float
        Error band of the settling time (the paper's 1.5 N).
    overshoot_margin_N : float
        The noise-free response stays this far inside the band (the sensor noise needs room).
    ms_max : float
        Maximum sensitivity of the linearised loop.
    noise_gain_max_V_per_N : float
        Bound on the controller's gain at the Nyquist frequency: sensor noise of ``s`` N rms
        reaches the command as at most ``s * bound`` V rms at high frequency.
    u_min_V, u_max_V : float
        Output range of the controller.
    step, trajectory : Reference
        The references the loop is tuned over (short holds: the settling happens early).
    tune_setpoint_weight : bool
        Whether ``b`` is a decision variable in ``[0, 1]`` (else 1, as LabVIEW). With the
        feedforward following the setpoint, a small ``b`` keeps the proportional action from
        kicking the command into its limit at a step.
    Tf_ratio_min : float
        Lower bound on ``Tf / Td`` (a derivative filter no faster than ``Td / 20`` by default).
    ramp_s : float
        The error's weight in the objective ramps from 0 at each change of the reference to 1
        after ``ramp_s``: the transport right after a jump (which no gains remove, see
        :func:`minimum_time`) counts little, the error the loop leaves after it counts fully.
    variants : dict
        Relative spread of the plant variants (see :func:`plant_variants`).
    """

    band_N: float = PAPER_BAND_N
    overshoot_margin_N: float = 0.6
    ms_max: float = 1.6
    noise_gain_max_V_per_N: float = 8.0
    u_min_V: float = 0.0
    u_max_V: float = 110.0
    step: Reference = field(default_factory=lambda: Reference.step(25.0, 60.0, 0.02, 0.6))
    trajectory: Reference = field(
        default_factory=lambda: Reference.staircase(25.0, [60.0, 80.0, 100.0, 80.0, 60.0], 0.4, t_start_s=0.02)
    )
    tune_setpoint_weight: bool = True
    Tf_ratio_min: float = 0.05
    ramp_s: float = 0.1
    variants: dict[str, float] = field(
        default_factory=lambda: {"gain": 0.15, "amp_bandwidth_Hz": 0.2, "slew": 0.2, "hysteresis": 0.2, "creep": 0.3}
    )

    def __post_init__(self) -> None:
        if not (0 < self.overshoot_margin_N < self.band_N):
            raise ValueError("TuningSpec needs 0 < overshoot_margin_N < band_N.")
        if not self.ms_max > 1.0:
            raise ValueError("TuningSpec.ms_max must be > 1.")
        if not self.noise_gain_max_V_per_N > 0:
            raise ValueError("TuningSpec.noise_gain_max_V_per_N must be > 0.")
        if not self.u_min_V < self.u_max_V:
            raise ValueError("TuningSpec needs u_min_V < u_max_V.")
        if not self.ramp_s > 0:
            raise ValueError("TuningSpec.ramp_s must be > 0.")


# --------------------------------------------------------------------------------------
# the plant variants
# --------------------------------------------------------------------------------------
def plant_variants(params: RigParams, spread: dict[str, float]) -> list[RigParams]:
    """The nominal plant and the corners that bound it: low/high gain with a slow/fast amplifier.

    ``spread`` gives relative changes: ``gain`` (coupling stiffness), ``amp_bandwidth_Hz``,
    ``slew`` (amplifier current limit), ``hysteresis`` (Bouc-Wen ``alpha``: the loop's width,
    so the feedforward's residual) and ``creep``. Four corners pair the changes that make the
    loop slower (less gain, bandwidth and slew, more hysteresis and creep) and faster.
    """
    unknown = set(spread) - {"gain", "amp_bandwidth_Hz", "slew", "hysteresis", "creep"}
    if unknown:
        raise ValueError(f"unknown variant spread {sorted(unknown)}")
    s = {k: float(spread.get(k, 0.0)) for k in ("gain", "amp_bandwidth_Hz", "slew", "hysteresis", "creep")}

    def corner(gain: float, amp: float, slew: float, hyst: float, creep: float) -> RigParams:
        return replace(
            params,
            coupling_stiffness_N_per_um=params.coupling_stiffness_N_per_um * (1 + gain * s["gain"]),
            amp_bandwidth_Hz=params.amp_bandwidth_Hz * (1 + amp * s["amp_bandwidth_Hz"]),
            amp_current_limit_A=params.amp_current_limit_A * (1 + slew * s["slew"]),
            bw_alpha=params.bw_alpha * (1 + hyst * s["hysteresis"]),
            creep_per_decade=params.creep_per_decade * (1 + creep * s["creep"]),
        )

    return [
        params,
        corner(-1, -1, -1, +1, +1),  # sluggish, most model error
        corner(+1, +1, +1, -1, -1),  # fast
        corner(+1, -1, -1, +1, -1),  # high gain, slow amplifier: the least phase margin
        corner(-1, +1, +1, -1, +1),
    ]


# --------------------------------------------------------------------------------------
# SIMC from a first-order-plus-dead-time fit
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FOPDT:
    """``K exp(-theta s) / (T s + 1)``: gain (N/V), time constant and dead time (s)."""

    K: float
    T_s: float
    theta_s: float
    rms_N: float


def fit_fopdt(rig: Rig, feedforward: InverseClassicalPI, *, level_N: float = 60.0, step_V: float = 5.0,
              window_s: float = 0.5) -> FOPDT:
    """Fit a FOPDT model to the compensated plant's response to a ``step_V`` voltage step.

    The feedforward holds the rig at ``level_N`` (from rest, approached as the step reference
    would), then the PID's output steps by ``step_V``; the noise-free force over ``window_s``
    is fitted by least squares.
    """
    dt = rig.dt_s
    settle = int(round(1.0 / dt))
    n = int(round(window_s / dt))
    ff_state = feedforward.initial_state()
    v_ff, ff_state = feedforward.step(ff_state, np.array(level_N))
    state = rig.initial_state()
    for _ in range(settle):
        state = rig.step(state, v_ff)
    f0 = float(rig.force(state))
    y = np.empty(n)
    for k in range(n):
        y[k] = float(rig.force(state)) - f0
        state = rig.step(state, v_ff + step_V)
    t = np.arange(n) * dt
    # the creep still drifting from the approach is part of the response here; it is slow
    # against the window, so the fit's rms says how well a FOPDT describes the fast part

    def fit(theta: float) -> Any:
        def residual(x: np.ndarray) -> np.ndarray:
            K, T = x
            return step_V * K * np.where(t > theta, -np.expm1(-(t - theta) / T), 0.0) - y
        return least_squares(residual, [max(y[-1] / step_V, 1e-3), 0.01], bounds=([1e-6, 1e-4], [np.inf, 10.0]))

    # the dead time by a fine grid (the residual is not smooth in it), K and T by least squares;
    # no shorter than the loop's known transport delay (the delay samples plus half a sample
    # for the hold), which the creep's fast lag would otherwise let the fit trade for a longer T
    theta_min = (rig.params.delay_samples + 0.5) * dt
    thetas = np.arange(theta_min, theta_min + 20.0 * dt, 0.1 * dt)
    fits = [fit(th) for th in thetas]
    best = int(np.argmin([f.cost for f in fits]))
    K, T = (float(v) for v in fits[best].x)
    return FOPDT(K=K, T_s=T, theta_s=float(thetas[best]), rms_N=float(np.sqrt(np.mean(fits[best].fun**2))))


def simc(model: FOPDT, *, tau_c_s: float | None = None, u_min_V: float = 0.0, u_max_V: float = 110.0) -> PIDGains:
    """Skogestad's SIMC PI rule: ``Kc = T / (K (tau_c + theta))``, ``Ti = min(T, 4 (tau_c + theta))``.

    ``tau_c`` defaults to ``theta`` (SIMC's "tight control" choice).
    """
    tau_c = model.theta_s if tau_c_s is None else tau_c_s
    tau_c = max(tau_c, 1e-4)
    Kc = model.T_s / (model.K * (tau_c + model.theta_s))
    Ti = min(model.T_s, 4.0 * (tau_c + model.theta_s))
    return PIDGains(Kc=Kc, Ti_s=Ti, Td_s=0.0, Tf_s=0.0, u_min=u_min_V, u_max=u_max_V)


# --------------------------------------------------------------------------------------
# the smooth tuning model of the compensated loop
# --------------------------------------------------------------------------------------
_PLANT_FIELDS = (
    "bolt_preload_N", "keff", "amp_a", "slew", "stroke_um_per_V", "bw_alpha", "bw_beta_per_V",
    "bw_gamma_per_V", "bw_kappa", "creep_per_decade",
)


def _plant_vector(params: RigParams) -> tuple[np.ndarray, np.ndarray]:
    """Numeric plant parameters for :func:`tuning_step` and the creep decays."""
    p, dt = params, params.sample_period_s
    tau = 1.0 / (2.0 * np.pi * float(p.amp_bandwidth_Hz))
    values = {
        "bolt_preload_N": float(p.bolt_preload_N),
        "keff": float(p.effective_stiffness_N_per_um),
        "amp_a": float(np.exp(-dt / tau)),
        "slew": float(p.slew_V_per_s) * dt,
        "stroke_um_per_V": float(p.stroke_um_per_V),
        "bw_alpha": float(p.bw_alpha),
        "bw_beta_per_V": float(p.bw_beta_per_V),
        "bw_gamma_per_V": float(p.bw_gamma_per_V),
        "bw_kappa": float(p.bw_kappa),
        "creep_per_decade": float(p.creep_per_decade),
    }
    return np.array([values[k] for k in _PLANT_FIELDS]), np.exp(-dt / np.asarray(p.creep_tau_s, float))


def _smooth_abs(x: Any) -> Any:
    return ca.sqrt(x * x + _EPS_ABS**2)


_CLIP_SHARPNESS = 50.0  # the smooth clip's corner is 1/50 of the limit wide


def _softplus(y: Any, k: Any) -> Any:
    """``log(1 + exp(k y)) / k`` without overflow."""
    return ca.fmax(y, 0) + ca.log1p(ca.exp(-k * ca.fabs(y))) / k


def _smooth_clip(x: Any, limit: Any) -> Any:
    """``clip(x, -limit, limit)`` with corners rounded by softplus: exact away from the corners,
    at most ``log(2) / 50`` of the limit off at them (a tanh would be a quarter off at ``x = limit``)."""
    k = _CLIP_SHARPNESS / limit
    return x - _softplus(x - limit, k) + _softplus(-x - limit, k)


def _rig_force(theta: Any, v: Any, h: Any, creep: Any, n_creep: int) -> tuple[Any, Any]:
    x = theta[4] * (v + theta[8] * v * v / 100.0 - h)
    lag = 0
    for i in range(n_creep):
        lag = lag + theta[9] * (creep[i] - x)
    return theta[0] + theta[1] * (x + lag), x


def tuning_step(n_creep: int, dt: float, delay: int, u_range: tuple[float, float] = (0.0, 110.0)) -> ca.Function:
    """One sample of the compensated closed loop as a CasADi function.

    ``(x, gains, theta, decay, r, ff) -> (x_next, y, u)``: ``x`` the loop state (rig:
    amplifier voltage, Bouc-Wen state, creep chain, pending commands; controller: integral,
    previous error, previous measurement, filtered derivative); ``gains = [Kc, Ti, Td, Tf, b]``;
    ``theta`` the plant vector; ``r`` and ``ff`` this sample's reference and feedforward. The
    controller is :func:`~piezopreload.models.controller.pid_update`, the one the rig runs
    (output clamp to ``u_range`` and conditional integration included).
    """
    nx = 2 + n_creep + delay + 4
    x = ca.SX.sym("x", nx)
    gains = ca.SX.sym("gains", 5)
    theta = ca.SX.sym("theta", len(_PLANT_FIELDS))
    decay = ca.SX.sym("decay", n_creep)
    r = ca.SX.sym("r")
    ff = ca.SX.sym("ff")
    v, h = x[0], x[1]
    creep = x[2 : 2 + n_creep]
    integral, e_prev, pv_prev, dpv = (x[2 + n_creep + delay + i] for i in range(4))
    y, _ = _rig_force(theta, v, h, creep, n_creep)
    u, _, integral_next, _, e, dpv_next = pid_update(
        CASADI_OPS, tuple(gains[i] for i in range(5)), u_range, dt, integral, e_prev, pv_prev, dpv, r, y, ff)
    # the rig: delay, amplifier (first order, slew clip), Bouc-Wen, creep
    rig_next = rig_step(x[: 2 + n_creep + delay], u, theta, decay, n_creep, delay)
    x_next = ca.vertcat(rig_next, integral_next, e, y, dpv_next)
    return ca.Function("loop_step", [x, gains, theta, decay, r, ff], [x_next, y, u],
                       ["x", "gains", "theta", "decay", "r", "ff"], ["x_next", "y", "u"])


def _rest_rig_state(params: RigParams) -> np.ndarray:
    """The rig part of the loop state at rest at 0 V: ``[v, h, creep..., pending...]``."""
    return np.zeros(2 + len(params.creep_tau_s) + params.delay_samples)


def _initial_loop_state(params: RigParams, r0: float, Kc: Any, b: Any, ff0: float) -> Any:
    """The rig at rest at 0 V and the bolt preload; the controller bumplessly at 0 V.

    As :meth:`Controller.initial_state` with ``u0 = 0``: the integral cancels the proportional
    action and the feedforward at the start. ``Kc`` and ``b`` may be CasADi symbols.
    """
    pv0 = float(params.bolt_preload_N)
    integral = -Kc * (b * r0 - pv0) - ff0
    return ca.vertcat(_rest_rig_state(params), integral, r0 - pv0, pv0, 0.0)


def _feedforward_sequence(feedforward: InverseClassicalPI | None, r: np.ndarray) -> np.ndarray:
    if feedforward is None:
        return np.zeros_like(r)
    return np.asarray(feedforward(r, feedforward.initial_state()), float)


# --------------------------------------------------------------------------------------
# the linearised loop
# --------------------------------------------------------------------------------------
def _plant_frequency_response(params: RigParams, omega: np.ndarray, gain_N_per_V: float) -> np.ndarray:
    """Small-signal response from command to measured force of the discrete rig."""
    dt = params.sample_period_s
    zi = np.exp(-1j * omega * dt)  # z^-1
    a = np.exp(-dt * 2.0 * np.pi * float(params.amp_bandwidth_Hz))
    amp = (1 - a) * zi / (1 - a * zi) * zi**params.delay_samples
    decay = np.exp(-dt / np.asarray(params.creep_tau_s, float))
    creep = 1 + float(params.creep_per_decade) * np.sum((1 - decay) / (1 - decay * zi[:, None]) - 1, axis=1)
    return gain_N_per_V * amp * creep


def _small_signal_gains(params: RigParams) -> tuple[float, float]:
    """The lowest and highest local slope dF/dV of the quasi-static loop over 0..110 V (N/V).

    Right after a reversal the Bouc-Wen state has slope ``alpha``, so the stroke's slope is
    ``1 - alpha`` (plus the asymmetry); far along a branch it approaches ``1 + 2 kappa v / 100``.
    """
    k = float(params.effective_stiffness_N_per_um) * float(params.stroke_um_per_V)
    lo = k * (1.0 - float(params.bw_alpha))
    hi = k * (1.0 + 2.0 * max(float(params.bw_kappa), 0.0) * 110.0 / 100.0)
    return lo, hi


def _controller_frequency_response(gains: Any, omega: np.ndarray, dt: float) -> tuple[Any, Any]:
    """Real and imaginary parts of the PID's feedback path ``C(e^{j w dt})`` (symbolic gains)."""
    Kc, Ti, Td, Tf = gains[0], gains[1], gains[2], gains[3]
    zi = np.exp(-1j * omega * dt)
    q = (1 + zi) / (1 - zi)  # trapezoidal integrator shape
    d = 1 - zi
    alpha = Tf / (Tf + dt)
    # D = Td (1 - alpha) / dt * d / (1 - alpha zi)
    den_re = 1 - alpha * zi.real
    den_im = -alpha * zi.imag
    den2 = den_re**2 + den_im**2
    ratio_re = (d.real * den_re + d.imag * den_im) / den2
    ratio_im = (d.imag * den_re - d.real * den_im) / den2
    kd = Td * (1 - alpha) / dt
    re = Kc * (1 + dt / (2 * Ti) * q.real + kd * ratio_re)
    im = Kc * (dt / (2 * Ti) * q.imag + kd * ratio_im)
    return re, im


def loop_frequency_response(gains: PIDGains, params: RigParams, omega: np.ndarray, gain_N_per_V: float) -> np.ndarray:
    """The loop transfer ``C G`` at ``omega`` (rad/s), numerically, for reports and checks."""
    g = [gains.Kc, gains.Ti_s, gains.Td_s, gains.Tf_s]
    re, im = _controller_frequency_response(g, omega, params.sample_period_s)
    return (np.asarray(re) + 1j * np.asarray(im)) * _plant_frequency_response(params, omega, gain_N_per_V)


def _omega_grid(dt: float, n: int = 160) -> np.ndarray:
    return np.logspace(np.log10(2 * np.pi * 0.05), np.log10(0.999 * np.pi / dt), n)


# --------------------------------------------------------------------------------------
# the NLP
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class TuningResult:
    gains: PIDGains
    baseline: PIDGains
    fopdt: FOPDT
    objective: float
    status: str
    iterations: int
    seconds: float
    ms: float
    binding: list[str]
    constraint_margins: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        return {
            "status": self.status, "iterations": self.iterations, "seconds": self.seconds,
            "objective": self.objective, "ms": self.ms, "binding": self.binding,
            "constraint_margins": self.constraint_margins,
            "fopdt": {"K_N_per_V": self.fopdt.K, "T_s": self.fopdt.T_s, "theta_s": self.fopdt.theta_s,
                      "rms_N": self.fopdt.rms_N},
        }


# the search box: log scale for the times and the gain, linear for the setpoint weight
_LOG_BOUNDS = {"Kc": (1e-3, 50.0), "Ti": (2e-3, 5.0), "Td": (1e-5, 0.05), "Tf": (1e-5, 0.5)}
_B_BOUNDS = (0.0, 1.0)


class _Scaling:
    """Decision variables ``z`` in the unit box <-> gains."""

    def __init__(self, names: list[str]) -> None:
        self.names = names

    def value(self, name: str, zi: Any) -> Any:
        if name == "b":
            if isinstance(zi, float | np.floating):
                zi = min(max(zi, 0.0), 1.0)  # IPOPT may end a hair outside its bounds
            return _B_BOUNDS[0] + zi * (_B_BOUNDS[1] - _B_BOUNDS[0])
        lo, hi = np.log(_LOG_BOUNDS[name])
        return np.exp(lo + zi * (hi - lo)) if isinstance(zi, float | np.floating) else ca.exp(lo + zi * (hi - lo))

    def z(self, name: str, x: float) -> float:
        if name == "b":
            return float(np.clip((x - _B_BOUNDS[0]) / (_B_BOUNDS[1] - _B_BOUNDS[0]), 0, 1))
        lo, hi = np.log(_LOG_BOUNDS[name])
        return float(np.clip((np.log(max(x, 1e-12)) - lo) / (hi - lo), 0, 1))

    def gains(self, z: np.ndarray, spec: TuningSpec) -> PIDGains:
        x = {n: float(self.value(n, float(z[i]))) for i, n in enumerate(self.names)}
        return PIDGains(Kc=x["Kc"], Ti_s=x["Ti"], Td_s=x["Td"], Tf_s=x["Tf"], b=x.get("b", 1.0),
                        u_min=spec.u_min_V, u_max=spec.u_max_V)


def _seeds(names: list[str], scaling: _Scaling, baseline: PIDGains) -> np.ndarray:
    """Starting points: the SIMC baseline and a coarse grid around the box's middle."""
    pts = [[scaling.z(n, {"Kc": baseline.Kc, "Ti": baseline.Ti_s, "Td": 1e-4, "Tf": 1e-4, "b": 1.0}[n]) for n in names]]
    grid = {"Kc": [0.3, 1.0, 3.0], "Ti": [0.02, 0.05, 0.15], "Td": [1e-4], "Tf": [1e-4], "b": [0.0, 0.5]}
    axes = [[scaling.z(n, v) for v in grid[n]] for n in names]
    pts += [list(p) for p in np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(names), -1).T]
    return np.array(pts)


def _smooth_max(g: Any, rho: float) -> Any:
    """Kreisselmeier-Steinhauser smooth maximum of the entries of ``g``: an upper bound.

    ``max(g) <= KS(g) <= max(g) + log(n) / rho``; in practice only the entries within a few
    ``1/rho`` of the maximum add anything, so the bound is tight where it matters.
    """
    m = ca.mmax(g)
    return m + ca.log(ca.sum1(ca.vec(ca.exp(rho * (g - m))))) / rho


_RHO_OVERSHOOT = 40.0  # 1/N: at most log(n)/40 ~ 0.16 N conservative, ~0.02 N in practice
_RHO_MS = 400.0  # on |1 + L|^2


@dataclass(frozen=True, eq=False)
class _Problem:
    """The tuning NLP: decision variables ``z`` in the unit box, objective and labelled constraints ``<= 0``."""

    z: Any
    names: list[str]
    scaling: _Scaling
    variants: list[RigParams]
    objective: Any
    labels: list[str]
    g: Any


def _build_problem(params: RigParams, feedforward: InverseClassicalPI | None, spec: TuningSpec) -> _Problem:
    dt = params.sample_period_s
    variants = plant_variants(params, spec.variants)
    step_fn = tuning_step(len(params.creep_tau_s), dt, params.delay_samples, (spec.u_min_V, spec.u_max_V))
    names = ["Kc", "Ti", "Td", "Tf"] + (["b"] if spec.tune_setpoint_weight else [])
    scaling = _Scaling(names)
    z = ca.MX.sym("z", len(names))
    vals = {n: scaling.value(n, z[i]) for i, n in enumerate(names)}
    b = vals.get("b", 1.0)
    gains = ca.vertcat(vals["Kc"], vals["Ti"], vals["Td"], vals["Tf"], b)

    objective = 0
    blocks: list[tuple[str, Any]] = [  # (label, g): g <= 0 required
        (f"derivative filter Tf >= {spec.Tf_ratio_min:g} Td", spec.Tf_ratio_min * vals["Td"] - vals["Tf"])]
    band_lim = spec.band_N - spec.overshoot_margin_N
    for ref_name, ref in (("step", spec.step), ("trajectory", spec.trajectory)):
        n = int(round(ref.duration_s / dt)) + 1
        t = np.arange(n) * dt
        r = ref.at(t)
        ff = _feedforward_sequence(feedforward, r)
        # time since the last change of the reference, and the direction of that change
        k_change = np.searchsorted(ref.times_s, t, side="right") - 1
        t_since = t - ref.times_s[k_change]
        prev_level = np.where(k_change > 0, ref.levels_N[np.maximum(k_change - 1, 0)], ref.levels_N[0])
        direction = np.sign(r - prev_level)
        weights = np.minimum(t_since / spec.ramp_s, 1.0) * dt / ref.duration_s
        roll = step_fn.mapaccum(n)
        over = np.flatnonzero(direction != 0)
        for j, variant in enumerate(variants):
            theta, decay = _plant_vector(variant)
            x0 = _initial_loop_state(variant, float(r[0]), vals["Kc"], b, float(ff[0]))
            _, ys, _ = roll(x0, ca.repmat(gains, 1, n), ca.repmat(theta, 1, n), ca.repmat(decay, 1, n),
                            r[None, :], ff[None, :])
            e = r[None, :] - ys
            objective = objective + ca.sum2(weights[None, :] * ca.sqrt(e * e + 1e-4)) / len(variants)
            if ref_name == "step":  # (the trajectory's top is out of reach of the weakest variants)
                overshoot = direction[over][None, :] * (ys[:, over] - r[None, over])
                blocks.append((f"overshoot inside {band_lim:g} N, step, variant {j}",
                               _smooth_max(overshoot, _RHO_OVERSHOOT) - band_lim))

    # robustness of the linearised loop, per variant and at both ends of the local slope
    omega = _omega_grid(dt)
    c_re, c_im = _controller_frequency_response(gains, omega, dt)
    for j, variant in enumerate(variants):
        for slope in _small_signal_gains(variant):
            G = _plant_frequency_response(variant, omega, slope)
            l_re = c_re * G.real - c_im * G.imag
            l_im = c_re * G.imag + c_im * G.real
            distance2 = (1 + l_re) ** 2 + l_im**2  # |1 + L|^2 >= 1 / Ms^2
            blocks.append((f"Ms <= {spec.ms_max:g}, variant {j}, slope {slope:.3f} N/V",
                           spec.ms_max**2 * _smooth_max(-distance2, _RHO_MS) + 1.0))
    re_ny, im_ny = _controller_frequency_response(gains, np.array([np.pi / dt]), dt)
    blocks.append((f"controller gain at Nyquist <= {spec.noise_gain_max_V_per_N:g} V/N",
                   ca.sqrt(re_ny**2 + im_ny**2 + 1e-12) / spec.noise_gain_max_V_per_N - 1.0))
    return _Problem(z=z, names=names, scaling=scaling, variants=variants, objective=objective,
                    labels=[label for label, _ in blocks], g=ca.vertcat(*[blk for _, blk in blocks]))


def tune_pid(
    params: RigParams,
    feedforward: InverseClassicalPI | None,
    spec: TuningSpec = TuningSpec(),
    *,
    max_iterations: int = 150,
    starts: int = 3,
    verbose: bool = False,
    progress: Callable[[int], None] | None = None,
) -> TuningResult:
    """Tune ``Kc, Ti, Td, Tf`` (and ``b``) on the compensated plant; see the module docstring.

    Every constraint family is one smooth maximum (per reference and variant for the
    overshoot, per variant and slope for Ms), so the NLP has a few dozen constraints and
    IPOPT runs with the exact Hessian. The NLP starts from the best of a few seeds (the SIMC
    baseline and a coarse grid) by constraint violation and then objective; a start that
    violates a constraint first minimises the violation (a phase-one problem), then the
    objective. Raises :class:`TuningInfeasible` naming the violated constraints when no start
    ends feasible. ``progress``, if given, is called with the count of IPOPT iterations so far
    (all starts and phases) at every iteration.
    """
    t0 = time.perf_counter()
    rig = Rig(params)
    fopdt = fit_fopdt(rig, feedforward if feedforward is not None else _ZeroFF())
    baseline = simc(fopdt, u_min_V=spec.u_min_V, u_max_V=spec.u_max_V)
    prob = _build_problem(params, feedforward, spec)
    z, g = prob.z, prob.g
    evaluate = ca.Function("evaluate", [z], [prob.objective, g])
    options = {
        # the slew clip and the output clamp are kinks: the dual infeasibility stalls near 1e-3
        # while the objective no longer moves, so stop on that
        "ipopt.max_iter": max_iterations, "ipopt.tol": 1e-6, "ipopt.acceptable_tol": 1e-2,
        "ipopt.acceptable_iter": 5, "ipopt.acceptable_obj_change_tol": 1e-4,
        "ipopt.print_level": 5 if verbose else 0, "print_time": False, "ipopt.sb": "yes",
    }
    counters = []
    if progress is not None:
        done = [0]

        def tick() -> None:
            done[0] += 1
            progress(done[0])

        counters = [_IterationCounter(z.numel(), g.numel(), tick), _IterationCounter(z.numel() + 1, g.numel(), tick)]
    solver = ca.nlpsol("tune", "ipopt", {"x": z, "f": prob.objective, "g": g},
                       {**options, **({"iteration_callback": counters[0]} if counters else {})})
    # phase one: the least violation, with a slack s >= max(g)
    slack = ca.MX.sym("s")
    phase_one = ca.nlpsol("tune_phase_one", "ipopt", {"x": ca.vertcat(z, slack), "f": slack, "g": g - slack},
                          {**options, "ipopt.tol": 1e-8, **({"iteration_callback": counters[1]} if counters else {})})

    def score(zv: np.ndarray) -> tuple[float, float]:
        """The worst constraint violation (0 if feasible) and the objective."""
        f, gv = evaluate(zv)
        return float(np.max(np.asarray(gv, float), initial=0.0)), float(f)

    seeds = _seeds(prob.names, prob.scaling, baseline)
    scores = [score(sd) for sd in seeds]
    order = sorted(range(len(seeds)), key=lambda i: (round(scores[i][0], 3), scores[i][1]))
    best: tuple[bool, float, np.ndarray, float, str] | None = None
    iterations = 0
    for i in order[:starts]:
        x0 = seeds[i]
        if scores[i][0] > 0:
            sol = phase_one(x0=np.append(x0, scores[i][0]), lbx=np.append(np.zeros(len(x0)), -np.inf),
                            ubx=np.append(np.ones(len(x0)), np.inf), lbg=-np.inf, ubg=0.0)
            iterations += int(phase_one.stats().get("iter_count", 0))
            x0 = np.clip(np.asarray(sol["x"], float).ravel()[:-1], 0.0, 1.0)
        sol = solver(x0=x0, lbx=0.0, ubx=1.0, lbg=-np.inf, ubg=0.0)
        stats = solver.stats()
        iterations += int(stats.get("iter_count", 0))
        zv = np.clip(np.asarray(sol["x"], float).ravel(), 0.0, 1.0)
        worst, f = score(zv)
        # feasible beats infeasible; among feasible the lower objective, among infeasible the
        # smaller violation (what the error message then reports)
        infeasible = worst > 1e-4
        candidate = (infeasible, worst if infeasible else f, zv, f, str(stats.get("return_status", "unknown")))
        if best is None or candidate[:2] < best[:2]:
            best = candidate
        if not infeasible:
            break
    assert best is not None
    _, _, zv, objective, status = best
    margins = dict(zip(prob.labels, (float(x) for x in np.asarray(evaluate(zv)[1], float).ravel())))
    binding = sorted(label for label, m in margins.items() if m > -1e-3)
    binding += [f"{name} at the {'lower' if zv[i] < 0.5 else 'upper'} end of its search range"
                for i, name in enumerate(prob.names) if min(zv[i], 1.0 - zv[i]) < 1e-4 and name != "b"]
    violated = sorted(((m, label) for label, m in margins.items() if m > 1e-4), reverse=True)
    if violated:
        detail = "; ".join(f"{label} (by {m:.3g})" for m, label in violated[:5])
        raise TuningInfeasible(f"PID tuning found no gains that meet the specification ({status}, {starts} starts); "
                               f"not met: {detail}. Relax those limits or the plant variants' spread.")
    tuned = prob.scaling.gains(zv, spec)
    ms = max(_max_sensitivity(tuned, v) for v in prob.variants)
    return TuningResult(
        gains=tuned, baseline=baseline, fopdt=fopdt, objective=objective, status=status,
        iterations=iterations, seconds=time.perf_counter() - t0, ms=ms, binding=binding,
        constraint_margins=margins,
    )


class _IterationCounter(ca.Callback):
    """CasADi's ``iteration_callback`` for an NLP with ``nx`` variables and ``ng`` constraints: calls ``tick()``."""

    def __init__(self, nx: int, ng: int, tick: Callable[[], None]) -> None:
        ca.Callback.__init__(self)
        self.nx, self.ng, self.tick = nx, ng, tick
        self.construct("iteration_counter", {})

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return "ret"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.scalar()
        if name in ("x", "lam_x"):
            return ca.Sparsity.dense(self.nx)
        if name in ("g", "lam_g"):
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)

    def eval(self, arg: list[Any]) -> list[Any]:
        self.tick()
        return [0]


def _max_sensitivity(gains: PIDGains, params: RigParams) -> float:
    omega = _omega_grid(params.sample_period_s, 2000)
    return max(float(np.max(1.0 / np.abs(1.0 + loop_frequency_response(gains, params, omega, s))))
               for s in _small_signal_gains(params))


class _ZeroFF:
    """No feedforward: the plant seen by the PID alone."""

    def initial_state(self, batch: tuple[int, ...] = ()) -> np.ndarray:
        return np.zeros(batch + (1,))

    def step(self, state: np.ndarray, target: Any) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros(np.shape(target)), state


# --------------------------------------------------------------------------------------
# the lower bound: minimum-time step
# --------------------------------------------------------------------------------------
def minimum_time(
    params: RigParams,
    *,
    initial_N: float = 25.0,
    final_N: float = 60.0,
    band_N: float = PAPER_BAND_N,
    hold_s: float = 0.3,
    u_min_V: float = 0.0,
    u_max_V: float = 110.0,
    horizon_s: float = 0.4,
) -> dict[str, Any]:
    """The shortest settling time any controller could give on this plant: an optimal control problem.

    The command sequence is free (no controller structure, perfect knowledge of the noise-free
    tuning model) within ``[u_min, u_max]``, through the same delay, amplifier bandwidth and
    slew limit; the force must enter the band at sample ``N`` and stay in it for ``hold_s``.
    The smallest feasible ``N`` is found by bisection, each candidate a feasibility NLP
    (CasADi Opti, IPOPT).
    """
    dt = params.sample_period_s
    n_creep = len(params.creep_tau_s)
    theta, decay = _plant_vector(params)
    x_rig0 = _rest_rig_state(params)
    n_hold = int(round(hold_s / dt))

    x = ca.SX.sym("x", x_rig0.size)
    u_sym = ca.SX.sym("u")
    f_sym, _ = _rig_force(theta, x[0], x[1], x[2 : 2 + n_creep], n_creep)
    step = ca.Function("rig", [x, u_sym], [rig_step(x, u_sym, ca.DM(theta), ca.DM(decay), n_creep, params.delay_samples), f_sym])

    def feasible(n_settle: int) -> tuple[bool, np.ndarray | None]:
        # multiple shooting: states and commands are variables, the dynamics equality constraints
        n = n_settle + n_hold
        opti = ca.Opti()
        X = opti.variable(x_rig0.size, n + 1)
        U = opti.variable(1, n)
        x_next, force = step.map(n)(X[:, :n], U)
        opti.subject_to(X[:, 0] == x_rig0)
        opti.subject_to(X[:, 1:] == x_next)
        opti.subject_to(opti.bounded(u_min_V, U, u_max_V))
        opti.subject_to(opti.bounded(final_N - band_N, force[n_settle:], final_N + band_N))
        opti.minimize(1e-4 * ca.sumsqr(ca.diff(U, 1, 1)))
        opti.set_initial(U, 0.5 * (u_min_V + u_max_V))
        opti.solver("ipopt", {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.max_iter": 500})
        try:
            sol = opti.solve()
            return True, np.atleast_1d(np.asarray(sol.value(U), float)).ravel()
        except RuntimeError:
            return False, None

    hi = int(round(horizon_s / dt))
    ok, u_best = feasible(hi)
    if not ok:
        raise TuningInfeasible(f"no command reaches {final_N:g} +/- {band_N:g} N within {horizon_s:g} s on this plant")
    lo = 0
    while hi - lo > 1:
        mid = (lo + hi) // 2
        ok, u_mid = feasible(mid)
        if ok:
            hi, u_best = mid, u_mid
        else:
            lo = mid
    return {"settling_s": hi * dt, "samples": hi, "command_V": u_best, "hold_s": hold_s}


def tracking_floor(params: RigParams, reference: Reference) -> dict[str, Any]:
    """A lower bound on the RMS tracking error of any causal controller without preview.

    After a jump of ``dF`` the force cannot move for ``delay + 1`` samples (the commands that
    decide them were sent before the jump), and then at most ``rate * dt`` per sample, where
    ``rate`` is the amplifier's slew times the steepest local slope of force over voltage
    (:func:`_small_signal_gains`; the amplifier's bandwidth, the creep lag and the hysteresis
    only slow it further). So sample ``m`` after the jump errs by at least
    ``max(dF - (m - delay) rate dt, 0)``. Summed over the reference's jumps and divided by the
    samples :meth:`ClosedLoopRun.tracking_error` scores (from the first change to the end),
    that is a floor for its RMS. Returns ``{"rms_N", "rate_N_per_s"}``.
    """
    dt, delay = params.sample_period_s, params.delay_samples
    rate = _small_signal_gains(params)[1] * float(params.slew_V_per_s)
    n = int(round(reference.duration_s / dt)) + 1
    t = np.arange(n) * dt
    k_jumps = np.searchsorted(t, reference.times_s[1:] - 1e-12)
    ends = np.append(k_jumps[1:], n)
    total = 0.0
    for j, (k, end) in enumerate(zip(k_jumps, ends)):
        jump = abs(float(reference.levels_N[j + 1] - reference.levels_N[j]))
        m = np.arange(int(end - k))
        total += float(np.sum(np.maximum(jump - np.maximum(m - delay, 0) * rate * dt, 0.0) ** 2))
    scored = int(np.sum(t >= reference.times_s[1]))
    return {"rms_N": float(np.sqrt(total / scored)), "rate_N_per_s": rate}


def rig_step(x: Any, u: Any, theta: Any, decay: Any, n_creep: int, delay: int) -> Any:
    """One sample of the smooth rig model; state ``[v, h, creep..., pending...]``, command ``u``.

    The rig of :meth:`piezopreload.models.actuator.Rig.step` with ``sqrt(x^2 + eps^2)`` for
    ``|x|``, an explicit Bouc-Wen step (the rig's is exact) and the slew clip's corners
    rounded (:func:`_smooth_clip`; a hard clip leaves the objective full of small kinks that
    stall IPOPT near the optimum).
    """
    v, h = x[0], x[1]
    creep = x[2 : 2 + n_creep]
    pending = x[2 + n_creep : 2 + n_creep + delay]
    if delay:
        applied = pending[0]
        pending_next = ca.vertcat(pending[1:delay], u) if delay > 1 else u  # (a 1x1 [1:] is not empty)
    else:
        applied, pending_next = u, pending
    dv = _smooth_clip((applied - v) * (1 - theta[2]), theta[3])
    v_next = v + dv
    h_next = h + theta[5] * dv - theta[6] * _smooth_abs(dv) * h - theta[7] * dv * _smooth_abs(h)
    xs = theta[4] * (v_next + theta[8] * v_next * v_next / 100.0 - h_next)
    creep_next = ca.vertcat(*[xs + (creep[i] - xs) * decay[i] for i in range(n_creep)])
    return ca.vertcat(v_next, h_next, creep_next, pending_next)
