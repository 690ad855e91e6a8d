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
is a batch of ``n`` plants simulated at once (:meth:`Plant.vary` draws such a batch).
The Bouc-Wen equation is rate-independent and, on a monotone voltage increment, linear in
its state on each side of zero, so it is integrated *exactly* over each sample.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from piezopreload.core._typing import Array
from piezopreload.core.errors import InputError
from piezopreload.core.records import Checked, Invalid, checked, entry
from piezopreload.models.ops import NUMPY, Layout, Ops, absolute, clip

__all__ = ["StackData", "P888_91", "Plant", "RigState", "Rig", "PlantModel", "bouc_wen_step", "bouc_wen_increment",
           "loop_width", "reach_N", "ABS_SCALE_V", "hertz_force"]


@checked
class StackData(Checked):
    """[rig.stack]: one piezo stack actuator, its data sheet's values (the defaults: PI P-888.91)."""

    name: str = entry("The stack type.", default="PI P-888.91")
    nominal_travel_um: float = entry("Free stroke at 0..100 V.", unit="um", gt=0, default=32.0)
    max_travel_um: float = entry("Free stroke over v_min_V..v_max_V.", unit="um", gt=0, default=38.0)
    blocked_force_N: float = entry("Blocked force.", unit="N", gt=0, default=3600.0)
    stiffness_N_per_um: float = entry("Axial stiffness.", unit="N/um", gt=0, default=100.0)
    capacitance_uF: float = entry("Electrical capacitance.", unit="uF", gt=0, default=6.0)
    v_min_V: float = entry("Lowest operating voltage.", unit="V", default=-20.0)
    v_max_V: float = entry("Highest operating voltage.", unit="V", default=120.0)

    def check(self) -> None:
        if not self.v_min_V < self.v_max_V:
            raise Invalid("v_max_V", f"must be above v_min_V ({self.v_min_V:g} V), got {self.v_max_V:g}", "StackData")


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

#: the numeric fields that may hold a batch (an array of plants' values)
_BATCH = ("coupling_stiffness_N_per_um", "amp_bandwidth_Hz", "amp_current_limit_A", "bw_alpha", "sample_period_s",
          "bolt_preload_N", "noise_N", "creep_per_decade", "bw_beta_per_V", "hertz_um_per_N23", "hertz_preload_N",
          "stroke_um_per_V", "bw_gamma_per_V", "bw_kappa", "amp_v_min_V", "amp_v_max_V")


