"""Creep: linear creep operators (first-order lags on the input) and the P-I models with creep.

Kuhnen's modified P-I model with creep (Eur. J. Control 9(4), 2003) and Krejci & Kuhnen (IEE
Proc. Control Theory Appl. 148(3), 2001) add to the hysteresis operator a superposition of
linear creep operators: first-order lags of the input with time constants spread over the
decades the creep covers, ``C[v] = sum_j c_j L_j[v]``, ``tau_j dL_j/dt = v - L_j``. The model
stays linear in all its weights, so it is identified by the same QP, and its one-sample map
stays a P-I model: see :class:`CreepPI`. :func:`inverse_at` is a model's inverse for a loop
sampled at a given period (the lags resampled exactly).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezopreload.core.errors import InputError
from piezopreload.models.hysteresis.inverse import InverseCreepPI, InverseSpec
from piezopreload.models.hysteresis.operators import NotInvertibleError, play, play_step, rising, vector
from piezopreload.models.hysteresis.pi import AsymmetricPI, ClassicalPI, HysteresisModel, ModifiedPI

__all__ = ["log_spaced_time_constants", "LagCoefficients", "lag_coefficients", "creep_lags", "Creep", "CreepPI",
           "CREEP_SUFFIX", "inverse_at"]


def log_spaced_time_constants(shortest_s: float, longest_s: float, n: int | None = None) -> NDArray[np.float64]:
    """``n`` time constants spaced evenly in log between ``shortest_s`` and ``longest_s``.

    Without ``n``, one per decade (rounded up) and both ends included: 0.01 s to 10 s gives
    0.01, 0.1, 1 and 10 s. The usual spread of a creep operator bank (Kuhnen 2003).
    """
    lo, hi = float(shortest_s), float(longest_s)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi):
        raise InputError(
            f"log-spaced time constants need 0 < shortest_s <= longest_s, got {shortest_s!r} and {longest_s!r}."
        )
    if n is None:
        n = int(np.ceil(np.log10(hi / lo) - 1e-9)) + 1 if hi > lo else 1
    if int(n) != n or n < 1:
        raise InputError(f"n must be a positive integer, got {n!r}.")
    if n > 1 and hi == lo:
        raise InputError(f"{n} distinct time constants need shortest_s < longest_s, got both {lo}.")
    return np.geomspace(lo, hi, int(n))


def _b0_series(h: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(h - 1 + exp(-h)) / h``, without the cancellation of the direct formula at small ``h``."""
    direct = (h + np.expm1(-h)) / np.where(h > 0, h, 1.0)
    series = h / 2 - h**2 / 6 + h**3 / 24 - h**4 / 120 + h**5 / 720
    return np.where(h < 1e-3, series, direct)


@dataclass(frozen=True, eq=False)
class LagCoefficients:
    """Exact one-sample coefficients of first-order lags ``tau dz/dt = v - z``.

    Exact for an input that is linear between samples (a first-order hold, the discretisation
    a sampled smooth signal calls for): ``z_k = a z_{k-1} + b1 v_{k-1} + b0 v_k`` with
    ``a = exp(-h)``, ``b0 = 1 - (1 - a)/h``, ``b1 = (1 - a) - b0``, ``h = dt / tau``
    (``b0 + b1 = 1 - a``: unit static gain). The state kept between samples is the *carry*
    ``s_k = a z_k + b1 v_k``, so that ``z_k = s_{k-1} + b0 v_k`` and ``s_k = a s_{k-1} + e v_k``
    with ``e = a b0 + b1``; at rest at ``v0``, ``s = (1 - b0) v0``.
    """

    a: NDArray[np.float64]
    b0: NDArray[np.float64]
    b1: NDArray[np.float64]

    @property
    def e(self) -> NDArray[np.float64]:
        return self.a * self.b0 + self.b1


def lag_coefficients(time_constants_s: ArrayLike, sample_period_s: float) -> LagCoefficients:
    """:class:`LagCoefficients` of lags with ``time_constants_s`` sampled every ``sample_period_s``."""
    tau = np.asarray(time_constants_s, dtype=float)
    dt = float(sample_period_s)
    if not (np.isfinite(dt) and dt > 0):
        raise InputError(f"sample_period_s must be a positive number of seconds, got {sample_period_s!r}.")
    if not np.all(np.isfinite(tau) & (tau > 0)):
        raise InputError(f"time constants must be positive and finite, got {tau.tolist()}.")
    h = dt / tau
    one_minus_a = -np.expm1(-h)
    b0 = _b0_series(h)
    return LagCoefficients(a=np.exp(-h), b0=b0, b1=one_minus_a - b0)


