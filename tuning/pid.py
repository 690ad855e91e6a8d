"""PID tuning with CasADi around the P-I-compensated plant: the rig tuner.

The plant the PID sees is the rig with the identified inverse-P-I feedforward in front: the
feedforward turns the reference into a voltage, the PID adds its correction, and what is left
for the feedback to do is the model error (hysteresis residual, creep, the amplifier's lag and
slew, the delay). :func:`tune_pid` finds ``Kc, Ti, Td, Tf`` (and optionally the setpoint weight)
that minimise a time-weighted absolute error (the weight ramps up over ``TuningSpec.ramp_s``
after each change of the reference) over the study's step and trajectory on several plant
variants at once, subject to

* no overshoot of the step beyond the error band (kept a margin inside it, for the sensor
  noise), on every variant;
* a maximum sensitivity ``Ms`` of the linearised loop on a frequency grid (Astrom-Hagglund
  MIGO; Garpinger-Hagglund), per variant and at both ends of the hysteresis' local slope
  (:mod:`piezopreload.tuning.linearised`), stated with the rows of
  :mod:`piezopreload.tuning.loopshape` that the autotuner's constraints are too;
* a bound on the controller's gain at the Nyquist frequency (noise amplification).

The command stays inside its range because the tuning model clamps it as the controller does
(with its conditional integration): the time-domain part is the tuning model of
:mod:`piezopreload.tuning.horizon` (the one closed loop with its corners rounded, its
derivatives by the gains carried along). Every constraint family enters as one smooth maximum
(Kreisselmeier-Steinhauser) per variant, so the NLP has five variables and some twenty
constraints, and IPOPT runs with exact first and second derivatives. The validation
(:mod:`piezopreload.tuning.validate`) then runs the gains on the exact rig.

The starting point and the baseline is SIMC (Skogestad 2003) on a first-order-plus-dead-time
fit of the compensated plant's response to a voltage step (:mod:`piezopreload.tuning.fopdt`).

A derivative time on the lower end of its search range is no derivative action: the result is
then tuned again as a PI (``Td = 0``, no filter; the result's ``active_bounds`` says so), so
the gain set and every export hold the PI the loop is. ``TuningSpec.filter_s = 0`` tunes a PI
from the start. The lower bounds the tuned loop is read against (the minimum-time step, the
tracking floor) are :mod:`piezopreload.tuning.bounds`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import casadi as ca
import numpy as np

from piezopreload.artifacts.tuning import ActiveBound, TuningSolve
from piezopreload.core import native
from piezopreload.core.errors import InfeasibleError, InputError
from piezopreload.core.progress import Count
from piezopreload.core.records import Checked, Invalid, checked, entry
from piezopreload.models.actuator import Plant, Rig
from piezopreload.models.closedloop import PAPER_BAND_N, Reference
from piezopreload.models.controller import OUTPUT_MAX_V, OUTPUT_MIN_V, SCHEDULE_MAX, PIDGains
from piezopreload.models.hysteresis import InverseModel
from piezopreload.models.ops import Layout
from piezopreload.tuning.fopdt import fit_fopdt, simc
from piezopreload.tuning.horizon import ROWS, Horizon, TimeDomain, feedforward_sequence, loop_rows, tuning_loop
from piezopreload.tuning.linearised import max_sensitivity, omega_grid, plant_frequency_response, small_signal_gains
from piezopreload.tuning.loopshape import bound_rows, isa_pid_response, omega_terms, smooth_max

__all__ = [
    "TuningSpec",
    "TUNING_KEYS",
    "plant_variants",
    "TuningInfeasible",
    "tune_pid",
    "ENGINES",
    "SEARCH_BOX",
]

class TuningInfeasible(InfeasibleError):
    """The specification cannot be met; the message names the binding constraints."""


def _levels(value: Any, least: int, what: str) -> list[float]:
    """A study's list of forces (``[tuning] step_N``): ``least`` or more numbers; ValueError naming ``what``."""
    if not (isinstance(value, list | tuple) and len(value) >= least
            and all(isinstance(x, int | float) and not isinstance(x, bool) and np.isfinite(x) for x in value)):
        raise ValueError(f"{what} must be {least} or more finite numbers, got {value!r}")
    return [float(x) for x in value]


def _step_of(step_N: Any) -> Reference:
    """The tuning's short step ``(from, to)`` (0.6 s, the step at 0.02 s)."""
    levels = _levels(step_N, 2, "the tuning's step")
    if len(levels) != 2:
        raise ValueError(f"the tuning's step must be (from, to), got {list(step_N)!r}")
    return Reference.step(levels[0], levels[1], 0.02, 0.6)


def _trajectory_of(trajectory_N: Any) -> Reference:
    """The tuning's short staircase: its rest level, then its levels, each held 0.4 s from 0.02 s."""
    levels = _levels(trajectory_N, 2, "the tuning's staircase")
    return Reference.staircase(levels[0], levels[1:], 0.4, t_start_s=0.02)


def _levels_of(reference: Reference) -> list[float]:
    return [float(x) for x in reference.levels_N]


