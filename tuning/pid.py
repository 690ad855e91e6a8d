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
does (with its conditional integration): the loop in the NLP is the one closed loop of
:mod:`piezopreload.models.loop` (:func:`tuning_loop`: the rig's and the controller's one step,
the same the simulation, the rig executor and the generated C code run), run over the step and
then the trajectory on one horizon (single shooting) on every plant variant; every constraint
family enters as one smooth maximum (Kreisselmeier-Steinhauser) per variant, so the NLP has
five variables and some twenty constraints, and IPOPT runs with exact first and second
derivatives.

The tuning model is that loop with its corners rounded (``smoothing``
:data:`TUNING_SMOOTHING`): the slew clip's corners, and the Bouc-Wen rate's ``|.|`` in one
explicit step per sample (see :func:`~piezopreload.models.actuator.bouc_wen_step`); the output
clamp stays the controller's (a kink, active only when the command reaches its limits). No
noise, no quantisation. The validation (:mod:`piezopreload.tuning.validate`) then runs the
gains on the exact rig.

The derivatives by the gains are carried along the simulation (forward sensitivities of the
one loop step, first and second order: :func:`_sensitivity_step`), so one pass over the horizon
gives the objective, the overshoots and their gradients and Hessians (:class:`_Horizon`,
handed to CasADi as a callback with its Jacobians). Where a C compiler works that step runs as
C, compiled once and cached (:mod:`piezopreload.core.native`); elsewhere (``engine="plain"``)
CasADi's virtual machine evaluates it: the same numbers, so the same iterates. The frequency
constraints are a small CasADi expression of the gains.

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
from scipy.optimize import minimize_scalar

from piezopreload.core import native
from piezopreload.core.errors import InfeasibleError, InputError
from piezopreload.models.actuator import PlantModel, Rig, RigParams, hertz_force
from piezopreload.models.closedloop import PAPER_BAND_N, Reference, simulate_open_loop
from piezopreload.models.controller import ControllerModel, PIDGains
from piezopreload.models.hysteresis import InverseClassicalPI
from piezopreload.models.loop import LOOP_OUTPUTS, LoopModel
from piezopreload.models.ops import CASADI, NUMPY, Layout

__all__ = [
    "TuningSpec",
    "scaled_references",
    "FOPDT",
    "fit_fopdt",
    "simc",
    "tuning_loop",
    "TUNING_SMOOTHING",
    "plant_variants",
    "TuningResult",
    "TuningInfeasible",
    "tune_pid",
    "loop_frequency_response",
    "minimum_time",
    "tracking_floor",
]

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
        Whether ``b`` is a decision variable in ``[0, 1]`` (else ``setpoint_weight``, 1 as LabVIEW). With the
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
    setpoint_weight : float
        ``b`` where it is not tuned (a gain schedule's entries share the robust set's).
    filter_s : float or None
        ``Tf`` held, not tuned (a gain schedule's entries share the robust set's derivative
        filter); None tunes it.
    force_range_N : (float, float) or None
        The measured force range the loop works in, for the linearised loop's slopes (the Ms
        constraints): a gain schedule's entry is tuned for the range around its level, where a
        Hertz coupling's force per volt is what it is there. None: the whole stroke (0-110 V).
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
    setpoint_weight: float = 1.0
    filter_s: float | None = None
    force_range_N: tuple[float, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"band_N": self.band_N, "overshoot_margin_N": self.overshoot_margin_N, "ms_max": self.ms_max,
                "noise_gain_max_V_per_N": self.noise_gain_max_V_per_N, "u_min_V": self.u_min_V, "u_max_V": self.u_max_V,
                "tune_setpoint_weight": self.tune_setpoint_weight, "variants": dict(self.variants),
                **({} if self.tune_setpoint_weight or self.setpoint_weight == 1.0 else {"b": self.setpoint_weight}),
                **({} if self.filter_s is None else {"filter_s": self.filter_s}),
                **({} if self.force_range_N is None else {"force_range_N": list(self.force_range_N)})}

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
        if self.filter_s is not None and not (np.isfinite(self.filter_s) and self.filter_s >= 0):
            raise ValueError(f"TuningSpec.filter_s must be finite and >= 0, got {self.filter_s!r}.")
        if not 0.0 <= self.setpoint_weight <= 1.0:
            raise ValueError(f"TuningSpec.setpoint_weight must be in [0, 1], got {self.setpoint_weight!r}.")
        if self.force_range_N is not None and not (len(self.force_range_N) == 2 and np.all(np.isfinite(self.force_range_N))
                                                   and self.force_range_N[0] <= self.force_range_N[1]):
            raise ValueError(f"TuningSpec.force_range_N must be (low, high) with low <= high, got {self.force_range_N!r}.")