def creep_lags(
    v: ArrayLike, coefficients: LagCoefficients, state: ArrayLike | None = None
) -> NDArray[np.float64]:
    """Outputs of a bank of lags, shape ``(..., N, m)``, for inputs ``v`` of shape ``(..., N)``.

    ``state`` holds the carries before the first sample (shape ``(..., m)``; 0, at rest at
    0 V, by default). The carry remembers the last input too: from rest at 0 V the first
    sample's input is taken as reached linearly from 0 over one sample period. The recursion ``z_k = s_{k-1} + b0 v_k``,
    ``s_k = a z_k + b1 v_k`` is an IIR filter with numerator ``(b0, b1)`` and denominator ``(1, -a)`` whose transposed
    direct-form state is the carry, so :func:`scipy.signal.lfilter` runs it.
    """
    from scipy.signal import lfilter

    v = np.asarray(v, dtype=float)
    if v.ndim == 0 or v.shape[-1] == 0:
        raise InputError(f"v must have at least one sample on its last axis, got shape {v.shape}.")
    m = coefficients.a.size
    batch = v.shape[:-1]
    s0 = np.zeros(batch + (m,)) if state is None else np.broadcast_to(np.asarray(state, float), batch + (m,))
    out = np.empty(batch + (v.shape[-1], m))
    for j in range(m):
        b = [coefficients.b0[j], coefficients.b1[j]]
        out[..., j], _ = lfilter(b, [1.0, -coefficients.a[j]], v, axis=-1, zi=s0[..., j : j + 1])
    return out