@checked(eq=False)
class Plant(Checked):
    """[rig]: the plant every control step runs on: the stacks, the amplifier, the coupling and the sensor.

    One plant, or a batch when the numeric fields are arrays (the Monte Carlo plants, :meth:`vary`). A study's
    plant is its ``[rig]`` table, read straight into this type (a key not given takes the default here), or the
    designed preload system's (``[plant] from_design``, :func:`piezopreload.design.plant.plant_from_design`),
    where the design sets the stacks, their count, the amplifier's current limit, the stroke per volt and the
    coupling, and those keys are refused in ``[rig]``. :class:`Rig` simulates it.

    The hysteresis is Bouc-Wen's ``dh/dv = alpha - beta sgn(dv) h - gamma |h|`` with ``h`` in volts: the loop's
    width grows with ``alpha`` and its shape with ``beta`` and ``gamma`` (``beta > |gamma|`` keeps ``h``
    bounded). With ``hertz_um_per_N23 > 0`` (``2 c_h / f_ar`` of the nut law ``delta(F) = (c_h F^(2/3) + s F) /
    f_ar``, :meth:`BallScrew.nut_approach_um`) the stacks' free stroke ``x`` and their force ``F_E`` obey ``x =
    F_E / k_eff + hertz ((F_0 + F_E)^(2/3) - F_0^(2/3))`` (:func:`hertz_force`), so the force per volt grows with
    the preload, and ``coupling_stiffness_N_per_um`` is the linear rest (the nut bodies, the screw under them,
    the sleeve and the bolts). The force read is ``bolt_preload_N + F_E``: a designed system whose sensors sit in
    series with the stacks reads the stacks' share alone, with ``bolt_preload_N = 0``.
    """

    stack: StackData = entry("The stack type; n_stacks of them act in parallel (default: PI P-888.91).",
                             default=P888_91)
    n_stacks: int = entry("Stacks acting in parallel (three in the paper).", ge=1, default=3)
    bolt_preload_N: float = entry("Preload the adjusting bolts set at 0 V (25 N in the paper).", unit="N", ge=0,
                                  default=25.0)
    coupling_stiffness_N_per_um: float = entry("Stiffness the stacks push against (nuts, balls, bolts and sleeve in "
                                               "series).", unit="N/um", gt=0, default=3.0)
    amp_bandwidth_Hz: float = entry("The amplifier's small-signal -3 dB bandwidth (first order).", unit="Hz", gt=0,
                                    default=20.0)
    amp_current_limit_A: float = entry("The amplifier's current limit: its slew rate into the stacks' capacitance.",
                                       unit="A", gt=0, default=0.1)
    amp_v_min_V: float = entry("The amplifier's lowest output.", unit="V", default=-20.0)
    amp_v_max_V: float = entry("The amplifier's highest output.", unit="V", default=120.0)
    stroke_um_per_V: float = entry("The stacks' anhysteretic free stroke per volt (d of the Bouc-Wen model).",
                                   unit="um/V", gt=0, default=0.35)
    bw_alpha: float = entry("Bouc-Wen hysteresis: alpha (the loop's width).", gt=0, default=0.25)
    bw_beta_per_V: float = entry("Bouc-Wen hysteresis: beta (the loop's shape; above the magnitude of gamma).",
                                 unit="1/V", ge=0,
                                 default=0.02)
    bw_gamma_per_V: float = entry("Bouc-Wen hysteresis: gamma.", unit="1/V", default=0.0)
    bw_kappa: float = entry("The loop's asymmetry: a term kappa v^2 / 100 V in the stroke, so the loop is not "
                            "point-symmetric as P-I loops are.", default=0.0)
    creep_per_decade: float = entry("Creep as a fraction of the stroke per decade of time.", ge=0, default=0.01)
    creep_tau_s: tuple[float, ...] = entry("Time constants of the creep chain (one per decade covered).", unit="s",
                                           gt=0, size=(1, 1_000_000), default=(0.1, 1.0, 10.0, 100.0))
    noise_N: float = entry("RMS white noise of the force measurement.", unit="N", ge=0, default=0.05)
    adc_bits: int = entry("The A/D's resolution (the PCI-1716 is a 16-bit card).", unit="bit", ge=2, le=32,
                          default=16)
    adc_full_scale_N: float = entry("Force at the A/D's full scale (the charge amplifier's range; it reads +/- "
                                    "this).", unit="N", gt=0, default=1000.0)
    sample_period_s: float = entry("The control loop's period.", unit="s", gt=0, default=1e-3)
    delay_samples: int = entry("Samples between reading the force and the amplifier receiving the command computed "
                               "from it (1: the D/A is written at the next tick).", ge=0, default=1)
    hertz_um_per_N23: float = entry("The nuts' Hertz contacts in the coupling, 2 c_h / f_ar (0: a linear coupling, "
                                    "the paper's rig).", unit="um/N^(2/3)", ge=0, default=0.0)
    hertz_preload_N: float = entry("F_0: the preload on the nuts when the stacks push nothing (the bolts'; above 0 "
                                   "with a Hertz coupling).", unit="N", ge=0, default=0.0)

    def check(self) -> None:
        if not np.all(np.asarray(self.amp_v_min_V) < np.asarray(self.amp_v_max_V)):
            raise Invalid("amp_v_max_V", f"must be above amp_v_min_V ({_shown(self.amp_v_min_V)} V), got "
                                         f"{_shown(self.amp_v_max_V)}", "Plant")
        if not np.all(np.asarray(self.bw_beta_per_V) > np.abs(np.asarray(self.bw_gamma_per_V))):
            raise Invalid("bw_beta_per_V", f"must be above |bw_gamma_per_V| ({_shown(np.abs(self.bw_gamma_per_V))}) "
                                           f"for a bounded loop, got {_shown(self.bw_beta_per_V)}", "Plant")
        if np.any(np.asarray(self.hertz_um_per_N23, float) > 0) and not np.all(np.asarray(self.hertz_preload_N) > 0):
            raise Invalid("hertz_preload_N", "must be > 0 (the bolts' preload on the nuts) where hertz_um_per_N23 > 0, "
                                             f"got {_shown(self.hertz_preload_N)}", "Plant")
        np.broadcast_shapes(*(np.shape(getattr(self, n)) for n in self.batch_fields()))

    # ---- batches -----------------------------------------------------------------------
    @staticmethod
    def batch_fields() -> tuple[str, ...]:
        """The numeric fields that may vary across a batch of plants.

        Returns
        -------
        tuple of str
            The names of the numeric fields that may hold one value per plant.
        """
        return _BATCH

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """The shape of the batch the fields broadcast to: ``()`` for one plant, ``(n,)`` for ``n`` plants."""
        return np.broadcast_shapes(*(np.shape(getattr(self, n)) for n in self.batch_fields()))

    def vary(self, n: int, spread: dict[str, float], seed: int | np.random.Generator = 0) -> Plant:
        """A batch of ``n`` plants around this one.

        ``spread`` maps a field name to a relative standard deviation; each plant's value is
        the nominal times a factor drawn from a normal distribution truncated to +/-2 sigma
        (and to positive factors), so no plant is absurd. Deterministic for a given seed.

        Parameters
        ----------
        n : int
            How many plants.
        spread : dict of str to float
            Each field to vary (one of :meth:`batch_fields`) and its relative standard deviation (0.1: 10 %).
        seed : int or numpy.random.Generator
            The seed of the draws, or the generator to draw from.

        Returns
        -------
        Plant
            A batch of ``n`` plants: each varied field an array of ``n`` values, the others as they are.

        Raises
        ------
        ValueError
            Where ``spread`` names a field that may not vary, or a spread that is negative or not finite.
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

    def take(self, index: int | slice) -> Plant:
        """One plant (or a sub-batch) of a batch.

        Parameters
        ----------
        index : int or slice
            The plant (or the plants) of the batch to take.

        Returns
        -------
        Plant
            One plant (each field a number) for an integer, a smaller batch for a slice.
        """
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
        """The stacks' stiffness together, in N/um: the number of stacks times one stack's."""
        return self.n_stacks * self.stack.stiffness_N_per_um

    @property
    def effective_stiffness_N_per_um(self) -> Any:
        """Stacks in series with the coupling: force per um of free stroke."""
        ks, ke = self.stack_stiffness_N_per_um, np.asarray(self.coupling_stiffness_N_per_um, float)
        return ks * ke / (ks + ke)

    @property
    def hertz(self) -> bool:
        """Whether the coupling follows the nuts' Hertz law (``hertz_um_per_N23 > 0``)."""
        return bool(np.any(np.asarray(self.hertz_um_per_N23, float) > 0))

    def stroke_for_force_um(self, stack_force_N: ArrayLike) -> Array:
        """The free stroke (um) that makes the stacks push ``stack_force_N`` (the inverse of :func:`hertz_force`).

        Parameters
        ----------
        stack_force_N : array_like
            The force the stacks push, in N.

        Returns
        -------
        ndarray
            The free stroke, in um: the linear coupling's ``F / k_eff`` plus the nuts' Hertz deflection from the
            contacts' preload to ``F``.
        """
        f = np.asarray(stack_force_N, float)
        k = np.asarray(self.effective_stiffness_N_per_um, float)
        c, f0 = np.asarray(self.hertz_um_per_N23, float), np.asarray(self.hertz_preload_N, float)
        stroke: Array = f / k + c * (np.cbrt(np.maximum(f0 + f, 0.0)) ** 2 - np.cbrt(f0) ** 2)
        return stroke

    def local_stiffness_N_per_um(self, stack_force_N: ArrayLike) -> Array:
        """dF_E/dx (N/um) at the stacks' force ``stack_force_N``: ``k_eff`` for a linear coupling,
        less where the nuts' Hertz contacts are soft (low preload).

        Parameters
        ----------
        stack_force_N : array_like
            The force the stacks push, in N.

        Returns
        -------
        ndarray
            The coupling's local stiffness ``dF/dx`` at that force, in N/um (same shape).
        """
        f = np.asarray(stack_force_N, float)
        k = np.asarray(self.effective_stiffness_N_per_um, float)
        c, f0 = np.asarray(self.hertz_um_per_N23, float), np.asarray(self.hertz_preload_N, float)
        total = np.maximum(f0 + f, 1e-9)
        return 1.0 / (1.0 / k + np.where(c > 0, c * (2.0 / 3.0) / np.cbrt(total), 0.0))

    @property
    def capacitance_F(self) -> float:
        """The stacks' capacitance together, in F: the number of stacks times one stack's (given in uF)."""
        return self.n_stacks * self.stack.capacitance_uF * 1e-6

    @property
    def slew_V_per_s(self) -> Any:
        """The amplifier's slew limit: current limit over the stacks' capacitance."""
        return np.asarray(self.amp_current_limit_A, float) / self.capacitance_F

    @property
    def adc_lsb_N(self) -> float:
        """The force sensor's ADC step, in N: the bipolar full scale (twice ``adc_full_scale_N``) over
        ``2**adc_bits``."""
        return float(2.0 * self.adc_full_scale_N / 2**self.adc_bits)

    def to_dict(self) -> dict[str, Any]:
        """The plant as its document holds it.

        Returns
        -------
        dict
            Every field by name (the stack's data as an object, a batch's fields as lists); a linear coupling leaves out
            the Hertz fields, as plants were written before the Hertz law.
        """
        out: dict[str, Any] = {}
        for f in fields(self):
            x = getattr(self, f.name)
            if f.name in _HERTZ and not self.hertz:
                continue  # a linear coupling's document is as it was before the Hertz law
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
    def from_dict(cls, data: dict[str, Any]) -> Plant:
        """The inverse of :meth:`to_dict`.

        Parameters
        ----------
        data : dict
            The plant's fields by name, the stack's data as an object.

        Returns
        -------
        Plant
            The plant, checked by its own rules.

        Raises
        ------
        ValueError
            Where ``data`` names a field the plant does not have, or a value its rules refuse.
        """
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