def scaled_references(step_N: Any = None, trajectory_N: Any = None) -> dict[str, Reference]:
    """The tuning's short step and staircase at a study's force scale (``TuningSpec``'s time scale:
    0.6 s for the step, 0.4 s per level): ``step_N = (from, to)``, ``trajectory_N = (rest, levels...)``;
    None keeps the paper's."""
    out: dict[str, Reference] = {}
    if step_N is not None:
        if len(step_N) != 2:
            raise ValueError(f"tuning.step_N must be (from, to), got {list(step_N)!r}")
        out["step"] = Reference.step(float(step_N[0]), float(step_N[1]), 0.02, 0.6)
    if trajectory_N is not None:
        if len(trajectory_N) < 2:
            raise ValueError(f"tuning.trajectory_N must be the rest level and at least one level, got {list(trajectory_N)!r}")
        out["trajectory"] = Reference.staircase(float(trajectory_N[0]), [float(x) for x in trajectory_N[1:]], 0.4,
                                                t_start_s=0.02)
    return out


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
    v_ff = float(feedforward.step(feedforward.initial_state(), np.array(level_N))[0])
    command = np.concatenate([np.full(settle, v_ff), np.full(n, v_ff + step_V)])
    force = simulate_open_loop(rig, command)["force_N"]  # the true force (the noise only reaches the reading)
    y = force[settle:] - force[settle]
    t = np.arange(n) * dt
    # the creep still drifting from the approach is part of the response here; it is slow
    # against the window, so the fit's rms says how well a FOPDT describes the fast part

    def fit(theta: float) -> tuple[float, float, float, np.ndarray]:
        """``(cost, K, T, residual)`` at dead time ``theta``: K enters linearly, so for each T it is
        the least-squares one in closed form and only T is searched (variable projection)."""
        after = t > theta

        def parts(log_T: float) -> tuple[float, float, np.ndarray]:
            phi = step_V * np.where(after, -np.expm1(-(t - theta) / np.exp(log_T)), 0.0)
            K = max(float(phi @ y) / max(float(phi @ phi), 1e-300), 1e-6)
            r = K * phi - y
            return 0.5 * float(r @ r), K, r

        res = minimize_scalar(lambda log_T: parts(log_T)[0], bounds=(np.log(1e-4), np.log(10.0)), method="bounded",
                              options={"xatol": 1e-10})
        cost, K, r = parts(float(res.x))
        return cost, K, float(np.exp(res.x)), r

    # the dead time by a fine grid (the residual is not smooth in it), K and T by least squares;
    # no shorter than the loop's known transport delay (the delay samples plus half a sample
    # for the hold), which the creep's fast lag would otherwise let the fit trade for a longer T
    theta_min = (rig.params.delay_samples + 0.5) * dt
    thetas = np.arange(theta_min, theta_min + 20.0 * dt, 0.1 * dt)
    fits = [fit(th) for th in thetas]
    best = int(np.argmin([f[0] for f in fits]))
    _, K, T, residual = fits[best]
    return FOPDT(K=K, T_s=T, theta_s=float(thetas[best]), rms_N=float(np.sqrt(np.mean(residual**2))))


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
#: how round the tuning model's corners are (see :class:`~piezopreload.models.actuator.PlantModel`):
#: the slew limit's over 1/50 of the limit, the Bouc-Wen direction switch over 1 mV
TUNING_SMOOTHING = 0.02


def tuning_loop(params: RigParams, smoothing: float = TUNING_SMOOTHING, schedule_size: int = 0) -> LoopModel:
    """The loop the tuning differentiates: the rig's one step with its corners rounded
    (``smoothing``; 0 is the exact rig), the PID alone (the feedforward enters as ``ff_extra``,
    computed once from the reference; ``schedule_size`` entries of a gain schedule), the sensor
    without quantisation (and no noise given)."""
    return LoopModel(PlantModel.of(params, smoothing), ControllerModel(None, schedule_size=schedule_size))


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


def _small_signal_gains(params: RigParams, force_range_N: tuple[float, float] | None = None) -> tuple[float, float]:
    """The lowest and highest local slope dF/dV of the quasi-static loop over 0..110 V (N/V), or with a Hertz
    coupling over the measured forces ``force_range_N`` (within the stroke).

    Right after a reversal the Bouc-Wen state has slope ``alpha``, so the stroke's slope is
    ``1 - alpha`` (plus the asymmetry); far along a branch it approaches ``1 + 2 kappa v / 100``.
    """
    k = float(params.effective_stiffness_N_per_um) * float(params.stroke_um_per_V)
    k_lo = k
    if params.hertz:  # the nuts' Hertz contacts: softest at the bolts' preload, stiffest at full stroke
        x_top = float(params.stroke_um_per_V) * 110.0
        f_top = float(hertz_force(NUMPY, x_top, float(params.effective_stiffness_N_per_um),
                                  float(params.hertz_um_per_N23), float(params.hertz_preload_N)))
        f_lo, f_hi = 0.0, f_top
        if force_range_N is not None:  # the stacks' share of the measured force, inside the stroke
            bolts = float(params.bolt_preload_N)
            f_lo = min(max(force_range_N[0] - bolts, 0.0), f_top)
            f_hi = min(max(force_range_N[1] - bolts, f_lo), f_top)
        k_lo = float(params.local_stiffness_N_per_um(f_lo)) * float(params.stroke_um_per_V)
        k = float(params.local_stiffness_N_per_um(f_hi)) * float(params.stroke_um_per_V)
    lo = k_lo * (1.0 - float(params.bw_alpha))
    hi = k * (1.0 + 2.0 * max(float(params.bw_kappa), 0.0) * 110.0 / 100.0)
    return lo, hi


def _omega_terms(omega: np.ndarray, dt: float) -> np.ndarray:
    """Per frequency, the numbers the controller's response is built from: ``(q_re, q_im, d_re,
    d_im, z_re, z_im)`` with ``z = e^{-j w dt}`` (``z^-1``), ``q = (1 + z) / (1 - z)`` the
    trapezoidal integrator's shape and ``d = 1 - z`` the backward difference; shape ``(6, n)``."""
    zi = np.exp(-1j * np.asarray(omega, float) * dt)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = (1 + zi) / (1 - zi)
    d = 1 - zi
    return np.array([q.real, q.imag, d.real, d.imag, zi.real, zi.imag])