@checked
class TuningSpec(Checked):
    """What the tuned loop must do: a study's ``[tuning]`` table (its keys, below), with the error band and the
    output range from its ``[simulation]`` and ``[controller]``.

    ``step`` and ``trajectory`` are the references the loop is tuned over (short holds: the settling happens
    early); a study gives them as ``step_N = [from, to]`` and ``trajectory_N = [rest, level, ...]``.
    ``tune_setpoint_weight`` makes ``b`` a decision variable in ``[0, 1]`` (else ``setpoint_weight``, 1 as
    LabVIEW): with the feedforward following the setpoint, a small ``b`` keeps the proportional action from
    kicking the command into its limit at a step. The error's weight in the objective ramps from 0 at each
    change of the reference to 1 after ``ramp_s``: the transport right after a jump (which no gains remove, see
    :func:`minimum_time`) counts little, the error the loop leaves after it counts fully. ``filter_s`` holds
    ``Tf`` (a gain schedule's entries share the robust set's derivative filter); None tunes it; 0 means no
    derivative filter and so no derivative action: a PI. ``force_range_N`` is the measured force range the loop
    works in, for the linearised loop's slopes (the Ms constraints; None: the whole stroke, 0-110 V); the
    tuning's reported Ms (``TuningSolve.ms``) is read over the same range.
    """

    band_N: float = entry("The error band of the settling time (a study's [simulation] band_N).", unit="N", gt=0,
                          default=PAPER_BAND_N)
    overshoot_margin_N: float = entry("The noise-free step stays this far inside the error band ([simulation] band_N, "
                                      "which it must be below).", unit="N", gt=0, default=0.6)
    ms_max: float = entry("The largest maximum sensitivity over the plant variants.", gt=1, default=1.6)
    noise_gain_max_V_per_N: float = entry("The controller's largest gain at the Nyquist frequency (sensor noise into "
                                          "the command).", unit="V/N", gt=0, default=8.0)
    u_min_V: float = entry("The controller's lowest output (a study's [controller] u_min_V).", unit="V",
                           default=OUTPUT_MIN_V)
    u_max_V: float = entry("The controller's highest output (a study's [controller] u_max_V).", unit="V",
                           default=OUTPUT_MAX_V)
    step: Reference = entry("The tuning's step (from, to), held 0.6 s (the paper's 25 -> 60 N by default).",
                            name="step_N", unit="N", read=_step_of, write=_levels_of, takes="a list of 2 numbers",
                            default_factory=lambda: _step_of([25.0, 60.0]))
    trajectory: Reference = entry("The tuning's staircase: its rest level, then its levels, each held 0.4 s (the "
                                  "paper's by default).", name="trajectory_N", unit="N", read=_trajectory_of,
                                  write=_levels_of, takes="a list of 2 or more numbers",
                                  default_factory=lambda: _trajectory_of([25.0, 60.0, 80.0, 100.0, 80.0, 60.0]))
    tune_setpoint_weight: bool = entry("Tune the setpoint weight b too (false: [controller] b).", default=True)
    Tf_ratio_min: float = entry("The least Tf / Td (a derivative filter no faster than Td / 20 by default).", gt=0,
                                default=0.05)
    ramp_s: float = entry("The time over which the error's weight ramps up after each change of the reference.",
                          unit="s", gt=0, default=0.1)
    variants: dict[str, float] = entry("The relative spread of the plant variants (see plant_variants).", ge=0,
                                       default_factory=lambda: {"gain": 0.15, "amp_bandwidth_Hz": 0.2, "slew": 0.2,
                                                                "hysteresis": 0.2, "creep": 0.3})
    setpoint_weight: float = entry("b where it is not tuned (a gain schedule's entries share the robust set's).", ge=0,
                                   le=1, default=1.0)
    filter_s: float | None = entry("Tf held, not tuned (None: tuned; 0: no derivative action, a PI).", unit="s", ge=0,
                                   default=None)
    force_range_N: tuple[float, float] | None = entry("The measured force range the loop works in, for the "
                                                      "linearised loop's slopes (None: the whole stroke).", unit="N",
                                                      increasing=True, default=None)
    schedule_levels: int = entry(f"Entries of a gain schedule on the preload level (0: one gain set; else "
                                 f"2..{SCHEDULE_MAX}).", ge=0, le=SCHEDULE_MAX, default=0)
    schedule_plants: int = entry("Monte Carlo plants per level and gain set when choosing between the schedule and "
                                 "the robust set.", ge=1, le=100_000, default=50)
    warm_start: str | None = entry("A tuning record or gain set (JSON, relative to the study file) whose gains the "
                                   "tuning starts from and keeps unless it finds better: a tighter problem's, the "
                                   "last run's (not set: the study's [controller] gains and SIMC's only).",
                                   default=None)

    def check(self) -> None:
        if not self.overshoot_margin_N < self.band_N:
            raise Invalid("overshoot_margin_N", f"must be below [simulation] band_N ({self.band_N:g} N), the error "
                                                f"band, got {self.overshoot_margin_N:g}", "TuningSpec")
        if not self.u_min_V < self.u_max_V:
            raise Invalid("u_max_V", f"must be above u_min_V ({self.u_min_V:g} V), got {self.u_max_V:g}",
                          "TuningSpec")
        if self.schedule_levels == 1:
            raise Invalid("schedule_levels", f"must be 0 (one gain set) or 2..{SCHEDULE_MAX}, got 1", "TuningSpec")

    def to_dict(self) -> dict[str, Any]:
        """The specification as the tuning record holds it (its numbers, not its references).

        Returns
        -------
        dict
            ``band_N``, ``overshoot_margin_N``, ``ms_max``, ... (``b``, ``filter_s``, ``force_range_N`` where set).
        """
        return {"band_N": self.band_N, "overshoot_margin_N": self.overshoot_margin_N, "ms_max": self.ms_max,
                "noise_gain_max_V_per_N": self.noise_gain_max_V_per_N, "u_min_V": self.u_min_V, "u_max_V": self.u_max_V,
                "tune_setpoint_weight": self.tune_setpoint_weight, "variants": dict(self.variants),
                **({} if self.tune_setpoint_weight or self.setpoint_weight == 1.0 else {"b": self.setpoint_weight}),
                **({} if self.filter_s is None else {"filter_s": self.filter_s}),
                **({} if self.force_range_N is None else {"force_range_N": list(self.force_range_N)})}