@dataclass(frozen=True, eq=False)
class Creep:
    """A bank of linear creep operators on the input: ``C[v] = sum_j c_j L_j[v]``.

    ``L_j`` is the first-order lag ``tau_j dL_j/dt = v - L_j`` (unit static gain), sampled
    exactly every ``sample_period_s`` for an input linear between samples
    (:class:`LagCoefficients`). After a step of the input, ``C`` grows by ``c_j`` times the
    step over about ``tau_j``: with nonnegative weights on log-spaced time constants it is the
    usual fit of logarithmic creep. The hysteresis part carries the instantaneous response;
    ``sum_j c_j`` is what creep adds once it has settled.

    Parameters
    ----------
    time_constants_s : array_like, shape (m,)
        Strictly increasing positive time constants ``tau_j`` in s.
    weights : array_like, shape (m,)
        ``c_j`` in output units per input unit.
    sample_period_s : float
        The sample period the model runs at; :meth:`with_sample_period` resamples it exactly.
    """

    time_constants_s: NDArray[np.float64]
    weights: NDArray[np.float64]
    sample_period_s: float

    def __post_init__(self) -> None:
        try:
            tau = vector("creep time_constants_s", self.time_constants_s)
            c = vector("creep weights", self.weights)
        except ValueError as exc:
            raise InputError(str(exc)) from exc
        if np.any(tau <= 0):
            raise InputError(f"creep time_constants_s must be > 0 s, got {tau.tolist()}.")
        if np.any(np.diff(tau) <= 0):
            raise InputError(f"creep time_constants_s must be strictly increasing, got {tau.tolist()}.")
        if c.shape != tau.shape:
            raise InputError(f"creep weights must have {tau.size} entries like time_constants_s, got {c.size}.")
        dt = float(self.sample_period_s)
        if not (np.isfinite(dt) and dt > 0):
            raise InputError("creep sample_period_s must be a positive number of seconds, "
                             f"got {self.sample_period_s!r}.")
        object.__setattr__(self, "time_constants_s", tau)
        object.__setattr__(self, "weights", c)
        object.__setattr__(self, "sample_period_s", dt)

    @property
    def n_lags(self) -> int:
        return int(self.time_constants_s.size)

    @property
    def coefficients(self) -> LagCoefficients:
        return lag_coefficients(self.time_constants_s, self.sample_period_s)

    @property
    def instantaneous_gain(self) -> float:
        """``sum_j c_j b0_j``: what this sample's input adds to this sample's creep output."""
        return float(self.weights @ self.coefficients.b0)

    def initial_state(self, batch: tuple[int, ...] = (), v0: ArrayLike = 0.0) -> NDArray[np.float64]:
        """Carries of lags at rest at input ``v0``, shape ``batch + (m,)``."""
        v0 = np.broadcast_to(np.asarray(v0, float), batch)
        return np.asarray((1.0 - self.coefficients.b0) * v0[..., None], np.float64)  # batch + (m,): an array

    def lags(self, v: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        """The lag outputs ``L_j[v]``, shape ``(..., N, m)`` (see :func:`creep_lags`)."""
        return creep_lags(v, self.coefficients, state)

    def carry(self, lags: ArrayLike, v: ArrayLike) -> NDArray[np.float64]:
        """The state after a sample whose lag outputs are ``lags`` (..., m) and input ``v`` (...)."""
        k = self.coefficients
        return np.asarray(k.a * np.asarray(lags, float) + k.b1 * np.asarray(v, float)[..., None], np.float64)

    def __call__(self, v: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        """``C[v]``, shape (..., N)."""
        return self.lags(v, state) @ self.weights

    def with_sample_period(self, sample_period_s: float) -> Creep:
        """The same continuous-time creep sampled every ``sample_period_s`` (exact)."""
        return Creep(self.time_constants_s, self.weights, sample_period_s)

    def to_dict(self) -> dict[str, Any]:
        return {
            "time_constants_s": self.time_constants_s.tolist(),
            "weights": self.weights.tolist(),
            "sample_period_s": self.sample_period_s,
        }

#: what a model kind with creep ends in (``"classical+creep"``)
CREEP_SUFFIX = "+creep"


@dataclass(frozen=True, eq=False)
class CreepPI:
    """A P-I model with creep: the classical, the paper's asymmetric or the modified model plus :class:`Creep`.

    * classical: ``O = sum_k w_k F_{r_k}[v] + C[v] + offset``;
    * paper-asymmetric: ``O = sum_k (p w_rise_k + q w_fall_k) F_{r_k}[v] + C[v] + offset``;
    * modified: ``O = S(sum_k w_k F_{r_k}[v] + C[v] + bias) + offset``: the creep joins the
      play operators inside the dead-zone superposition ``S``, as in Kuhnen's modified model
      with creep, so the model stays linear in its weights in the QP's inverse form.

    One sample at a time the creep is ``C_k = sum_j c_j s_{j,k-1} + beta v_k`` with the carries
    ``s`` of the last sample and ``beta = sum_j c_j b0_j`` (:attr:`Creep.instantaneous_gain`):
    this sample's input enters linearly, alongside the linear operator ``F_0[v] = v``. So the
    one-sample map from ``v_k`` to the output is the P-I model with the weights
    ``(w_1 + beta, w_2, ..., w_n)`` and an offset known from the state, and its analytic
    inverse, eqs. (19)-(20), applies sample by sample (:class:`InverseCreepPI`).

    The state is ``[play operator outputs (n), creep carries (m)]``, zero at rest at 0 V.
    """

    hysteresis: ClassicalPI | AsymmetricPI | ModifiedPI
    creep: Creep
    kind: str = field(default="", init=False)

    def __post_init__(self) -> None:
        if not isinstance(self.hysteresis, ClassicalPI | AsymmetricPI | ModifiedPI):
            raise InputError(
                "hysteresis must be a ClassicalPI, AsymmetricPI or ModifiedPI, "
                f"got {type(self.hysteresis).__name__}."
            )
        if not isinstance(self.creep, Creep):
            raise InputError(f"creep must be a Creep, got {type(self.creep).__name__}.")
        object.__setattr__(self, "kind", self.hysteresis.kind + CREEP_SUFFIX)

    @property
    def n_operators(self) -> int:
        return self.hysteresis.n_operators

    @property
    def n_lags(self) -> int:
        return self.creep.n_lags

    @property
    def thresholds(self) -> NDArray[np.float64]:
        return self.hysteresis.thresholds

    @property
    def offset(self) -> float:
        return self.hysteresis.offset

    @property
    def sample_period_s(self) -> float:
        return self.creep.sample_period_s

    @property
    def one_sample_weights(self) -> NDArray[np.float64]:
        """Weights of the one-sample P-I map: ``w`` with ``w_1 + beta`` (classical and modified)."""
        if isinstance(self.hysteresis, AsymmetricPI):
            raise NotInvertibleError("the paper's direction-switched model has no one-sample P-I map to invert.")
        w = self.hysteresis.weights.copy()
        w[0] += self.creep.instantaneous_gain
        return w

    @property
    def invertible(self) -> bool:
        h = self.hysteresis
        if isinstance(h, AsymmetricPI):
            return False
        ok = bool(np.all(np.cumsum(self.one_sample_weights) > 0))
        return ok and (h.shaper.invertible if isinstance(h, ModifiedPI) else True)

    def with_sample_period(self, sample_period_s: float) -> CreepPI:
        """The same model at another sample period: the hysteresis is rate-independent, the lags resampled exactly."""
        return CreepPI(self.hysteresis, self.creep.with_sample_period(sample_period_s))

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray[np.float64]:
        """At rest at 0 V: zeros of shape ``batch + (n + m,)``."""
        return np.zeros(batch + (self.n_operators + self.n_lags,))

    def _split(self, state: ArrayLike | None,
               batch: tuple[int, ...]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        n, m = self.n_operators, self.n_lags
        if state is None:
            return np.zeros(batch + (n,)), np.zeros(batch + (m,))
        x = np.asarray(state, float)
        if x.shape[-1:] != (n + m,):
            raise InputError(
                f"a {self.kind} state has {n + m} entries (n={n} play operators, then m={m} creep carries) "
                f"on its last axis, got shape {x.shape}."
            )
        return x[..., :n], x[..., n:]

    def _pre(self, ops: NDArray[np.float64], creep: NDArray[np.float64], v: NDArray[np.float64],
             v_prev: ArrayLike) -> NDArray[np.float64]:
        h = self.hysteresis
        pre: NDArray[np.float64]
        if isinstance(h, AsymmetricPI):
            p = rising(v, v_prev)
            pre = np.where(p, ops @ h.weights_rising, ops @ h.weights_falling) + creep
        else:
            pre = ops @ h.weights + creep + (h.bias if isinstance(h, ModifiedPI) else 0.0)
        return pre

    def _out(self, pre: NDArray[np.float64]) -> NDArray[np.float64]:
        h = self.hysteresis
        return (h.shaper(pre) if isinstance(h, ModifiedPI) else pre) + h.offset

    def run(
        self, v: ArrayLike, state: ArrayLike | None = None, v_prev: ArrayLike = 0.0
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Output for input ``v`` of shape (..., N) from ``state``, and the state after the last sample.

        ``v_prev`` is the input before the first sample (the asymmetric model's direction).
        """
        v = np.asarray(v, dtype=float)
        y0, s0 = self._split(state, v.shape[:-1])
        ops = play(v, self.thresholds, y0)
        lags = self.creep.lags(v, s0)
        out = self._out(self._pre(ops, lags @ self.creep.weights, v, v_prev))
        final = np.concatenate([ops[..., -1, :], self.creep.carry(lags[..., -1, :], v[..., -1])], axis=-1)
        return out, final

    def __call__(self, v: ArrayLike, state: ArrayLike | None = None, v_prev: ArrayLike = 0.0) -> NDArray[np.float64]:
        """Output for input ``v`` of shape (..., N), from ``state`` (at rest at 0 V by default)."""
        return self.run(v, state, v_prev)[0]

    def step(self, state: ArrayLike, v: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """One sample of the classical or modified model: ``(output, new_state)``."""
        if isinstance(self.hysteresis, AsymmetricPI):
            raise InputError("step needs the classical or the modified model; "
                             "run the asymmetric one with run(v, state, v_prev).")
        v = np.asarray(v, dtype=float)
        y_prev, s_prev = self._split(state, v.shape)
        k = self.creep.coefficients
        y = play_step(y_prev, v, self.thresholds)
        lags = s_prev + k.b0 * v[..., None]
        out = self._out(self._pre(y, lags @ self.creep.weights, v, 0.0))
        return out, np.concatenate([y, self.creep.carry(lags, v)], axis=-1)

    def inverse_spec(self) -> InverseSpec:
        """The hysteresis model's one-sample map with the creep's one-sample gain in its linear weight, and the
        creep bank's coefficients at :attr:`sample_period_s`."""
        k = self.creep.coefficients
        spec = self.hysteresis.inverse_spec(self.creep.instantaneous_gain)
        return replace(spec, what=spec.what + " with creep (its linear weight plus the creep's one-sample gain)",
                       creep_weights=self.creep.weights, creep_decay=k.a, creep_input=k.e)

    def inverse(self) -> InverseCreepPI:
        """The inverse, one sample at a time (:class:`InverseStep`); exact for the classical and the modified
        model, direction-switched for the paper's asymmetric one (exact where its output is reachable)."""
        inverse = InverseCreepPI(forward=self)
        inverse.realtime()  # raises NotInvertibleError with the reason
        return inverse

    def to_dict(self) -> dict[str, Any]:
        return {**self.hysteresis.to_dict(), "kind": self.kind, "creep": self.creep.to_dict()}



def inverse_at(model: HysteresisModel | CreepPI, sample_period_s: float) -> Any:
    """``model.inverse()`` for a loop sampled every ``sample_period_s``: a creep bank is resampled exactly first.

    The hysteresis is rate-independent; only the lags' coefficients depend on the period.
    """
    if isinstance(model, CreepPI) and model.sample_period_s != float(sample_period_s):
        model = model.with_sample_period(sample_period_s)
    return model.inverse()