def _controller_response(gains: Any, dt: Any, w: Any) -> tuple[Any, Any]:
    """Real and imaginary parts of the PID's feedback path ``C(e^{j w dt})`` from :func:`_omega_terms`'
    numbers ``w`` (numeric or symbolic gains ``(Kc, Ti, Td, Tf)``)."""
    Kc, Ti, Td, Tf = gains[0], gains[1], gains[2], gains[3]
    q_re, q_im, d_re, d_im, z_re, z_im = (w[i] for i in range(6))
    alpha = Tf / (Tf + dt)
    # D = Td (1 - alpha) / dt * d / (1 - alpha z)
    den_re = 1 - alpha * z_re
    den_im = -alpha * z_im
    den2 = den_re**2 + den_im**2
    ratio_re = (d_re * den_re + d_im * den_im) / den2
    ratio_im = (d_im * den_re - d_re * den_im) / den2
    kd = Td * (1 - alpha) / dt
    re = Kc * (1 + dt / (2 * Ti) * q_re + kd * ratio_re)
    im = Kc * (dt / (2 * Ti) * q_im + kd * ratio_im)
    return re, im


def _controller_frequency_response(gains: Any, omega: np.ndarray, dt: float) -> tuple[Any, Any]:
    """Real and imaginary parts of the PID's feedback path ``C(e^{j w dt})`` at ``omega`` (rad/s)."""
    return _controller_response(gains, dt, _omega_terms(omega, dt))


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
    engine: str = "plain"
    compile_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {
            "status": self.status, "iterations": self.iterations, "seconds": self.seconds,
            "engine": self.engine, "compile_s": self.compile_s,
            "objective": self.objective, "ms": self.ms, "binding": self.binding,
            "constraint_margins": self.constraint_margins,
            "fopdt": {"K_N_per_V": self.fopdt.K, "T_s": self.fopdt.T_s, "theta_s": self.fopdt.theta_s,
                      "rms_N": self.fopdt.rms_N},
        }


# the search box: log scale for the times and the gain, linear for the setpoint weight
_LOG_BOUNDS = {"Kc": (1e-3, 50.0), "Ti": (2e-3, 5.0), "Td": (1e-5, 0.05), "Tf": (1e-5, 0.5)}
_B_BOUNDS = (0.0, 1.0)


class _Scaling:
    """Decision variables ``z`` in the unit box <-> gains.

    The box of ``Kc`` (:data:`_LOG_BOUNDS`) suits a plant of up to 1 N/V (the paper's rig, about
    0.7 N/V); a stiffer plant's ``Kc`` box is divided by its force per volt (``kc_scale``), so
    the box stays where the gains are (a designed preload system has some 50-200 N/V).
    """

    def __init__(self, names: list[str], kc_scale: float = 1.0) -> None:
        self.names = names
        self.bounds = {**_LOG_BOUNDS, "Kc": (_LOG_BOUNDS["Kc"][0] * kc_scale, _LOG_BOUNDS["Kc"][1] * kc_scale)}

    def value(self, name: str, zi: Any) -> Any:
        if name == "b":
            if isinstance(zi, float | np.floating):
                zi = min(max(zi, 0.0), 1.0)  # IPOPT may end a hair outside its bounds
            return _B_BOUNDS[0] + zi * (_B_BOUNDS[1] - _B_BOUNDS[0])
        lo, hi = np.log(self.bounds[name])
        return np.exp(lo + zi * (hi - lo)) if isinstance(zi, float | np.floating) else ca.exp(lo + zi * (hi - lo))

    def z(self, name: str, x: float) -> float:
        if name == "b":
            return float(np.clip((x - _B_BOUNDS[0]) / (_B_BOUNDS[1] - _B_BOUNDS[0]), 0, 1))
        lo, hi = np.log(self.bounds[name])
        return float(np.clip((np.log(max(x, 1e-12)) - lo) / (hi - lo), 0, 1))

    def gains(self, z: np.ndarray, spec: TuningSpec) -> PIDGains:
        x = {n: float(self.value(n, float(z[i]))) for i, n in enumerate(self.names)}
        return PIDGains(Kc=x["Kc"], Ti_s=x["Ti"], Td_s=x["Td"], Tf_s=x.get("Tf", spec.filter_s or 0.0),
                        b=x.get("b", spec.setpoint_weight),
                        u_min=spec.u_min_V, u_max=spec.u_max_V)