#: the paper's specification (what :func:`tune_pid` tunes for where it is given none)
_PAPER_SPEC = TuningSpec()

#: the keys of a study's [tuning] table, by field name (the others come from [simulation], [controller] or code)
TUNING_KEYS = ("overshoot_margin_N", "ms_max", "noise_gain_max_V_per_N", "tune_setpoint_weight", "step",
               "trajectory", "schedule_levels", "schedule_plants", "warm_start")


# --------------------------------------------------------------------------------------
# the plant variants
# --------------------------------------------------------------------------------------
def plant_variants(params: Plant, spread: dict[str, float]) -> list[Plant]:
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

    def corner(gain: float, amp: float, slew: float, hyst: float, creep: float) -> Plant:
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
# the search box
# --------------------------------------------------------------------------------------
#: the search box of the gains (s, and V/N for Kc on a plant of up to 1 N/V): log scale
SEARCH_BOX = {"Kc": (1e-3, 50.0), "Ti": (2e-3, 5.0), "Td": (1e-5, 0.05), "Tf": (1e-5, 0.5)}
_B_BOUNDS = (0.0, 1.0)
#: the gain field each variable is
_FIELDS = {"Kc": "Kc", "Ti": "Ti_s", "Td": "Td_s", "Tf": "Tf_s"}
#: a variable this close to an end of its box (in the unit box) is on it
_ON_BOUND = 1e-4


class _Scaling:
    """Decision variables ``z`` in the unit box <-> gains.

    The box of ``Kc`` (:data:`SEARCH_BOX`) suits a plant of up to 1 N/V (the paper's rig, about
    0.7 N/V); a stiffer plant's ``Kc`` box is divided by its force per volt (``kc_scale``), so
    the box stays where the gains are (a designed preload system has some 50-200 N/V).
    """

    def __init__(self, names: list[str], kc_scale: float = 1.0) -> None:
        self.names = names
        self.bounds = {**SEARCH_BOX, "Kc": (SEARCH_BOX["Kc"][0] * kc_scale, SEARCH_BOX["Kc"][1] * kc_scale)}

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
        return PIDGains(Kc=x["Kc"], Ti_s=x["Ti"], Td_s=x.get("Td", 0.0), Tf_s=x.get("Tf", spec.filter_s or 0.0),
                        b=x.get("b", spec.setpoint_weight),
                        u_min_V=spec.u_min_V, u_max_V=spec.u_max_V)

    def on_bounds(self, z: np.ndarray) -> list[tuple[str, str, float]]:
        """``(name, side, bound)`` of every gain (not ``b``) within :data:`_ON_BOUND` of an end of its box."""
        out = []
        for i, name in enumerate(self.names):
            if name != "b" and min(z[i], 1.0 - z[i]) < _ON_BOUND:
                side = "lower" if z[i] < 0.5 else "upper"
                out.append((name, side, float(self.bounds[name][0 if side == "lower" else 1])))
        return out


def _z_of(names: list[str], scaling: _Scaling, g: PIDGains) -> np.ndarray:
    """``g`` in the unit box (clipped into it)."""
    return np.array([scaling.z(n, {"Kc": g.Kc, "Ti": g.Ti_s, "Td": g.Td_s, "Tf": g.Tf_s, "b": g.b}[n]) for n in names])


def _seeds(names: list[str], scaling: _Scaling, baseline: PIDGains, first: Sequence[PIDGains] = ()) -> np.ndarray:
    """Starting points: the SIMC baseline (the ``first`` gains before it: warm starts, known good gains) and a coarse
    grid around the box's middle."""
    pts = [[scaling.z(n, {"Kc": baseline.Kc, "Ti": baseline.Ti_s, "Td": 1e-4, "Tf": 1e-4, "b": 1.0}[n]) for n in names]]
    pts[:0] = [list(_z_of(names, scaling, g)) for g in first]  # gains tuned for a neighbouring problem, say
    k = scaling.bounds["Kc"][0] / SEARCH_BOX["Kc"][0]
    grid = {"Kc": [0.3 * k, 1.0 * k, 3.0 * k], "Ti": [0.02, 0.05, 0.15], "Td": [1e-4], "Tf": [1e-4], "b": [0.0, 0.5]}
    axes = [[scaling.z(n, v) for v in grid[n]] for n in names]
    pts += [list(p) for p in np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(names), -1).T]
    return np.array(pts)