_HERTZ = ("hertz_um_per_N23", "hertz_preload_N")


def _shown(x: Any) -> str:
    """A plant's value (a number, or a batch's array) as a message shows it."""
    return f"{float(x):g}" if np.ndim(x) == 0 else repr(np.asarray(x, float).tolist())

#: Newton steps of :func:`hertz_force` from an upper bound of the root: 5 leave under 1e-11 N on a designed
#: system (4 leave 1e-8 N, 3 leave 2e-3 N; quadratic convergence)
HERTZ_NEWTON_STEPS = 5


def hertz_force(ops: Ops, x_um: Any, keff_N_per_um: Any, hertz_um_per_N23: Any, preload_N: Any) -> Any:
    """The stacks' force ``F_E`` (N) for their free stroke ``x_um`` against the nuts' Hertz contacts.

    Solves ``x = F_E / k + c ((F_0 + F_E)^(2/3) - F_0^(2/3))`` (``c = hertz_um_per_N23``, ``F_0 =
    preload_N``; :func:`piezopreload.models.feed_drive.stack_loop_um` with the linear parts
    gathered in ``k``) on numpy or CasADi (``ops``). In ``u = (F_0 + F_E)^(1/3)`` it is the cubic
    ``phi(u) = u^3 / k + c u^2 - (x + F_0 / k + c F_0^(2/3)) = 0``, increasing and convex for
    ``u > 0``: Newton from an upper bound of the root (the smaller of the roots of each term
    alone) descends monotonically onto it, so a fixed number of steps serves the compiled step
    and the tuning's derivatives. A stroke that would unload the nuts entirely gives ``F_E = -F_0``.
    """
    a = 1.0 / keff_N_per_um
    c = hertz_um_per_N23
    u0 = preload_N ** (1.0 / 3.0)
    rhs = ops.maximum(x_um + a * preload_N + c * u0 * u0, 1e-12)
    u = ops.minimum((rhs / a) ** (1.0 / 3.0), ops.sqrt(rhs / c))
    for _ in range(HERTZ_NEWTON_STEPS):
        u = u - (a * u * u * u + c * u * u - rhs) / (3.0 * a * u * u + 2.0 * c * u)
    return u * u * u - preload_N