def _seeds(names: list[str], scaling: _Scaling, baseline: PIDGains, start: PIDGains | None = None) -> np.ndarray:
    """Starting points: the SIMC baseline (``start`` before it, if given) and a coarse grid around the box's middle."""
    pts = [[scaling.z(n, {"Kc": baseline.Kc, "Ti": baseline.Ti_s, "Td": 1e-4, "Tf": 1e-4, "b": 1.0}[n]) for n in names]]
    if start is not None:  # a warm start: gains tuned for a neighbouring problem
        pts.insert(0, [scaling.z(n, {"Kc": start.Kc, "Ti": start.Ti_s, "Td": start.Td_s, "Tf": start.Tf_s,
                                     "b": start.b}[n]) for n in names])
    k = scaling.bounds["Kc"][0] / _LOG_BOUNDS["Kc"][0]
    grid = {"Kc": [0.3 * k, 1.0 * k, 3.0 * k], "Ti": [0.02, 0.05, 0.15], "Td": [1e-4], "Tf": [1e-4], "b": [0.0, 0.5]}
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
    """The tuning NLP in the unit box: decision variables ``z`` and the slack ``s`` of the
    least-violation phase, its numbers ``p`` (:attr:`data` laid out by :attr:`layout`), the
    objective and the labelled constraints ``g <= 0``.

    One NLP serves both phases: ``f = (1 - a) objective + a s`` and ``g - s <= 0`` with ``a``
    (``phase_one`` in the data) 0 and ``s`` fixed at 0 for the tuning, 1 and ``s`` free for the
    least violation.
    """

    z: Any
    s: Any
    p: Any
    layout: Layout
    data: np.ndarray
    names: list[str]
    scaling: _Scaling
    variants: list[RigParams]
    objective: Any
    labels: list[str]
    g: Any
    horizon: _Horizon
    callbacks: list[Any]

    @property
    def x(self) -> Any:
        return ca.vertcat(self.z, self.s)

    def nlp(self) -> dict[str, Any]:
        a = self.layout.get(self.p, "phase_one")
        return {"x": self.x, "p": self.p, "f": (1 - a) * self.objective + a * self.s, "g": self.g - self.s}

    def with_phase(self, phase_one: bool) -> np.ndarray:
        data = self.data.copy()
        data[self.layout.index("phase_one")] = 1.0 if phase_one else 0.0
        return data


def _loop_rows(ref: Reference, dt: float, ramp_s: float) -> dict[str, np.ndarray]:
    """Per sample of ``ref``: the reference, the objective's weight (ramping up after each change)
    and the sign of the last change (0 before the first), which the overshoot is measured along."""
    n = int(round(ref.duration_s / dt)) + 1
    t = np.arange(n) * dt
    r = ref.at(t)
    k_change = np.searchsorted(ref.times_s, t, side="right") - 1
    t_since = t - ref.times_s[k_change]
    prev_level = np.where(k_change > 0, ref.levels_N[np.maximum(k_change - 1, 0)], ref.levels_N[0])
    return {"r": r, "weight": np.minimum(t_since / ramp_s, 1.0) * dt / ref.duration_s, "sign": np.sign(r - prev_level)}


#: the gains the time-domain part is differentiated by, in the controller's parameter order
_N_GAINS = 5
_PAIRS = [(i, j) for i in range(_N_GAINS) for j in range(i, _N_GAINS)]
#: the per-sample rows of the horizon, in order
_ROWS = ("r", "ff", "weight", "sign", "restart")


def _sensitivity_step(loop: LoopModel) -> ca.Function:
    """One sample of the tuning loop with its derivatives by the gains carried along.

    ``(xa, p, r, ff, restart) -> (xa_next, out)``: ``xa`` holds the loop's state ``x``, its
    first derivatives ``S = dx/dg`` (by the gains ``g = (Kc, Ti, Td, Tf, b)``, the first five
    controller parameters) and its second derivatives ``T`` (one column per pair ``i <= j``);
    ``p`` the loop's parameters; ``out`` the force, its gradient and its second derivatives.
    Where ``restart`` is 1 the loop first starts afresh (the rig at rest at 0 V, the controller
    bumpless at 0 V with the reference and feedforward of this sample: :meth:`LoopModel.start`),
    so the references run one after another on one horizon.

    Forward sensitivities, by CasADi's directional derivatives of the one loop step: with
    ``w = (x, g)`` and directions ``d_i = (S_i, e_i)``, ``S_i+ = F' d_i`` and
    ``T_ij+ = d_j' F'' d_i + F_x T_ij``. Five gains make this one small function that a C loop
    runs over the horizon: the whole NLP's derivatives in one pass, exact.
    """
    nx, n_plant = loop.state.size, loop.plant.params.size
    x, p = ca.SX.sym("x", nx), ca.SX.sym("p", loop.params.size)
    r, ff, restart = ca.SX.sym("r"), ca.SX.sym("ff"), ca.SX.sym("restart")
    gains = p[n_plant:n_plant + _N_GAINS]
    x_from = ca.if_else(restart > 0.5, loop.start(CASADI, p, r, ff), x)
    x_next, y = loop.step(CASADI, p, x_from, r, 0.0, ff)
    out = ca.vertcat(x_next, y[LOOP_OUTPUTS.index("force_N")])
    S, T = ca.SX.sym("S", nx, _N_GAINS), ca.SX.sym("T", nx, len(_PAIRS))
    w = ca.vertcat(x, gains)
    directions = ca.vertcat(S, ca.DM.eye(_N_GAINS))
    first = ca.jtimes(out, w, directions)
    along = [ca.jtimes(out, w, directions[:, i]) for i in range(_N_GAINS)]
    second = ca.horzcat(*[ca.jtimes(along[i], w, directions[:, j]) + ca.jtimes(out, x, T[:, k])
                          for k, (i, j) in enumerate(_PAIRS)])
    xa = ca.vertcat(x, ca.vec(S), ca.vec(T))
    xa_next = ca.vertcat(out[:nx], ca.vec(first[:nx, :]), ca.vec(second[:nx, :]))
    result = ca.vertcat(out[nx], first[nx, :].T, second[nx, :].T)
    return ca.Function("pp_tuning_sensitivity_step", [xa, p, r, ff, restart], [xa_next, result],
                       ["xa", "p", "r", "ff", "restart"], ["xa_next", "out"])


