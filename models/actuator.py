"""The reference rig: from the command voltage to the measured preload force.

Each part is a small, documented model with its parameters in SI-with-units names:

``u`` (V, from the D/A)
  --[one-sample delay]--> amplifier: first-order small-signal bandwidth and a slew limit
  set by its current limit into the stacks' capacitance, output range ``amp_v_*``
  --> stacks' free stroke ``x_h(v)``: an asymmetric Bouc-Wen hysteresis (the *truth* model,
  deliberately not a Prandtl-Ishlinskii model, so that identification and inversion meet
  realistic model error)
  --> creep: the stroke keeps growing after a step, about ``creep_per_decade`` of it per
  decade of time (a chain of first-order lags, the usual Kelvin-Voigt fit of logarithmic creep)
  --> force coupling: the stacks push the two nuts apart against the stiffness of nuts, balls
  and bolts; ``F = F_bolt + k_eff x``, ``k_eff`` the stacks' stiffness in series with the
  coupling stiffness
  --> force sensor and A/D: white noise, 16-bit quantisation over the A/D's force range.

The stacks are three PI P-888.91 PICMA stacks in parallel. Values used, from PI's data sheet
"P-882 - P-888 PICMA Stack Multilayer Piezo Actuators" (row P-888.91): 10 x 10 x 36 mm,
32 um nominal travel at 0..100 V and 38 um at -20..120 V, blocked force 3,600 N, axial stiffness
100 N/um, electrical capacitance 6.0 uF (+/-20 %), operating voltage -20..120 V.

The mechanical mode of the nut on the coupling stiffness (a slave nut of ~0.5 kg on the
calibrated ~3 N/um gives ~400 Hz) lies more than two decades above the force loop's crossover
(about 1 Hz with the paper's gains), so the coupling is quasi-static here.

Everything broadcasts: give any numeric parameter as an array of shape ``(n,)`` and the rig
is a batch of ``n`` plants simulated at once (:meth:`RigParams.vary` draws such a batch).
The Bouc-Wen equation is rate-independent and, on a monotone voltage increment, linear in
its state on each side of zero, so it is integrated *exactly* over each sample.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["StackData", "P888_91", "RigParams", "RigState", "Rig", "bouc_wen_increment", "loop_width", "reach_N"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class StackData:
    """One piezo stack actuator, catalogue values."""

    name: str
    nominal_travel_um: float  # at 0..100 V
    max_travel_um: float  # at v_min_V..v_max_V
    blocked_force_N: float
    stiffness_N_per_um: float
    capacitance_uF: float
    v_min_V: float
    v_max_V: float

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "name":
                continue
            if not np.isfinite(getattr(self, f.name)):
                raise ValueError(f"StackData.{f.name} must be finite, got {getattr(self, f.name)!r}.")
        for name in ("nominal_travel_um", "max_travel_um", "blocked_force_N", "stiffness_N_per_um", "capacitance_uF"):
            if getattr(self, name) <= 0:
                raise ValueError(f"StackData.{name} must be > 0, got {getattr(self, name)!r}.")
        if not self.v_min_V < self.v_max_V:
            raise ValueError(f"StackData needs v_min_V < v_max_V, got {self.v_min_V} and {self.v_max_V}.")


#: PI P-888.91 PICMA stack (data sheet row; see the module docstring).
P888_91 = StackData(
    name="PI P-888.91",
    nominal_travel_um=32.0,
    max_travel_um=38.0,
    blocked_force_N=3600.0,
    stiffness_N_per_um=100.0,
    capacitance_uF=6.0,
    v_min_V=-20.0,
    v_max_V=120.0,
)

# numeric fields that may hold a batch, with their admissible range (closed unless noted)
_POSITIVE = (
    "coupling_stiffness_N_per_um",
    "amp_bandwidth_Hz",
    "amp_current_limit_A",
    "bw_alpha",
    "sample_period_s",
)
_NONNEGATIVE = ("bolt_preload_N", "noise_N", "creep_per_decade", "bw_beta_per_V")


@dataclass(frozen=True, eq=False)
class RigParams:
    """Parameters of the simulated rig (one plant, or a batch when fields are arrays).

    Parameters
    ----------
    stack : StackData
        The stack type; ``n_stacks`` of them act in parallel.
    bolt_preload_N : float
        Preload set by the adjusting bolts at 0 V (25 N in the paper).
    coupling_stiffness_N_per_um : float
        Stiffness the stacks push against (nuts, balls, bolts and sleeve in series).
    amp_bandwidth_Hz : float
        Small-signal -3 dB bandwidth of the amplifier driving the stacks (first order).
    amp_current_limit_A : float
        Output current limit; the slew rate is this over the stacks' total capacitance.
    amp_v_min_V, amp_v_max_V : float
        Amplifier output range.
    stroke_um_per_V : float
        Free stroke per volt of the anhysteretic part (``d`` of the Bouc-Wen model).
    bw_alpha, bw_beta_per_V, bw_gamma_per_V : float
        Bouc-Wen hysteresis ``dh/dv = alpha - beta sgn(dv) h - gamma |h|`` with ``h`` in volts;
        the loop's width grows with ``alpha`` and its shape with ``beta`` and ``gamma``
        (``beta > |gamma|`` keeps ``h`` bounded).
    bw_kappa : float
        Asymmetry: a quadratic term ``kappa v^2 / 100 V`` in the stroke, so the loop is not
        point-symmetric as P-I loops are.
    creep_per_decade : float
        Creep as a fraction of the stroke per decade of time.
    creep_tau_s : tuple of float
        Time constants of the creep chain (one per decade covered).
    noise_N : float
        RMS white noise of the force measurement.
    adc_bits : int
        A/D resolution (the PCI-1716 is a 16-bit card).
    adc_full_scale_N : float
        Force at the A/D's full scale (the charge amplifier's range); the A/D reads
        ``-full_scale .. +full_scale``.
    sample_period_s : float
        Period of the control loop.
    delay_samples : int
        Samples between reading the force and the amplifier receiving the command computed
        from it (1: the D/A is written at the next tick).
    """

    stack: StackData = P888_91
    n_stacks: int = 3
    bolt_preload_N: Any = 25.0
    coupling_stiffness_N_per_um: Any = 3.0
    amp_bandwidth_Hz: Any = 20.0
    amp_current_limit_A: Any = 0.1
    amp_v_min_V: Any = -20.0
    amp_v_max_V: Any = 120.0
    stroke_um_per_V: Any = 0.35
    bw_alpha: Any = 0.25
    bw_beta_per_V: Any = 0.02
    bw_gamma_per_V: Any = 0.0
    bw_kappa: Any = 0.0
    creep_per_decade: Any = 0.01
    creep_tau_s: tuple[float, ...] = (0.1, 1.0, 10.0, 100.0)
    noise_N: Any = 0.05
    adc_bits: int = 16
    adc_full_scale_N: float = 1000.0
    sample_period_s: float = 1e-3
    delay_samples: int = 1

    def __post_init__(self) -> None:
        for name in _POSITIVE:
            x = np.asarray(getattr(self, name), float)
            if not (np.all(np.isfinite(x)) and np.all(x > 0)):
                raise ValueError(f"RigParams.{name} must be finite and > 0, got {getattr(self, name)!r}.")
        for name in _NONNEGATIVE:
            x = np.asarray(getattr(self, name), float)
            if not (np.all(np.isfinite(x)) and np.all(x >= 0)):
                raise ValueError(f"RigParams.{name} must be finite and >= 0, got {getattr(self, name)!r}.")
        for name in ("stroke_um_per_V", "bw_gamma_per_V", "bw_kappa", "amp_v_min_V", "amp_v_max_V"):
            if not np.all(np.isfinite(np.asarray(getattr(self, name), float))):
                raise ValueError(f"RigParams.{name} must be finite, got {getattr(self, name)!r}.")
        if not np.all(np.asarray(self.stroke_um_per_V) > 0):
            raise ValueError(f"RigParams.stroke_um_per_V must be > 0, got {self.stroke_um_per_V!r}.")
        if not np.all(np.asarray(self.bw_beta_per_V) > np.abs(np.asarray(self.bw_gamma_per_V))):
            raise ValueError(
                "RigParams needs bw_beta_per_V > |bw_gamma_per_V| for a bounded Bouc-Wen loop, "
                f"got beta={self.bw_beta_per_V!r}, gamma={self.bw_gamma_per_V!r}."
            )
        if not np.all(np.asarray(self.amp_v_min_V) < np.asarray(self.amp_v_max_V)):
            raise ValueError("RigParams needs amp_v_min_V < amp_v_max_V.")
        if not (isinstance(self.n_stacks, int | np.integer) and self.n_stacks >= 1):
            raise ValueError(f"RigParams.n_stacks must be a positive integer, got {self.n_stacks!r}.")
        if not (isinstance(self.adc_bits, int | np.integer) and 2 <= self.adc_bits <= 32):
            raise ValueError(f"RigParams.adc_bits must be an integer in 2..32, got {self.adc_bits!r}.")
        if not (isinstance(self.delay_samples, int | np.integer) and self.delay_samples >= 0):
            raise ValueError(f"RigParams.delay_samples must be an integer >= 0, got {self.delay_samples!r}.")
        if not (np.isfinite(self.adc_full_scale_N) and self.adc_full_scale_N > 0):
            raise ValueError(f"RigParams.adc_full_scale_N must be > 0, got {self.adc_full_scale_N!r}.")
        taus = np.asarray(self.creep_tau_s, float)
        if taus.ndim != 1 or not np.all(np.isfinite(taus) & (taus > 0)):
            raise ValueError(f"RigParams.creep_tau_s must be positive time constants, got {self.creep_tau_s!r}.")
        np.broadcast_shapes(*(np.shape(getattr(self, n)) for n in self.batch_fields()))

    # ---- batches -----------------------------------------------------------------------
    @staticmethod
    def batch_fields() -> tuple[str, ...]:
        """The numeric fields that may vary across a batch of plants."""
        return _POSITIVE + _NONNEGATIVE + ("stroke_um_per_V", "bw_gamma_per_V", "bw_kappa", "amp_v_min_V", "amp_v_max_V")

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return np.broadcast_shapes(*(np.shape(getattr(self, n)) for n in self.batch_fields()))

    def vary(self, n: int, spread: dict[str, float], seed: int | np.random.Generator = 0) -> RigParams:
        """A batch of ``n`` plants around this one.

        ``spread`` maps a field name to a relative standard deviation; each plant's value is
        the nominal times a factor drawn from a normal distribution truncated to +/-2 sigma
        (and to positive factors), so no plant is absurd. Deterministic for a given seed.
        """
        rng = np.random.default_rng(seed)
        unknown = sorted(set(spread) - set(self.batch_fields()))
        if unknown:
            raise ValueError(f"cannot vary {unknown}: fields that may vary are {sorted(self.batch_fields())}.")
        changes: dict[str, Any] = {}
        for name in sorted(spread):
            rel = float(spread[name])
            if not (np.isfinite(rel) and rel >= 0):
                raise ValueError(f"spread of {name} must be a finite relative deviation >= 0, got {spread[name]!r}.")
            z = np.clip(rng.standard_normal(n), -2.0, 2.0)
            factor = np.maximum(1.0 + rel * z, 0.05)
            changes[name] = np.asarray(getattr(self, name), float) * factor
        return replace(self, **changes)

    def take(self, index: int | slice) -> RigParams:
        """One plant (or a sub-batch) of a batch."""
        shape = self.batch_shape
        changes: dict[str, Any] = {}
        for name in self.batch_fields():
            x = np.asarray(getattr(self, name), float)
            if x.ndim:  # a field that varies across the batch; the others stay as they are
                changes[name] = np.broadcast_to(x, shape)[index]
        values: dict[str, Any] = {k: (float(v) if np.ndim(v) == 0 else np.array(v)) for k, v in changes.items()}
        return replace(self, **values)

    # ---- derived quantities ------------------------------------------------------------
    @property
    def stack_stiffness_N_per_um(self) -> float:
        return self.n_stacks * self.stack.stiffness_N_per_um

    @property
    def effective_stiffness_N_per_um(self) -> Any:
        """Stacks in series with the coupling: force per um of free stroke."""
        ks, ke = self.stack_stiffness_N_per_um, np.asarray(self.coupling_stiffness_N_per_um, float)
        return ks * ke / (ks + ke)

    @property
    def capacitance_F(self) -> float:
        return self.n_stacks * self.stack.capacitance_uF * 1e-6

    @property
    def slew_V_per_s(self) -> Any:
        """The amplifier's slew limit: current limit over the stacks' capacitance."""
        return np.asarray(self.amp_current_limit_A, float) / self.capacitance_F

    @property
    def adc_lsb_N(self) -> float:
        return 2.0 * self.adc_full_scale_N / 2**self.adc_bits

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in fields(self):
            x = getattr(self, f.name)
            if f.name == "stack":
                out["stack"] = {g.name: getattr(x, g.name) for g in fields(x)}
            elif isinstance(x, tuple):
                out[f.name] = [float(t) for t in x]
            elif np.ndim(x):
                out[f.name] = np.asarray(x, float).tolist()
            else:
                out[f.name] = x if isinstance(x, int | str) else float(x)
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RigParams:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown rig parameter(s) {unknown}; known: {sorted(known)}.")
        kwargs = dict(data)
        if "stack" in kwargs and isinstance(kwargs["stack"], dict):
            kwargs["stack"] = StackData(**kwargs["stack"])
        if "creep_tau_s" in kwargs:
            kwargs["creep_tau_s"] = tuple(float(t) for t in kwargs["creep_tau_s"])
        for name in cls.batch_fields():
            if isinstance(kwargs.get(name), list):
                kwargs[name] = np.asarray(kwargs[name], float)
        return cls(**kwargs)


def bouc_wen_increment(h: ArrayLike, dv: ArrayLike, alpha: ArrayLike, beta: ArrayLike, gamma: ArrayLike) -> Array:
    """Exact solution of ``dh/dv = alpha - beta sgn(dv) h - gamma |h|`` over a monotone ``dv``.

    Along the direction of travel ``s = sgn(dv)``, ``g = s h`` obeys
    ``dg/du = alpha - (beta + gamma sgn(g)) g`` with ``u = |dv|``: linear on each side of
    ``g = 0``, so ``g`` relaxes exponentially toward ``alpha / (beta + gamma sgn g)``. A
    negative ``g`` first crosses zero (at ``u*``) and then follows the positive-side solution.
    """
    h, dv = np.broadcast_arrays(np.asarray(h, float), np.asarray(dv, float))
    alpha, beta, gamma = (np.asarray(x, float) for x in (alpha, beta, gamma))
    s = np.where(dv < 0, -1.0, 1.0)
    u = np.abs(dv)
    g0 = s * h
    c_pos = beta + gamma
    c_neg = beta - gamma  # > 0 by the parameter check

    def relax(g: Array, c: Array, du: Array) -> Array:
        # g(u) = alpha/c + (g - alpha/c) exp(-c u), written stably for small c u
        return g * np.exp(-c * du) - alpha * np.expm1(-c * du) / c

    # distance to the zero crossing for g0 < 0: g(u*) = 0  =>  u* = log1p(-g0 c / alpha) / c
    with np.errstate(divide="ignore", invalid="ignore"):
        u_star = np.where(g0 < 0, np.log1p(-g0 * c_neg / alpha) / c_neg, 0.0)
    crosses = (g0 < 0) & (u > u_star)
    g_neg = relax(g0, c_neg, u)  # stays negative (valid when not crossing)
    g_pos = relax(np.where(crosses, 0.0, g0), c_pos, np.where(crosses, u - u_star, u))
    g = np.where(g0 < 0, np.where(crosses, g_pos, g_neg), g_pos)
    return s * g


@dataclass(frozen=True, eq=False)
class RigState:
    """Everything the rig remembers; copy it to branch a simulation.

    ``v_amp`` amplifier output (V); ``h`` Bouc-Wen state (V); ``creep`` the lagged strokes of
    the creep chain (um, last axis one per time constant); ``pending`` the commands on their
    way to the amplifier (V, last axis ``delay_samples`` long, oldest first).
    """

    v_amp: Array
    h: Array
    creep: Array
    pending: Array


@dataclass(frozen=True, eq=False)
class Rig:
    """The simulated reference rig: ``step`` advances one sample, ``measure`` reads the A/D."""

    params: RigParams = field(default_factory=RigParams)

    @property
    def dt_s(self) -> float:
        return self.params.sample_period_s

    def initial_state(self, batch: tuple[int, ...] = (), v0_V: float = 0.0) -> RigState:
        """At rest at ``v0_V`` long enough for creep to have settled, the loop's branch reset.

        A rest state at 0 V with ``h = 0`` is the virgin state a P-I model also starts from.
        """
        p = self.params
        shape = np.broadcast_shapes(batch, p.batch_shape)
        v = np.full(shape, float(v0_V))
        h = np.zeros(shape)
        x = self._stroke(v, h)
        creep = np.repeat(x[..., None], len(p.creep_tau_s), axis=-1)
        pending = np.full(shape + (p.delay_samples,), float(v0_V))
        return RigState(v, h, creep, pending)

    # ---- the chain -----------------------------------------------------------------------
    def _stroke(self, v: Array, h: Array) -> Array:
        """Hysteretic free stroke (um) of the stacks at amplifier voltage ``v``."""
        p = self.params
        return np.asarray(p.stroke_um_per_V) * (v + np.asarray(p.bw_kappa) * v**2 / 100.0 - h)

    def _creep_gains(self) -> Array:
        return np.asarray(self.params.creep_per_decade, float)[..., None] * np.ones(len(self.params.creep_tau_s))

    def force(self, state: RigState) -> Array:
        """The true preload force (N) in state ``state``."""
        p = self.params
        x = self._stroke(state.v_amp, state.h)
        x_total = x + np.sum(self._creep_gains() * (state.creep - x[..., None]), axis=-1)
        return np.asarray(p.bolt_preload_N) + p.effective_stiffness_N_per_um * x_total

    def step(self, state: RigState, command_V: ArrayLike) -> RigState:
        """Advance one sample period; ``command_V`` is written to the D/A at this tick."""
        p = self.params
        dt = p.sample_period_s
        command = np.broadcast_to(np.asarray(command_V, float), state.v_amp.shape)
        if p.delay_samples:
            u = state.pending[..., 0]
            pending = np.concatenate([state.pending[..., 1:], command[..., None]], axis=-1)
        else:
            u, pending = command, state.pending
        target = np.clip(u, p.amp_v_min_V, p.amp_v_max_V)
        tau = 1.0 / (2.0 * np.pi * np.asarray(p.amp_bandwidth_Hz))
        dv = (target - state.v_amp) * -np.expm1(-dt / tau)
        slew = p.slew_V_per_s * dt
        dv = np.clip(dv, -slew, slew)
        v = state.v_amp + dv
        h = bouc_wen_increment(state.h, dv, p.bw_alpha, p.bw_beta_per_V, p.bw_gamma_per_V)
        x = self._stroke(v, h)
        decay = np.exp(-dt / np.asarray(p.creep_tau_s))
        creep = x[..., None] + (state.creep - x[..., None]) * decay
        return RigState(v, h, creep, pending)

    def measure(self, state: RigState, rng: np.random.Generator) -> Array:
        """The A/D reading of the force: noise, then 16-bit quantisation and range clipping."""
        p = self.params
        f = self.force(state)
        noisy = f + np.asarray(p.noise_N) * rng.standard_normal(f.shape)
        lsb = p.adc_lsb_N
        return np.clip(np.round(noisy / lsb) * lsb, -p.adc_full_scale_N, p.adc_full_scale_N - lsb)

    def quasi_static_loop(self, v: ArrayLike, state: RigState | None = None) -> tuple[Array, RigState]:
        """Force along a voltage path followed slowly enough for the amplifier (no creep, no noise).

        The rate-independent part of the rig: the loop a P-I model is meant to describe.
        """
        v = np.asarray(v, float)
        st = self.initial_state() if state is None else state
        h, v_prev = st.h, st.v_amp
        out = np.empty(np.broadcast_shapes(v.shape, h.shape + (1,)) if h.shape else v.shape)
        p = self.params
        for i in range(v.shape[-1]):
            h = bouc_wen_increment(h, v[..., i] - v_prev, p.bw_alpha, p.bw_beta_per_V, p.bw_gamma_per_V)
            v_prev = v[..., i]
            out[..., i] = np.asarray(p.bolt_preload_N) + p.effective_stiffness_N_per_um * self._stroke(v_prev, h)
        creep = np.repeat(self._stroke(v_prev, h)[..., None], len(p.creep_tau_s), axis=-1)
        return out, RigState(np.asarray(v_prev, float), h, creep, st.pending)


def loop_width(rig: Rig, v_max_V: float = 100.0, points: int = 1001) -> Array:
    """Hysteresis width of the quasi-static ``0 -> v_max -> 0`` loop as a fraction of its span.

    The largest difference between the falling and the rising branch at equal voltage, over the
    force span, on the second cycle (after the virgin rise).
    """
    up = np.linspace(0.0, v_max_V, points)
    cycle = np.concatenate([up, up[::-1][1:]])
    f, _ = rig.quasi_static_loop(np.concatenate([cycle, cycle[1:]]))
    second = f[..., cycle.size - 1 :]
    rise, fall = second[..., :points], second[..., points - 1 :][..., ::-1]
    span = np.max(second, axis=-1) - np.min(second, axis=-1)
    return np.max(fall - rise, axis=-1) / span


def reach_N(rig: Rig, v_V: float) -> Array:
    """Force reached by a slow rise from rest to ``v_V``, creep settled: the most the rig gives."""
    f, _ = rig.quasi_static_loop(np.linspace(0.0, v_V, 1001))
    return f[..., -1]