#: the voltage scale of the Bouc-Wen rate's rounded ``|dv|`` per unit of smoothing: the tuning's
#: smoothing 0.02 rounds it over 1 mV (see :func:`bouc_wen_step`)
ABS_SCALE_V = 0.05


def bouc_wen_step(ops: Ops, h: Any, dv: Any, alpha: Any, beta: Any, gamma: Any, smoothing: float = 0.0) -> Any:
    """The Bouc-Wen state after a monotone voltage increment ``dv``, on numpy or CasADi (``ops``).

    ``dh/dv = alpha - beta sgn(dv) h - gamma |h|``. Exactly (``smoothing = 0``, the rig): along
    the direction of travel ``s = sgn(dv)``, ``g = s h`` obeys ``dg/du = alpha - (beta + gamma
    sgn(g)) g`` with ``u = |dv|``, linear on each side of ``g = 0``, so ``g`` relaxes exponentially
    toward ``alpha / (beta + gamma sgn g)``. A negative ``g`` first crosses zero (at ``u*``) and
    then follows the positive-side solution. The new state is ``h + s (g - g0)``.

    Smoothed (``smoothing > 0``, for an optimiser): one explicit step of the rate,
    ``h + alpha dv - beta |dv| h - gamma dv |h|``, with both ``|.|`` rounded as
    ``sqrt(x^2 + eps^2)``, ``eps = smoothing * ABS_SCALE_V`` (1 mV at the tuning's 0.02). Its
    increment agrees with the exact one to first order in ``dv`` (within 1 % of it at the paper's
    slew limit). The exact flow with its switches rounded was tried as the tuning model: from
    the same start IPOPT took another path and ended, after 150 iterations, among small jumps of
    the gradient without converging.
    """
    if smoothing:
        eps = smoothing * ABS_SCALE_V
        return h + alpha * dv - beta * absolute(ops, dv, eps) * h - gamma * dv * absolute(ops, h, eps)
    s = ops.where(dv < 0, -1.0, 1.0)
    u = ops.fabs(dv)
    g0 = s * h
    c_pos = beta + gamma
    c_neg = beta - gamma  # > 0 by the parameter check

    def relax(g: Any, c: Any, du: Any) -> Any:
        # g(u) = alpha/c + (g - alpha/c) exp(-c u), written stably for small c u
        em1 = ops.expm1(-c * du)
        return g * (em1 + 1.0) - alpha * em1 / c

    # distance to the zero crossing for g0 < 0: g(u*) = 0  =>  u* = log1p(-g0 c / alpha) / c
    # (g0 <= 0 inside the logarithm, so the branch not taken stays finite, its derivative too)
    u_star = ops.log1p(-ops.minimum(g0, 0.0) * c_neg / alpha) / c_neg
    negative = g0 < 0
    crosses = ops.logical_and(negative, u > u_star)
    g_neg = relax(g0, c_neg, u)  # stays negative (valid when not crossing)
    g_pos = relax(ops.where(crosses, 0.0, g0), c_pos, ops.where(crosses, u - u_star, u))
    g = ops.where(negative, ops.where(crosses, g_pos, g_neg), g_pos)
    return h + s * (g - g0)