class _Horizon:
    """The tuning references on one horizon, run on every plant variant with the force's first and
    second derivatives by the gains, and what the NLP takes from them: the objective and the
    step's overshoot (a smooth maximum) per variant, with their gradients and Hessians.

    ``engine`` ``"compiled"`` runs :func:`_sensitivity_step` as C (a :class:`~piezopreload.core.native.StepRunner`,
    built once and cached); ``"plain"`` evaluates the same function in CasADi's virtual machine.
    The last evaluation is kept: IPOPT asks for values, Jacobians and Hessians at one point.
    """

    def __init__(self, loop: LoopModel, variants: list[RigParams], rows: np.ndarray, tail: np.ndarray,
                 engine: str) -> None:
        self.loop, self.rows, self.tail = loop, rows, tail  # tail: the controller's parameters after the gains
        self.plants = np.array([loop.plant.parameters(v) for v in variants])
        self.n_variants, self.n = len(variants), rows.shape[1]
        self.fn = _sensitivity_step(loop)
        self.size_x = int(self.fn.numel_in(0))
        self.engine = engine
        self.runner: native.StepRunner | None = None
        if engine == "compiled":
            self.runner = native.step_runner(("tuning", loop), lambda: self.fn, "pp_tuning_sensitivity",
                                             native.FLAGS_LARGE)
        self._key: bytes | None = None
        self._value: dict[str, np.ndarray] = {}

    def forces(self, gains: np.ndarray) -> np.ndarray:
        """``(variants, 1 + 5 + 15, samples)``: the force, its gradient and its second derivatives."""
        params = np.hstack([self.plants, np.tile(np.concatenate([gains, self.tail]), (self.n_variants, 1))])
        r, ff, restart = (self.rows[_ROWS.index(k)] for k in ("r", "ff", "restart"))
        if self.runner is not None:
            out, _ = self.runner(params, np.zeros(self.size_x), [r, ff, restart], self.n_variants)
            return out
        roll = self.fn.mapaccum(self.n)
        return np.array([np.asarray(roll(np.zeros(self.size_x), params[v], r[None, :], ff[None, :],
                                         restart[None, :])[1], float) for v in range(self.n_variants)])

    def evaluate(self, gains: Any) -> dict[str, np.ndarray]:
        gains = np.asarray(gains, float).ravel()
        key = gains.tobytes()
        if key == self._key:
            return self._value
        y_all = self.forces(gains)
        y, dy = y_all[:, 0, :], y_all[:, 1:1 + _N_GAINS, :]
        d2 = np.zeros((self.n_variants, _N_GAINS, _N_GAINS, self.n))
        for k, (i, j) in enumerate(_PAIRS):
            d2[:, i, j] = d2[:, j, i] = y_all[:, 1 + _N_GAINS + k, :]
        r, weight, sign = (self.rows[_ROWS.index(k)] for k in ("r", "weight", "sign"))
        # the objective: sum_k w_k phi(r_k - y_k), phi(e) = sqrt(e^2 + 1e-4)
        e = r - y
        phi = np.sqrt(e * e + 1e-4)
        d1, dd = e / phi, 1e-4 / phi**3  # phi' and phi''
        obj = np.sum(weight * phi, axis=-1)
        w1, w2 = weight * d1, weight * dd  # (variants, samples)
        obj_g = -np.matmul(dy, w1[:, :, None])[..., 0]
        obj_h = np.matmul(dy * w2[:, None, :], dy.transpose(0, 2, 1)) - np.matmul(d2, w1[:, None, :, None])[..., 0]
        # the step's overshoot: a Kreisselmeier-Steinhauser maximum of sign (y - r); samples before
        # the first change (sign 0) drop out
        o = sign * (y - r) + (np.abs(sign) - 1.0) * 1e3
        m = np.max(o, axis=-1, keepdims=True)
        ex = np.exp(_RHO_OVERSHOOT * (o - m))
        total = np.sum(ex, axis=-1, keepdims=True)
        ks = m[:, 0] + np.log(total[:, 0]) / _RHO_OVERSHOOT
        pi = ex / total
        s_dy = sign[None, None, :] * dy
        ks_g = np.matmul(s_dy, pi[:, :, None])[..., 0]
        ks_h = (np.matmul(d2, (pi * sign)[:, None, :, None])[..., 0]
                + _RHO_OVERSHOOT * (np.matmul(s_dy * pi[:, None, :], s_dy.transpose(0, 2, 1))
                                    - ks_g[:, :, None] * ks_g[:, None, :]))
        self._key = key
        self._value = {"objective": obj, "objective_g": obj_g, "objective_h": obj_h,
                       "overshoot": ks, "overshoot_g": ks_g, "overshoot_h": ks_h}
        return self._value