_RHO_MS = 400.0  # on |1 + L|^2


# --------------------------------------------------------------------------------------
# the NLP
# --------------------------------------------------------------------------------------
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
    variants: list[Plant]
    objective: Any
    labels: list[str]
    g: Any
    horizon: Horizon
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


def _variable_names(spec: TuningSpec) -> list[str]:
    """The decision variables: Kc and Ti; Td where a derivative filter is (tuned, or held above
    0); Tf where tuned; b."""
    derivative = spec.filter_s is None or spec.filter_s > 0
    return (["Kc", "Ti"] + (["Td"] if derivative else []) + (["Tf"] if spec.filter_s is None else [])
            + (["b"] if spec.tune_setpoint_weight else []))


#: the decision variables in the order of the gains the tuning horizon is differentiated by (its ``N_GAINS``)
_GAIN_ORDER = ("Kc", "Ti", "Td", "Tf", "b")


def _horizon(params: Plant, feedforward: InverseModel | None, spec: TuningSpec, variants: list[Plant],
             engine: str) -> Horizon:
    """The step, then the trajectory, on one horizon: the loop restarts at each one's first sample (the
    trajectory's top is out of reach of the weakest variants: only the step's overshoot counts)."""
    dt = params.sample_period_s
    parts = []
    for name, ref in (("step", spec.step), ("trajectory", spec.trajectory)):
        rows = loop_rows(ref, dt, spec.ramp_s)
        rows["ff"] = feedforward_sequence(feedforward, rows["r"])
        rows["restart"] = (np.arange(rows["r"].size) == 0).astype(float)
        if name != "step":
            rows["sign"] = np.zeros_like(rows["r"])
        parts.append(np.vstack([rows[k] for k in ROWS]))
    free = [i for i, name in enumerate(_GAIN_ORDER) if name in _variable_names(spec)]  # the held gains' not run
    return Horizon(tuning_loop(params), variants, np.hstack(parts), np.array([spec.u_min_V, spec.u_max_V, dt]), engine,
                   free)


def _ms_blocks(d: Any, gains4: list[Any], slopes: list[tuple[float, float]], n_omega: int,
               ms_max: float) -> list[tuple[str, Any]]:
    """Robustness of the linearised loop, per variant and at both ends of the local slope: ``|S| <= Ms`` on the
    frequency grid (:func:`~piezopreload.tuning.loopshape.bound_rows`, vectorised over every (variant, slope,
    frequency)), each (variant, slope) one smooth maximum, scaled by ``Ms^2`` (``1 - Ms^2 |1 + L|^2``)."""
    n_freq = d.G_re.numel()
    terms = ca.reshape(d.omega_terms, n_freq, 6).T
    re, im = isa_pid_response(gains4, d.dt_s, [terms[i, :] for i in range(6)])
    rows = bound_rows(re, im, d.G_re.T, d.G_im.T, {"Ms": d.ms_max})["Ms"]
    blocks, k = [], 0
    for j, pair in enumerate(slopes):
        for slope in pair:
            blocks.append((f"Ms <= {ms_max:g}, variant {j}, slope {slope:.3f} N/V",
                           d.ms_max**2 * smooth_max(rows[:, k * n_omega:(k + 1) * n_omega], _RHO_MS)))
            k += 1
    return blocks


def _build_problem(params: Plant, feedforward: InverseModel | None, spec: TuningSpec,
                   engine: str = "plain") -> _Problem:
    dt = params.sample_period_s
    variants = plant_variants(params, spec.variants)
    names = _variable_names(spec)
    scaling = _Scaling(names, 1.0 / max(1.0, float(np.mean(small_signal_gains(params)))))  # the whole stroke's box
    horizon = _horizon(params, feedforward, spec, variants, engine)
    omega = omega_grid(dt)
    slopes = [small_signal_gains(v, spec.force_range_N) for v in variants]
    G = np.vstack([plant_frequency_response(v, omega, slope) for v, pair in zip(variants, slopes) for slope in pair])
    n_freq = G.size
    layout = Layout("tuning data", [
        ("dt_s", None), ("omega_terms", 6 * n_freq), ("G_re", n_freq), ("G_im", n_freq), ("nyquist", 6),
        ("band_limit_N", None), ("ms_max", None), ("noise_gain_max_V_per_N", None), ("tf_ratio_min", None),
        ("phase_one", None)])
    data = layout.numbers(
        dt_s=dt, omega_terms=np.tile(omega_terms(omega, dt), G.shape[0]).ravel(), G_re=G.real.ravel(),
        G_im=G.imag.ravel(), nyquist=omega_terms(np.array([np.pi / dt]), dt).ravel(),
        band_limit_N=spec.band_N - spec.overshoot_margin_N, ms_max=spec.ms_max,
        noise_gain_max_V_per_N=spec.noise_gain_max_V_per_N, tf_ratio_min=spec.Tf_ratio_min, phase_one=0.0)

    z, s, p = ca.MX.sym("z", len(names)), ca.MX.sym("s"), ca.MX.sym("p", layout.size)
    d = layout.unpack(p)
    vals = {"Td": 0.0, "Tf": float(spec.filter_s or 0.0), **{k: scaling.value(k, z[i]) for i, k in enumerate(names)}}
    gains = ca.vertcat(vals["Kc"], vals["Ti"], vals["Td"], vals["Tf"], vals.get("b", spec.setpoint_weight))
    time_domain = TimeDomain(horizon)  # (the problem keeps the Python object alive for CasADi)
    total, overshoot = time_domain(gains)
    band_lim = spec.band_N - spec.overshoot_margin_N
    blocks: list[tuple[str, Any]] = []  # (label, g): g <= 0 required
    if "Td" in names:
        blocks.append((f"derivative filter Tf >= {spec.Tf_ratio_min:g} Td", d.tf_ratio_min * vals["Td"] - vals["Tf"]))
    blocks += [(f"overshoot inside {band_lim:g} N, step, variant {j}", overshoot[j] - d.band_limit_N)
               for j in range(len(variants))]
    gains4 = [vals["Kc"], vals["Ti"], vals["Td"], vals["Tf"]]
    blocks += _ms_blocks(d, gains4, slopes, omega.size, spec.ms_max)
    re_ny, im_ny = isa_pid_response(gains4, d.dt_s, d.nyquist)
    blocks.append((f"controller gain at Nyquist <= {spec.noise_gain_max_V_per_N:g} V/N",
                   ca.sqrt(re_ny**2 + im_ny**2 + 1e-12) / d.noise_gain_max_V_per_N - 1.0))
    return _Problem(z=z, s=s, p=p, layout=layout, data=data, names=names, scaling=scaling, variants=variants,
                    objective=total / len(variants), labels=[label for label, _ in blocks],
                    g=ca.vertcat(*[blk for _, blk in blocks]), horizon=horizon, callbacks=[time_domain])