def bouc_wen_increment(h: ArrayLike, dv: ArrayLike, alpha: ArrayLike, beta: ArrayLike, gamma: ArrayLike) -> Array:
    """:func:`bouc_wen_step` on numpy arrays, exact: the Bouc-Wen state after the increment ``dv``."""
    h, dv = np.broadcast_arrays(np.asarray(h, float), np.asarray(dv, float))
    alpha, beta, gamma = (np.asarray(x, float) for x in (alpha, beta, gamma))
    return np.asarray(bouc_wen_step(NUMPY, h, dv, alpha, beta, gamma), float)


@dataclass(frozen=True)
class PlantModel:
    """The rig's one step, written once over an ops table, with named parameters and state.

    The structure (how many creep lags, how many samples of delay, how smooth the corners)
    fixes the layouts; the numbers are a parameter vector (:meth:`parameters`), so one compiled
    step serves every plant of that structure. Every function takes ``ops`` and runs on numpy
    (a batch in the leading axes) or on CasADi expressions:

    * :meth:`force`: the true preload force of a state;
    * :meth:`step`: one sample, from the command written at this tick: delay line, amplifier
      (range, first-order bandwidth, slew limit), truth Bouc-Wen hysteresis, creep;
    * :meth:`measure`: the A/D reading of a force for a standard normal draw ``z`` (noise,
      16-bit quantisation, range clip); the smooth model reads the force unquantised (a
      staircase has no derivative to offer an optimiser);
    * :meth:`rest_state`: at rest at a voltage, creep settled.

    ``smoothing`` (0: the exact rig) rounds the slew limit's corners over that fraction of the
    limit and the Bouc-Wen direction switch over ``smoothing * ABS_SCALE_V`` volts, for the
    tuning NLP; the amplifier's range clip stays exact (the controller's clamp keeps the command
    inside it).
    """

    n_creep: int
    delay_samples: int = 1
    smoothing: float = 0.0
    hertz: bool = False  # the nuts' Hertz law in the coupling (Plant.hertz_um_per_N23 > 0)

    def __post_init__(self) -> None:
        if not (isinstance(self.n_creep, int | np.integer) and self.n_creep >= 0):
            raise InputError(f"PlantModel.n_creep must be an integer >= 0, got {self.n_creep!r}.")
        if not (isinstance(self.delay_samples, int | np.integer) and self.delay_samples >= 0):
            raise InputError(f"PlantModel.delay_samples must be an integer >= 0, got {self.delay_samples!r}.")
        if not (np.isfinite(self.smoothing) and 0.0 <= self.smoothing < 1.0):
            raise InputError(f"PlantModel.smoothing must be in [0, 1), got {self.smoothing!r}.")

    @classmethod
    def of(cls, params: Plant, smoothing: float = 0.0) -> PlantModel:
        """The structure of the rig ``params``."""
        return cls(len(params.creep_tau_s), int(params.delay_samples), float(smoothing), params.hertz)

    @cached_property
    def state(self) -> Layout:
        """``v_amp`` amplifier output (V), ``h`` Bouc-Wen state (V), ``creep`` the creep chain's
        lagged strokes (um), ``pending`` the commands on their way to the amplifier (V, oldest first)."""
        return Layout("plant state", [("v_amp", None), ("h", None), ("creep", self.n_creep),
                                      ("pending", self.delay_samples)])

    @cached_property
    def params(self) -> Layout:
        """The step's numbers, derived once from :class:`Plant` (per sample where it says so)."""
        return Layout("plant parameters", [
            ("bolt_preload_N", None), ("keff_N_per_um", None), ("stroke_um_per_V", None), ("bw_kappa", None),
            ("amp_v_min_V", None), ("amp_v_max_V", None),
            ("amp_fraction", None),  # of the gap to the target the amplifier closes per sample
            ("slew_V_per_sample", None),
            ("bw_alpha", None), ("bw_beta_per_V", None), ("bw_gamma_per_V", None),
            ("creep_per_decade", None), ("creep_decay", self.n_creep),  # per sample
            ("noise_N", None), ("adc_lsb_N", None), ("adc_full_scale_N", None),
        ] + ([("hertz_um_per_N23", None), ("hertz_preload_N", None)] if self.hertz else []))

    def parameters(self, params: Plant) -> Array:
        """The parameter vector of ``params`` (shape ``batch + (n,)`` for a batch of plants)."""
        if len(params.creep_tau_s) != self.n_creep or params.delay_samples != self.delay_samples:
            raise InputError(f"the rig has {len(params.creep_tau_s)} creep lags and {params.delay_samples} samples of "
                             f"delay; this model {self.n_creep} and {self.delay_samples}.")
        if params.hertz != self.hertz:
            raise InputError(f"the rig's coupling is {'Hertzian' if params.hertz else 'linear'}; this model's "
                             f"{'Hertzian' if self.hertz else 'linear'} (PlantModel.of(params) matches them).")
        hertz = {"hertz_um_per_N23": params.hertz_um_per_N23, "hertz_preload_N": params.hertz_preload_N} \
            if self.hertz else {}
        p, dt = params, params.sample_period_s
        tau = 1.0 / (2.0 * np.pi * np.asarray(p.amp_bandwidth_Hz, float))
        decay = np.exp(-dt / np.asarray(p.creep_tau_s, float))
        return self.params.numbers(
            bolt_preload_N=p.bolt_preload_N, keff_N_per_um=p.effective_stiffness_N_per_um,
            stroke_um_per_V=p.stroke_um_per_V, bw_kappa=p.bw_kappa, amp_v_min_V=p.amp_v_min_V,
            amp_v_max_V=p.amp_v_max_V, amp_fraction=-np.expm1(-dt / tau), slew_V_per_sample=p.slew_V_per_s * dt,
            bw_alpha=p.bw_alpha, bw_beta_per_V=p.bw_beta_per_V, bw_gamma_per_V=p.bw_gamma_per_V,
            creep_per_decade=p.creep_per_decade, creep_decay=np.broadcast_to(decay, p.batch_shape + decay.shape),
            noise_N=p.noise_N, adc_lsb_N=p.adc_lsb_N, adc_full_scale_N=p.adc_full_scale_N, **hertz)

    # ---- the chain ---------------------------------------------------------------------------
    def stroke(self, ops: Ops, p: Any, v: Any, h: Any) -> Any:
        """Hysteretic free stroke (um) of the stacks at amplifier voltage ``v`` (``p`` unpacked)."""
        return p.stroke_um_per_V * (v + p.bw_kappa * v**2 / 100.0 - h)

    def rest_state(self, ops: Ops, params: Any, v0_V: Any = 0.0) -> Any:
        """At rest at ``v0_V`` long enough for creep to have settled, the loop's branch reset."""
        p = self.params.unpack(params)
        x = self.stroke(ops, p, v0_V, 0.0)
        return self.state.pack(ops, v_amp=v0_V, h=0.0, creep=ops.repeat(x, self.n_creep),
                               pending=ops.repeat(v0_V, self.delay_samples))

    def force(self, ops: Ops, params: Any, state: Any) -> Any:
        """The true preload force (N) in ``state``: ``F_bolt + k_eff (x + sum c (creep - x))``, or with
        the nuts' Hertz law ``F_bolt + F_E(x + sum c (creep - x))`` (:func:`hertz_force`)."""
        p, s = self.params.unpack(params), self.state.unpack(state)
        x = self.stroke(ops, p, s.v_amp, s.h)
        x_total = x + ops.sum(ops.expand(p.creep_per_decade) * (s.creep - ops.expand(x)))
        return p.bolt_preload_N + self.coupling(ops, p, x_total)

    def coupling(self, ops: Ops, p: Any, x_um: Any) -> Any:
        """The stacks' force (N) for the free stroke ``x_um`` (``p`` unpacked): linear, or Hertzian."""
        if self.hertz:
            return hertz_force(ops, x_um, p.keff_N_per_um, p.hertz_um_per_N23, p.hertz_preload_N)
        return p.keff_N_per_um * x_um

    def step(self, ops: Ops, params: Any, state: Any, command_V: Any) -> Any:
        """The state one sample later; ``command_V`` is written to the D/A at this tick."""
        p, s = self.params.unpack(params), self.state.unpack(state)
        if self.delay_samples:
            u = ops.first(s.pending)
            pending = ops.shift_in(s.pending, command_V)
        else:
            u, pending = command_V, s.pending
        target = clip(ops, u, p.amp_v_min_V, p.amp_v_max_V)
        dv = (target - s.v_amp) * p.amp_fraction
        dv = clip(ops, dv, -p.slew_V_per_sample, p.slew_V_per_sample, self.smoothing)
        v = s.v_amp + dv
        h = bouc_wen_step(ops, s.h, dv, p.bw_alpha, p.bw_beta_per_V, p.bw_gamma_per_V, self.smoothing)
        x = ops.expand(self.stroke(ops, p, v, h))
        creep = x + (s.creep - x) * p.creep_decay
        return self.state.pack(ops, v_amp=v, h=h, creep=creep, pending=pending)

    def measure(self, ops: Ops, params: Any, force_N: Any, z: Any) -> Any:
        """The A/D reading of ``force_N`` for the standard normal draw ``z``: noise, quantisation, range.

        Quantisation rounds half up (``floor(x + 1/2)``) on both tables alike.
        """
        p = self.params.unpack(params)
        noisy = force_N + p.noise_N * z
        if self.smoothing:
            return noisy
        lsb = p.adc_lsb_N
        return clip(ops, ops.floor(noisy / lsb + 0.5) * lsb, -p.adc_full_scale_N, p.adc_full_scale_N - lsb)