class _TimeDomain(ca.Callback):
    """The time-domain part of the NLP for CasADi: ``gains -> (objective summed over the
    variants, overshoot per variant)``, with its Jacobian (``order=1``) and the Jacobian of
    that (``order=2``), all from one :class:`_Horizon` evaluation."""

    def __init__(self, horizon: _Horizon, order: int = 0) -> None:
        ca.Callback.__init__(self)
        self.h, self.order, self.nv = horizon, order, horizon.n_variants
        self._shapes_in = [(_N_GAINS, 1), (1, 1), (self.nv, 1), (1, _N_GAINS), (self.nv, _N_GAINS)][:[1, 3, 5][order]]
        self._children: list[_TimeDomain] = []
        self.construct(f"pp_tuning_time_domain_{order}", {})

    def get_n_in(self) -> int:
        return len(self._shapes_in)

    def get_n_out(self) -> int:
        return [2, 2, 6][self.order]

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(*self._shapes_in[i])

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        if self.order == 0:
            return ca.Sparsity.dense(1 if i == 0 else self.nv, 1)
        if self.order == 1:
            return ca.Sparsity.dense(1 if i == 0 else self.nv, _N_GAINS)
        # the Jacobian of output i // 3 of order 1 (vectorised, column-major) by its input i % 3:
        # only the gains enter; the nominal outputs it also takes do not
        rows = _N_GAINS if i < 3 else self.nv * _N_GAINS
        shape = self._shapes_in[i % 3]
        return ca.Sparsity.dense(rows, _N_GAINS) if i % 3 == 0 else ca.Sparsity(rows, shape[0] * shape[1])

    def eval(self, arg: list[Any]) -> list[Any]:
        v = self.h.evaluate(arg[0])
        if self.order == 0:
            return [np.sum(v["objective"]), v["overshoot"]]
        if self.order == 1:
            return [np.sum(v["objective_g"], axis=0)[None, :], v["overshoot_g"]]
        # d vec(jac)/d gains: row i the objective's; row v + nv i the overshoot of variant v's
        hess_os = np.transpose(v["overshoot_h"], (1, 0, 2)).reshape(self.nv * _N_GAINS, _N_GAINS)
        empty = [ca.DM(self.get_sparsity_out(i).size1(), self.get_sparsity_out(i).size2()) for i in range(6)]
        return [np.sum(v["objective_h"], axis=0), empty[1], empty[2], hess_os, empty[4], empty[5]]

    def has_jacobian(self) -> bool:
        return self.order < 2

    def get_jacobian(self, name: str, inames: list[str], onames: list[str], opts: dict[str, Any]) -> ca.Function:
        child = _TimeDomain(self.h, self.order + 1)
        self._children.append(child)  # CasADi keeps a reference to the Function, not to the Python object
        return child


def _build_problem(params: RigParams, feedforward: InverseClassicalPI | None, spec: TuningSpec,
                   engine: str = "plain") -> _Problem:
    dt = params.sample_period_s
    variants = plant_variants(params, spec.variants)
    loop = tuning_loop(params)
    names = ["Kc", "Ti", "Td"] + (["Tf"] if spec.filter_s is None else []) + (["b"] if spec.tune_setpoint_weight else [])
    scaling = _Scaling(names, 1.0 / max(1.0, float(np.mean(_small_signal_gains(params)))))  # the whole stroke's box
    # the step, then the trajectory, on one horizon: the loop restarts at each one's first sample
    # (the trajectory's top is out of reach of the weakest variants: only the step's overshoot counts)
    parts = []
    for name, ref in (("step", spec.step), ("trajectory", spec.trajectory)):
        rows = _loop_rows(ref, dt, spec.ramp_s)
        rows["ff"] = _feedforward_sequence(feedforward, rows["r"])
        rows["restart"] = (np.arange(rows["r"].size) == 0).astype(float)
        if name != "step":
            rows["sign"] = np.zeros_like(rows["r"])
        parts.append(np.vstack([rows[k] for k in _ROWS]))
    horizon = _Horizon(loop, variants, np.hstack(parts), np.array([spec.u_min_V, spec.u_max_V, dt]), engine)
    omega = _omega_grid(dt)
    slopes = [_small_signal_gains(v, spec.force_range_N) for v in variants]
    G = np.vstack([_plant_frequency_response(v, omega, slope) for v, pair in zip(variants, slopes) for slope in pair])
    n_freq = G.size
    layout = Layout("tuning data", [
        ("dt_s", None), ("omega_terms", 6 * n_freq), ("G_re", n_freq), ("G_im", n_freq), ("nyquist", 6),
        ("band_limit_N", None), ("ms_max", None), ("noise_gain_max_V_per_N", None), ("tf_ratio_min", None),
        ("phase_one", None)])
    data = layout.numbers(
        dt_s=dt, omega_terms=np.tile(_omega_terms(omega, dt), G.shape[0]).ravel(), G_re=G.real.ravel(),
        G_im=G.imag.ravel(), nyquist=_omega_terms(np.array([np.pi / dt]), dt).ravel(),
        band_limit_N=spec.band_N - spec.overshoot_margin_N, ms_max=spec.ms_max,
        noise_gain_max_V_per_N=spec.noise_gain_max_V_per_N, tf_ratio_min=spec.Tf_ratio_min, phase_one=0.0)

    z, s, p = ca.MX.sym("z", len(names)), ca.MX.sym("s"), ca.MX.sym("p", layout.size)
    d = layout.unpack(p)
    vals = {k: scaling.value(k, z[i]) for i, k in enumerate(names)}
    if spec.filter_s is not None:
        vals["Tf"] = float(spec.filter_s)
    gains = ca.vertcat(vals["Kc"], vals["Ti"], vals["Td"], vals["Tf"], vals.get("b", spec.setpoint_weight))
    time_domain = _TimeDomain(horizon)  # (the problem keeps the Python object alive for CasADi)
    total, overshoot = time_domain(gains)
    objective = total / len(variants)
    band_lim = spec.band_N - spec.overshoot_margin_N
    blocks: list[tuple[str, Any]] = [  # (label, g): g <= 0 required
        (f"derivative filter Tf >= {spec.Tf_ratio_min:g} Td", d.tf_ratio_min * vals["Td"] - vals["Tf"])]
    blocks += [(f"overshoot inside {band_lim:g} N, step, variant {j}", overshoot[j] - d.band_limit_N)
               for j in range(len(variants))]

    # robustness of the linearised loop, per variant and at both ends of the local slope:
    # |1 + C G|^2 >= 1 / Ms^2 on the frequency grid, vectorised over every (variant, slope, frequency)
    gains4 = [vals["Kc"], vals["Ti"], vals["Td"], vals["Tf"]]
    terms = ca.reshape(d.omega_terms, n_freq, 6).T
    re, im = _controller_response(gains4, d.dt_s, [terms[i, :] for i in range(6)])
    g_re, g_im = d.G_re.T, d.G_im.T
    distance2 = (1 + re * g_re - im * g_im) ** 2 + (re * g_im + im * g_re) ** 2
    k = 0
    for j, pair in enumerate(slopes):
        for slope in pair:
            block = distance2[:, k * omega.size:(k + 1) * omega.size]
            blocks.append((f"Ms <= {spec.ms_max:g}, variant {j}, slope {slope:.3f} N/V",
                           d.ms_max**2 * _smooth_max(-block, _RHO_MS) + 1.0))
            k += 1
    re_ny, im_ny = _controller_response(gains4, d.dt_s, d.nyquist)
    blocks.append((f"controller gain at Nyquist <= {spec.noise_gain_max_V_per_N:g} V/N",
                   ca.sqrt(re_ny**2 + im_ny**2 + 1e-12) / d.noise_gain_max_V_per_N - 1.0))
    return _Problem(z=z, s=s, p=p, layout=layout, data=data, names=names, scaling=scaling, variants=variants,
                    objective=objective, labels=[label for label, _ in blocks],
                    g=ca.vertcat(*[blk for _, blk in blocks]), horizon=horizon, callbacks=[time_domain])