ENGINES = ("auto", "compiled", "plain")


# --------------------------------------------------------------------------------------
# solving
# --------------------------------------------------------------------------------------
#: a point whose worst constraint is within this of its bound is feasible (the constraints' units: N, Ms^2, ...)
_FEASIBLE = 1e-4
#: IPOPT's statuses that end a run at a local optimum (anything else: a limit reached, or trouble)
_CONVERGED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
#: a run that has found nothing better than the incumbent (feasible) for this many iterations is stopped: on a loop
#: with kinks an interior-point method may wander without end around the best point it has seen
_PATIENCE = 50
_STALLED = "User_Requested_Stop"
#: the status a result records when its gains came from no run of IPOPT but from a known point offered before any
#: (the study's, a tighter problem's, the last run's), none of the runs found better
KNOWN_POINT = "a known point"


@dataclass
class _Incumbent:
    """The best point the search has seen, from any start, any iterate or any known point: a feasible one beats an
    infeasible one; among feasible the lower objective, among infeasible the smaller violation. A run that ends on
    its iteration limit (or wanders off, as an interior-point method may on a loop with kinks) loses nothing it
    found, and gains that meet the specification are never reported infeasible once one was seen."""

    z: np.ndarray | None = None
    objective: float = float("inf")
    violation: float = float("inf")
    source: str = ""

    @property
    def feasible(self) -> bool:
        return self.violation <= _FEASIBLE

    def offer(self, z: np.ndarray, objective: float, violation: float, source: str) -> bool:
        """Keep ``z`` if it beats the incumbent; whether it did."""
        if not (np.isfinite(objective) and np.isfinite(violation)):
            return False
        feasible = violation <= _FEASIBLE
        better = (self.z is None or (feasible and (not self.feasible or objective < self.objective))
                  or (not feasible and not self.feasible and violation < self.violation))
        if better:
            self.z, self.objective, self.violation, self.source = np.array(z, float), objective, violation, source
        return better