@dataclass(frozen=True, eq=False)
class RigState:
    """Everything the rig remembers; copy it to branch a simulation.

    ``v_amp`` amplifier output (V); ``h`` Bouc-Wen state (V); ``creep`` the lagged strokes of
    the creep chain (um, last axis one per time constant); ``pending`` the commands on their
    way to the amplifier (V, last axis ``delay_samples`` long, oldest first). The fields of
    :attr:`PlantModel.state`.
    """

    v_amp: Array
    h: Array
    creep: Array
    pending: Array


@dataclass(frozen=True, eq=False)
class Rig:
    """The simulated reference rig: ``step`` advances one sample, ``measure`` reads the A/D.

    The numpy face of :class:`PlantModel` (exact, no smoothing) for one plant or a batch.
    """

    params: Plant = field(default_factory=Plant)

    @property
    def dt_s(self) -> float:
        return self.params.sample_period_s

    @cached_property
    def model(self) -> PlantModel:
        return PlantModel.of(self.params)

    @cached_property
    def parameter_vector(self) -> Array:
        """:meth:`PlantModel.parameters` of this rig (batch leading)."""
        return self.model.parameters(self.params)

    def vector(self, state: RigState) -> Array:
        """``state`` as the flat vector of :attr:`PlantModel.state`."""
        return self.model.state.numbers(v_amp=state.v_amp, h=state.h, creep=state.creep, pending=state.pending)

    def state_from_vector(self, x: Array) -> RigState:
        s = self.model.state.unpack(np.asarray(x, float))
        return RigState(np.array(s.v_amp), np.array(s.h), np.array(s.creep), np.array(s.pending))

    def initial_state(self, batch: tuple[int, ...] = (), v0_V: float = 0.0) -> RigState:
        """At rest at ``v0_V`` long enough for creep to have settled, the loop's branch reset.

        A rest state at 0 V with ``h = 0`` is the virgin state a P-I model also starts from.
        """
        x = self.model.rest_state(NUMPY, self.parameter_vector, float(v0_V))
        shape = np.broadcast_shapes(batch, self.params.batch_shape)
        return self.state_from_vector(np.broadcast_to(x, shape + x.shape[-1:]))

    def _stroke(self, v: Array, h: Array) -> Array:
        """Hysteretic free stroke (um) of the stacks at amplifier voltage ``v``."""
        return np.asarray(self.model.stroke(NUMPY, self.model.params.unpack(self.parameter_vector), v, h))

    def force(self, state: RigState) -> Array:
        """The true preload force (N) in state ``state``."""
        return np.asarray(self.model.force(NUMPY, self.parameter_vector, self.vector(state)))

    def step(self, state: RigState, command_V: ArrayLike) -> RigState:
        """Advance one sample period; ``command_V`` is written to the D/A at this tick."""
        command = np.broadcast_to(np.asarray(command_V, float), np.shape(state.v_amp))
        return self.state_from_vector(self.model.step(NUMPY, self.parameter_vector, self.vector(state), command))

    def measure(self, state: RigState, rng: np.random.Generator) -> Array:
        """The A/D reading of the force: noise, then 16-bit quantisation and range clipping."""
        f = self.force(state)
        return np.asarray(self.model.measure(NUMPY, self.parameter_vector, f, rng.standard_normal(f.shape)))

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
            out[..., i] = np.asarray(p.bolt_preload_N) + self.model.coupling(
                NUMPY, self.model.params.unpack(self.parameter_vector), self._stroke(v_prev, h))
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
    width: Array = np.max(fall - rise, axis=-1) / span
    return width


def reach_N(rig: Rig, v_V: float) -> Array:
    """Force reached by a slow rise from rest to ``v_V``, creep settled: the most the rig gives."""
    f, _ = rig.quasi_static_loop(np.linspace(0.0, v_V, 1001))
    return f[..., -1]