ENGINES = ("auto", "compiled", "plain")


def tune_pid(
    params: RigParams,
    feedforward: InverseClassicalPI | None,
    spec: TuningSpec = TuningSpec(),
    *,
    max_iterations: int = 150,
    starts: int = 3,
    verbose: bool = False,
    progress: Callable[[int], None] | None = None,
    engine: str = "auto",
    start: PIDGains | None = None,
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

    ``engine``: ``"compiled"`` runs the loop with its derivatives as C (built once and cached,
    :mod:`piezopreload.core.native`), ``"plain"`` in CasADi's virtual machine, ``"auto"``
    compiles where a C compiler works. The same NLP and the same derivatives either way, so
    the same iterates and optimum; the result says which ran and how long the build took.

    ``start``: gains to try first (a warm start, say the robust set for one entry of a gain
    schedule); the seeds are still ranked by violation and objective.
    """
    if engine not in ENGINES:
        raise InputError(f"engine must be one of {ENGINES}, got {engine!r}.")
    if starts < 1:
        raise InputError(f"starts must be >= 1, got {starts}.")
    t0 = time.perf_counter()
    rig = Rig(params)
    fopdt = fit_fopdt(rig, feedforward if feedforward is not None else _ZeroFF())
    baseline = simc(fopdt, u_min_V=spec.u_min_V, u_max_V=spec.u_max_V)
    used, compile_s = "plain", 0.0
    if engine != "plain" and native.enabled():
        before = native.build_stats()["compile_s"]
        try:
            prob = _build_problem(params, feedforward, spec, "compiled")
            used = "compiled"
        except native.NativeBuildError:
            if engine == "compiled" or native.engine() == "c":
                raise
        compile_s = native.build_stats()["compile_s"] - before
    if used == "plain":
        prob = _build_problem(params, feedforward, spec, "plain")
    nlp = prob.nlp()
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

        counters = [_IterationCounter(prob.x.numel(), prob.g.numel(), tick) for _ in range(2)]
    solver = ca.nlpsol("tune", "ipopt", nlp, {**options, **({"iteration_callback": counters[0]} if counters else {})})
    # phase one: the least violation, with a slack s >= max(g)
    phase_one = ca.nlpsol("tune_phase_one", "ipopt", nlp,
                          {**options, "ipopt.tol": 1e-8, **({"iteration_callback": counters[1]} if counters else {})})
    evaluate = ca.Function("evaluate", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]])
    data, data_one = prob.with_phase(False), prob.with_phase(True)
    n_z = len(prob.names)

    def score(zv: np.ndarray) -> tuple[float, float]:
        """The worst constraint violation (0 if feasible) and the objective."""
        f, gv = evaluate(np.append(zv, 0.0), data)
        return float(np.max(np.asarray(gv, float), initial=0.0)), float(f)

    seeds = _seeds(prob.names, prob.scaling, baseline, start)
    scores = [score(sd) for sd in seeds]
    order = sorted(range(len(seeds)), key=lambda i: (round(scores[i][0], 3), scores[i][1]))
    best: tuple[bool, float, np.ndarray, float, str] | None = None
    iterations = 0
    for i in order[:starts]:
        x0 = seeds[i]
        if scores[i][0] > 0:
            sol = phase_one(x0=np.append(x0, scores[i][0]), p=data_one, lbx=np.append(np.zeros(n_z), -np.inf),
                            ubx=np.append(np.ones(n_z), np.inf), lbg=-np.inf, ubg=0.0)
            iterations += int(phase_one.stats().get("iter_count", 0))
            x0 = np.clip(np.asarray(sol["x"], float).ravel()[:-1], 0.0, 1.0)
        sol = solver(x0=np.append(x0, 0.0), p=data, lbx=np.append(np.zeros(n_z), 0.0),
                     ubx=np.append(np.ones(n_z), 0.0), lbg=-np.inf, ubg=0.0)
        stats = solver.stats()
        iterations += int(stats.get("iter_count", 0))
        zv = np.clip(np.asarray(sol["x"], float).ravel()[:-1], 0.0, 1.0)
        worst, f = score(zv)
        # feasible beats infeasible; among feasible the lower objective, among infeasible the
        # smaller violation (what the error message then reports)
        infeasible = worst > 1e-4
        candidate = (infeasible, worst if infeasible else f, zv, f, str(stats.get("return_status", "unknown")))
        if best is None or candidate[:2] < best[:2]:
            best = candidate
        if not infeasible:
            break
    assert best is not None  # starts >= 1
    _, _, zv, objective, status = best
    g_best = np.asarray(evaluate(np.append(zv, 0.0), data)[1], float).ravel()
    margins = dict(zip(prob.labels, (float(x) for x in g_best)))
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
        constraint_margins=margins, engine=used, compile_s=compile_s,
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
#: a minimum-time candidate IPOPT has not solved in this many iterations counts as infeasible
#: (from the settled-command start the feasible ones converge in under 60; refuting the
#: infeasible ones far below the minimum can take it hundreds)
_MIN_TIME_ITERATIONS = 150
#: samples of hold in the relaxed search of :func:`minimum_time` (on the paper's rig its minimum is
#: the full 300 samples' minimum already; where it is not, the full hold is searched above it)
_MIN_TIME_RELAXED_HOLD = 10


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
    (CasADi Opti, IPOPT) started from a trajectory that meets the dynamics: the rig's response
    to the constant command whose settled force is ``final_N``. The bisection starts above a
    bound no command beats: the force does not move for ``delay + 1`` samples and then at most
    at the steepest slope times the slew (as :func:`tracking_floor` argues), with a 20 % margin.
    It runs first with a hold of ten samples, a relaxation whose minimum bounds the true one from
    below on small problems; the full hold is then checked there and, where it needs longer,
    searched above it.
    """
    dt = params.sample_period_s
    plant = tuning_loop(params).plant
    theta = ca.DM(plant.parameters(params))
    x_rig0 = np.asarray(plant.rest_state(NUMPY, plant.parameters(params)), float)
    n_hold = int(round(hold_s / dt))

    x = ca.SX.sym("x", x_rig0.size)
    u_sym = ca.SX.sym("u")
    step = ca.Function("rig", [x, u_sym], [plant.step(CASADI, theta, x, u_sym), plant.force(CASADI, theta, x)])

    def feasible(n_settle: int, n_hold: int) -> tuple[bool, np.ndarray | None]:
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
        u0 = np.full((1, n), u_steady)
        opti.set_initial(U, u0)
        opti.set_initial(X, np.hstack([x_rig0[:, None], np.asarray(step.mapaccum(n)(x_rig0, u0)[0])]))
        opti.solver("ipopt", {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                              "ipopt.max_iter": _MIN_TIME_ITERATIONS})
        try:
            sol = opti.solve()
            return True, np.atleast_1d(np.asarray(sol.value(U), float)).ravel()
        except RuntimeError:
            return False, None

    # the start: the constant command whose settled force is final_N, and the rig's response to it
    n_settle_s = int(round(2.0 / dt))
    lo_V, hi_V = u_min_V, u_max_V
    for _ in range(25):  # to a few microvolts: a starting point
        mid_V = 0.5 * (lo_V + hi_V)
        settled = float(np.asarray(step.mapaccum(n_settle_s)(x_rig0, np.full((1, n_settle_s), mid_V))[1])[0, -1])
        lo_V, hi_V = (mid_V, hi_V) if settled < final_N else (lo_V, mid_V)
    u_steady = 0.5 * (lo_V + hi_V)

    def search(lo: int, hi: int, n_hold: int) -> int:
        """The smallest feasible N in ``(lo, hi]`` (``lo`` infeasible, ``hi`` feasible) by bisection."""
        while hi - lo > 1:
            mid = (lo + hi) // 2
            lo, hi = (lo, mid) if feasible(mid, n_hold)[0] else (mid, hi)
        return hi

    horizon = int(round(horizon_s / dt))
    rate = _small_signal_gains(params)[1] * float(params.slew_V_per_s) * dt  # N per sample, at most
    bound = params.delay_samples + (abs(final_N - initial_N) - band_N) / rate
    lo = max(0, min(int(0.8 * bound) - 1, horizon - 1))  # no command settles this early
    # first with a short hold, a relaxation (fewer constraints): what it cannot settle, the full
    # hold cannot either, so its minimum is a lower bound, found on small problems
    short = min(n_hold, _MIN_TIME_RELAXED_HOLD)
    if not feasible(horizon, short)[0]:
        raise TuningInfeasible(f"no command reaches {final_N:g} +/- {band_N:g} N within {horizon_s:g} s on this plant")
    n_min = search(lo, horizon, short)
    ok, u_best = feasible(n_min, n_hold)
    if not ok:  # the full hold needs longer: search above the relaxation's minimum
        step_up, below = 1, n_min
        while True:
            candidate = min(below + step_up, horizon)
            ok, u_best = feasible(candidate, n_hold)
            if ok:
                break
            if candidate == horizon:
                raise TuningInfeasible(f"no command reaches {final_N:g} +/- {band_N:g} N and holds it for "
                                       f"{hold_s:g} s within {horizon_s:g} s on this plant")
            below, step_up = candidate, 2 * step_up
        n_min = search(below, candidate, n_hold)
        if n_min != candidate:
            ok, u_best = feasible(n_min, n_hold)
    return {"settling_s": n_min * dt, "samples": n_min, "command_V": u_best, "hold_s": hold_s}


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