class _Solvers:
    """The NLP's two IPOPT solvers (the tuning and the least violation, :class:`_Problem`), its evaluation and the
    incumbent every iterate of the tuning is offered to (:class:`_Incumbent`)."""

    def __init__(self, prob: _Problem, max_iterations: int, verbose: bool,
                 tick: Callable[[], None] | None) -> None:
        self.prob = prob
        self.max_iterations = max_iterations
        nlp = prob.nlp()
        options = {
            # the slew clip and the output clamp are kinks: the dual infeasibility stalls near 1e-3
            # while the objective no longer moves, so stop on that
            "ipopt.max_iter": max_iterations, "ipopt.tol": 1e-6, "ipopt.acceptable_tol": 1e-2,
            "ipopt.acceptable_iter": 5, "ipopt.acceptable_obj_change_tol": 1e-4,
            "ipopt.print_level": 5 if verbose else 0, "print_time": False, "ipopt.sb": "yes",
        }
        self.incumbent = _Incumbent()
        self._run = ""  # the run the tuning solver's iterates belong to (the incumbent's source)
        self._idle = 0  # the run's iterations since it last improved the incumbent
        n_x, n_g = prob.x.numel(), prob.g.numel()
        self.watch = _Watch(n_x, n_g, self._iterate, tick)  # every iterate of the tuning
        self.counter = _Watch(n_x, n_g, None, tick)  # the least violation's: counted, not offered
        self.solver = ca.nlpsol("tune", "ipopt", nlp, {**options, "iteration_callback": self.watch})
        self.phase_one = ca.nlpsol("tune_phase_one", "ipopt", nlp, {
            **options, "ipopt.tol": 1e-8, "iteration_callback": self.counter})
        self.evaluate = ca.Function("evaluate", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]])
        self.data, self.data_one = prob.with_phase(False), prob.with_phase(True)
        self.iterations = 0
        self.runs: list[dict[str, Any]] = []

    @property
    def n_z(self) -> int:
        return len(self.prob.names)

    def _iterate(self, x: np.ndarray, f: float, g: np.ndarray) -> bool:
        """An iterate of the tuning (its slack is 0, so ``g`` is the constraints): offered to the incumbent. Whether
        to stop the run: it has found nothing better than a feasible incumbent for :data:`_PATIENCE` iterations."""
        z = x[:self.n_z]
        better = bool(np.all((z >= 0.0) & (z <= 1.0))) and self.incumbent.offer(
            z, f, float(np.max(g, initial=0.0)), self._run)
        self._idle = 0 if better else self._idle + 1
        return self.incumbent.feasible and self._idle >= _PATIENCE

    def score(self, zv: np.ndarray) -> tuple[float, float]:
        """The worst constraint violation (0 if feasible) and the objective."""
        f, gv = self.evaluate(np.append(zv, 0.0), self.data)
        return float(np.max(np.asarray(gv, float), initial=0.0)), float(f)

    def margins(self, zv: np.ndarray) -> dict[str, float]:
        g = np.asarray(self.evaluate(np.append(zv, 0.0), self.data)[1], float).ravel()
        return dict(zip(self.prob.labels, (float(x) for x in g)))

    def offer(self, zv: np.ndarray, source: str) -> tuple[float, float]:
        """Score ``zv`` and offer it to the incumbent; its violation and objective."""
        violation, f = self.score(zv)
        self.incumbent.offer(zv, f, violation, source)
        return violation, f

    def solve(self, x0: np.ndarray, violation: float, run: str) -> tuple[np.ndarray, str]:
        """From ``x0``: the least violation first if it violates a constraint, then the tuning (``run`` names it)."""
        n_z = self.n_z
        if violation > 0:
            sol = self.phase_one(x0=np.append(x0, violation), p=self.data_one, lbx=np.append(np.zeros(n_z), -np.inf),
                                 ubx=np.append(np.ones(n_z), np.inf), lbg=-np.inf, ubg=0.0)
            self.iterations += int(self.phase_one.stats().get("iter_count", 0))
            x0 = np.clip(np.asarray(sol["x"], float).ravel()[:-1], 0.0, 1.0)
        self._run, self._idle = run, 0
        sol = self.solver(x0=np.append(x0, 0.0), p=self.data, lbx=np.append(np.zeros(n_z), 0.0),
                          ubx=np.append(np.ones(n_z), 0.0), lbg=-np.inf, ubg=0.0)
        stats = self.solver.stats()
        self.iterations += int(stats.get("iter_count", 0))
        zv = np.clip(np.asarray(sol["x"], float).ravel()[:-1], 0.0, 1.0)
        status = str(stats.get("return_status", "unknown"))
        self.offer(zv, run)
        self.runs.append({"run": run, "status": status, "iterations": int(stats.get("iter_count", 0))})
        return zv, status

    def best_of(self, seeds: np.ndarray, starts: int, known: dict[str, np.ndarray] | None = None) -> tuple[str, str]:
        """Search from the ``starts`` best seeds (by violation, then objective), the ``known`` points (gains known to
        be good, scored first) offered too; the incumbent is the result. A start that converges to a feasible point
        ends the search; one that stops on its iteration limit does not, and where the incumbent came from such a
        run the search goes on from it once more. Returns IPOPT's status of the incumbent's run and a sentence on
        how the search ended."""
        for name, z in (known or {}).items():
            self.offer(z, name)
        scores = [self.score(sd) for sd in seeds]
        order = sorted(range(len(seeds)), key=lambda i: (round(scores[i][0], 3), scores[i][1]))
        for k, i in enumerate(order[:starts]):
            zv, status = self.solve(seeds[i], scores[i][0], f"start {k + 1}")
            if status in _CONVERGED and self.score(zv)[0] <= _FEASIBLE:
                break
        inc = self.incumbent
        if inc.z is not None and self.status_of(inc.source) == "Maximum_Iterations_Exceeded":
            # the best point came from a run stopped on its limit: go on from it (IPOPT's barrier starts afresh)
            self.solve(inc.z, inc.violation, f"{inc.source}, continued")
        return self.status_word(self.incumbent.source), self.ending()

    def status_of(self, run: str) -> str | None:
        """IPOPT's status at the end of the run named ``run``; None where no run is named so (a known point, offered
        before any run)."""
        return next((r["status"] for r in self.runs if r["run"] == run), None)

    def status_word(self, run: str) -> str:
        """:meth:`status_of` as the result records it: a known point's is :data:`KNOWN_POINT`."""
        status = self.status_of(run)
        return KNOWN_POINT if status is None else status

    def ending(self) -> str:
        """How the search ended, in words: the runs, their statuses, where the result came from."""
        limited = sum(r["status"] == "Maximum_Iterations_Exceeded" for r in self.runs)
        stalled = sum(r["status"] == _STALLED for r in self.runs)
        runs = f"{len(self.runs)} run{'' if len(self.runs) == 1 else 's'} of IPOPT" + (
            f", {limited} stopped on the iteration limit ({self.max_iterations})" if limited else "") + (
            f", {stalled} stopped after {_PATIENCE} iterations without a better point" if stalled else "")
        inc = self.incumbent
        status = self.status_of(inc.source)
        if status is None:
            where = f"{inc.source} (no run found better)"
        elif status in _CONVERGED:
            where = f"{inc.source}, converged ({status})"
        elif status == _STALLED:
            where = f"the best iterate of {inc.source} (no better one in the {_PATIENCE} iterations after it)"
        else:
            where = f"the best iterate of {inc.source} ({status})"
        return f"{runs}; the result is {'feasible' if inc.feasible else 'the least violation'}: {where}"


def _check_feasible(margins: dict[str, float], search: str) -> None:
    violated = sorted(((m, label) for label, m in margins.items() if m > _FEASIBLE), reverse=True)
    if violated:
        detail = "; ".join(f"{label} (by {m:.3g})" for m, label in violated[:5])
        raise TuningInfeasible(f"PID tuning found no gains that meet the specification ({search}); "
                               f"not met: {detail}. Relax those limits or the plant variants' spread.")


def _pi_note(retuned: bool) -> str:
    return ("no derivative action there: the controller is a PI (Td = 0, no derivative filter), "
            + ("tuned again as one" if retuned else "which meets every constraint of the tuning"))


def _active_bounds(on_bounds: list[tuple[str, str, float]], made_pi: bool, retuned: bool) -> tuple[ActiveBound, ...]:
    out = []
    for name, side, bound in on_bounds:
        if made_pi and name in ("Td", "Tf"):
            continue
        note = ("the derivative is at its least; without it no PI meets the specification"
                if (name, side) == ("Td", "lower")
                else "the optimum may lie beyond the search range")
        out.append(ActiveBound(_FIELDS[name], side, bound, note))
    if made_pi:
        out.insert(0, ActiveBound("Td_s", "lower", SEARCH_BOX["Td"][0], _pi_note(retuned)))
    return tuple(out)


def _engine(params: Plant, feedforward: InverseModel | None, spec: TuningSpec,
            engine: str) -> tuple[_Problem, str, float]:
    """The problem on the compiled engine where asked and available, else plain; the engine and its build time."""
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
    return prob, used, compile_s


def _as_pi(params: Plant, feedforward: InverseModel | None, spec: TuningSpec, engine: str,
           pid: PIDGains, max_iterations: int, tick: Callable[[], None] | None
           ) -> tuple[PIDGains, _Solvers, np.ndarray, bool] | None:
    """The PI of ``pid`` (its derivative on its lower bound): ``pid`` without its derivative and filter where that
    meets every constraint of the tuning, else the PI tuned from its Kc, Ti (and b); with its solvers (their
    incumbent is the PI), its point and whether it was tuned again. None if no PI is feasible."""
    spec_pi = replace(spec, filter_s=0.0)
    prob, _, _ = _engine(params, feedforward, spec_pi, engine)
    solvers = _Solvers(prob, max_iterations, False, tick)
    seed = _z_of(prob.names, prob.scaling, pid)
    if solvers.offer(seed, "the PID without its derivative")[0] <= _FEASIBLE:
        return replace(pid, Td_s=0.0, Tf_s=0.0), solvers, seed, False
    solvers.best_of(seed[None, :], 1)
    inc = solvers.incumbent
    if inc.z is None or not inc.feasible:
        return None
    return prob.scaling.gains(inc.z, spec_pi), solvers, inc.z, True


def tune_pid(
    params: Plant,
    feedforward: InverseModel | None,
    spec: TuningSpec = _PAPER_SPEC,
    *,
    max_iterations: int = 150,
    starts: int = 3,
    verbose: bool = False,
    counter: Count | None = None,
    engine: str = "auto",
    start: PIDGains | None = None,
    known: Mapping[str, PIDGains] | None = None,
) -> TuningSolve:
    """Tune ``Kc, Ti, Td, Tf`` (and ``b``) on the compensated plant; see the module docstring.

    Every constraint family is one smooth maximum (per reference and variant for the
    overshoot, per variant and slope for Ms), so the NLP has a few dozen constraints and
    IPOPT runs with the exact Hessian. The NLP starts from the best of a few seeds (the SIMC
    baseline and a coarse grid) by constraint violation and then objective; a start that
    violates a constraint first minimises the violation (a phase-one problem), then the
    objective. Every iterate of every run is offered to an incumbent (feasible beats
    infeasible, then the lower objective), which is the result: a run that ends on its
    iteration limit, or wanders off as an interior-point method may on a loop with kinks,
    loses nothing it found; a start that converges to a feasible point ends the search, one
    stopped on its limit does not, and the search goes on once from an incumbent such a run
    found. ``TuningSolve.search`` says how it ended. Raises :class:`TuningInfeasible`
    naming the violated constraints when no feasible point was seen. ``counter``, if given
    (:meth:`Progress.counter <piezopreload.core.progress.Progress.counter>`), is called with the count of IPOPT
    iterations so far (all starts and phases) at every iteration.

    ``engine``: ``"compiled"`` runs the loop with its derivatives as C (built once and cached,
    :mod:`piezopreload.core.native`), ``"plain"`` in CasADi's virtual machine, ``"auto"``
    compiles where a C compiler works. The same NLP and the same derivatives either way, so
    the same iterates and optimum; the result says which ran and how long the build took.

    ``start``: gains to try first (a warm start, say the robust set for one entry of a gain
    schedule); the seeds are still ranked by violation and objective. ``known``: gains known to
    be good by name (the study's, a tighter problem's, the last run's): each is scored and
    offered to the incumbent before any run and tried as a start, so the result is never worse
    than the best of them that meets the specification (a relaxed limit cannot lose a solution
    it is given).

    A derivative time that ends on the lower end of its range makes the result a PI: tuned again
    without the derivative and its filter from the PID's Kc and Ti (``TuningSolve.active_bounds``
    says so); the gains on an end of their range are named there too.
    """
    if engine not in ENGINES:
        raise InputError(f"engine must be one of {ENGINES}, got {engine!r}.")
    if starts < 1:
        raise InputError(f"starts must be >= 1, got {starts}.")
    t0 = time.perf_counter()
    fopdt = fit_fopdt(Rig(params), feedforward if feedforward is not None else _ZeroFF())
    baseline = simc(fopdt, u_min_V=spec.u_min_V, u_max_V=spec.u_max_V)
    prob, used, compile_s = _engine(params, feedforward, spec, engine)
    total = [0]

    def tick() -> None:
        total[0] += 1
        if counter is not None:
            counter(total[0])

    known = dict(known or {})
    solvers = _Solvers(prob, max_iterations, verbose, tick if counter is not None else None)
    status, search = solvers.best_of(
        _seeds(prob.names, prob.scaling, baseline, list(dict.fromkeys(g for g in (start, *known.values()) if g))),
        starts,
        {name: _z_of(prob.names, prob.scaling, g) for name, g in known.items()})
    zv = solvers.incumbent.z
    if zv is None:  # pragma: no cover - a search always scores its seeds
        raise TuningInfeasible(f"PID tuning found no point to judge ({search})")
    margins = solvers.margins(zv)
    _check_feasible(margins, search)
    objective = solvers.incumbent.objective
    tuned, on_bounds, iterations = prob.scaling.gains(zv, spec), prob.scaling.on_bounds(zv), solvers.iterations
    made_pi = any(name == "Td" and side == "lower" for name, side, _ in on_bounds)
    retuned = False
    if made_pi:
        pi = _as_pi(params, feedforward, spec, engine, tuned, max_iterations, tick if counter is not None else None)
        if pi is None:  # no PI meets the specification: keep the PID with its derivative on the bound
            made_pi = False
        else:
            tuned, pi_solvers, z_pi, retuned = pi
            inc = pi_solvers.incumbent
            objective, margins = pi_solvers.score(z_pi)[1], pi_solvers.margins(z_pi)
            on_bounds = on_bounds + pi_solvers.prob.scaling.on_bounds(z_pi)
            iterations += pi_solvers.iterations
            if retuned:
                status, search = pi_solvers.status_word(inc.source), f"{search}; as a PI: {pi_solvers.ending()}"
    binding = sorted(label for label, m in margins.items() if m > -1e-3)
    ms = max(max_sensitivity(tuned, v, spec.force_range_N) for v in prob.variants)  # over the range it was tuned for
    return TuningSolve(
        status=status, iterations=iterations, seconds=time.perf_counter() - t0, engine=used, compile_s=compile_s,
        objective=objective, ms=ms, binding=tuple(binding), constraint_margins=margins,
        fopdt={"K_N_per_V": fopdt.K, "T_s": fopdt.T_s, "theta_s": fopdt.theta_s, "rms_N": fopdt.rms_N},
        form="PI" if tuned.Td_s == 0.0 else "PID", spec=spec.to_dict(), search=search, gains=tuned, baseline=baseline,
        active_bounds=_active_bounds(sorted(set(on_bounds)), made_pi, retuned),
    )


class _Watch(ca.Callback):
    """CasADi's ``iteration_callback`` for an NLP with ``nx`` variables and ``ng`` constraints: hands every iterate
    (``x``, ``f``, ``g``) to ``on_iterate`` where given (which returns whether to stop the run), and calls
    ``tick()`` where given."""

    def __init__(self, nx: int, ng: int, on_iterate: Callable[[np.ndarray, float, np.ndarray], bool] | None,
                 tick: Callable[[], None] | None) -> None:
        ca.Callback.__init__(self)
        self.nx, self.ng, self.on_iterate, self.tick = nx, ng, on_iterate, tick
        self.construct("iteration_watch", {})

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

    def eval(self, arg: Sequence[Any]) -> list[Any]:
        stop = False
        if self.on_iterate is not None:
            names = [ca.nlpsol_out(i) for i in range(ca.nlpsol_n_out())]
            x, f, g = (np.asarray(arg[names.index(k)], float).ravel() for k in ("x", "f", "g"))
            stop = self.on_iterate(x, float(f[0]), g)
        if self.tick is not None:
            self.tick()
        return [1 if stop else 0]  # non-zero: IPOPT stops (User_Requested_Stop)


class _ZeroFF:
    """No feedforward: the plant seen by the PID alone."""

    def initial_state(self, batch: tuple[int, ...] = ()) -> np.ndarray:
        return np.zeros(batch + (1,))

    def step(self, state: np.ndarray, target: Any) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros(np.shape(target)), state
