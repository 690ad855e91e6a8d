"""Prandtl-Ishlinskii hysteresis: play operators, P-I models and their analytic inverses.

Section 3.2 of Zhang, Jin, Lin (2021), restated in ``docs/models.md`` (section 2):

* the play operator, eq. (14);
* the classical P-I model, eq. (15), with a linear term (threshold 0) and an output offset;
* the paper's direction-switched asymmetric model, eq. (18);
* Kuhnen's modified P-I model (play operators followed by a superposition of one-sided
  dead-zone operators, K. Kuhnen, Eur. J. Control 9(4), 2003), which describes asymmetric
  loops and keeps an exact analytic inverse;
* the analytic inverses, eqs. (19)-(20);
* creep: a bank of first-order lags on the input (Kuhnen's linear creep operators) added to
  any of the three models (:class:`CreepPI`);
* the real-time inverse of every one of them, with or without creep: one one-sample step
  (:class:`InverseStep`, over the ops table of :mod:`piezopreload.models.ops`) that the
  numpy simulation, the compiled rig step and the exported C code all run.

Everything here is pure: parameters are frozen dataclasses that validate themselves, the
functions take explicit initial states and return final states, nothing is printed or read.
Arrays broadcast over leading batch dimensions: an input of shape ``(..., N)`` gives operator
outputs of shape ``(..., N, n)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezopreload.core.errors import InputError, InternalError
from piezopreload.models.ops import CASADI, NUMPY, Layout, Ops

__all__ = [
    "NotInvertibleError",
    "play",
    "play_step",
    "rising",
    "deadzone",
    "ClassicalPI",
    "InverseClassicalPI",
    "AsymmetricPI",
    "InverseAsymmetricPI",
    "DeadZone",
    "ModifiedPI",
    "InverseModifiedPI",
    "uniform_thresholds",
    "model_from_dict",
    "log_spaced_time_constants",
    "LagCoefficients",
    "lag_coefficients",
    "creep_lags",
    "Creep",
    "CreepPI",
    "InverseCreepPI",
    "InverseStep",
    "inverse_realtime",
    "inverse_at",
]


class NotInvertibleError(InputError):
    """The model has no exact inverse (a partial sum of its weights is not positive)."""


# --------------------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------------------
def _vector(name: str, value: ArrayLike, *, min_len: int = 1) -> NDArray[np.float64]:
    arr = np.array(value, dtype=float, copy=True)
    if arr.ndim != 1 or arr.size < min_len:
        raise ValueError(
            f"{name} must be a 1-D sequence of at least {min_len} numbers, got shape {arr.shape}."
        )
    if not np.all(np.isfinite(arr)):
        bad = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise ValueError(f"{name}[{bad}] is {arr[bad]}; all entries must be finite.")
    arr.setflags(write=False)
    return arr


def _scalar(name: str, value: float) -> float:
    x = float(value)
    if not np.isfinite(x):
        raise ValueError(f"{name} must be finite, got {value!r}.")
    return x


def _check_thresholds(name: str, r: NDArray[np.float64]) -> None:
    if r[0] != 0.0:
        raise ValueError(f"{name}[0] must be 0 (the linear term), got {r[0]}.")
    if np.any(np.diff(r) <= 0):
        k = int(np.flatnonzero(np.diff(r) <= 0)[0]) + 1
        raise ValueError(
            f"{name} must be strictly increasing; {name}[{k}] = {r[k]} <= {name}[{k - 1}] = {r[k - 1]}."
        )


def uniform_thresholds(n: int, reach: float) -> NDArray[np.float64]:
    """Thresholds ``r_k = (k - 1) / n * reach``, k = 1..n: eq. (16) of the paper with ``reach = v_max``.

    For play operators that start at rest (output 0), ``reach`` should be the largest input
    magnitude ``max |v|``; each operator then moves at least once.
    """
    if int(n) != n or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}.")
    if not np.isfinite(reach) or reach <= 0:
        raise ValueError(f"reach must be positive and finite, got {reach!r}.")
    return np.arange(int(n), dtype=float) / int(n) * float(reach)


# --------------------------------------------------------------------------------------
# the play operator, eq. (14)
# --------------------------------------------------------------------------------------
def play_step(y_prev: ArrayLike, v: ArrayLike, thresholds: ArrayLike) -> NDArray[np.float64]:
    """One sample of a bank of play operators, eq. (14).

    ``y = max(v - r, min(v + r, y_prev))``, broadcast: ``y_prev`` has shape ``(..., n)``,
    ``v`` shape ``(...)``, ``thresholds`` shape ``(n,)``.
    """
    r = np.asarray(thresholds, dtype=float)
    v = np.asarray(v, dtype=float)[..., None]
    return np.maximum(v - r, np.minimum(v + r, y_prev))


def _play_1d(v: NDArray, r: NDArray, y0: NDArray, out: NDArray) -> None:
    """Play-operator bank on one signal, by monotone segments.

    On a segment where the input does not fall, eq. (14) reduces to ``y_i = max(y_s, v_i - r)``
    with ``y_s`` the state entering the segment (``v_i + r >= v_{i-1} + r >= y_{i-1}``); where it
    does not rise, ``y_i = min(y_s, v_i + r)``. So one vectorised operation per segment replaces
    a Python loop over samples: exact, and fast for the smooth inputs of identification.
    """
    n_samples = v.shape[0]
    out[0] = np.maximum(v[0] - r, np.minimum(v[0] + r, y0))
    if n_samples == 1:
        return
    direction = np.sign(np.diff(v))
    # a flat sample leaves every operator where it is: give it the previous direction
    nonzero = direction != 0
    if not nonzero.any():
        out[1:] = out[0]
        return
    idx = np.where(nonzero, np.arange(direction.size), 0)
    np.maximum.accumulate(idx, out=idx)
    direction = direction[idx]
    direction[: np.flatnonzero(nonzero)[0]] = 1.0
    starts = np.flatnonzero(np.diff(direction)) + 1
    bounds = np.concatenate(([0], starts, [direction.size])) + 1  # sample indices
    y = out[0]
    for a, b in zip(bounds[:-1], bounds[1:]):
        seg = v[a:b, None]
        if direction[a - 1] > 0:
            np.maximum(seg - r, y, out=out[a:b])
        else:
            np.minimum(seg + r, y, out=out[a:b])
        y = out[b - 1]


def play(
    v: ArrayLike, thresholds: ArrayLike, y0: ArrayLike | None = None
) -> NDArray[np.float64]:
    """Outputs of a bank of play operators, eq. (14) of the paper.

    Parameters
    ----------
    v : array_like, shape (..., N)
        Input signal(s); leading dimensions are independent signals.
    thresholds : array_like, shape (n,)
        Nonnegative thresholds ``r_k``.
    y0 : array_like, shape (..., n), optional
        Operator states before the first sample; 0 (at rest) by default.

    Returns
    -------
    ndarray, shape (..., N, n)
        ``y[..., i, k] = F_{r_k}[v](t_i)``; the final state is ``y[..., -1, :]``.
    """
    v = np.asarray(v, dtype=float)
    r = np.asarray(thresholds, dtype=float)
    if r.ndim != 1:
        raise ValueError(f"thresholds must be 1-D, got shape {r.shape}.")
    if np.any(r < 0):
        raise ValueError("thresholds must be nonnegative.")
    if v.ndim == 0 or v.shape[-1] == 0:
        raise ValueError(f"v must have at least one sample on its last axis, got shape {v.shape}.")
    batch = v.shape[:-1]
    n_samples = v.shape[-1]
    y0 = np.zeros(batch + r.shape) if y0 is None else np.broadcast_to(np.asarray(y0, float), batch + r.shape)
    out = np.empty(batch + (n_samples, r.size))
    flat_v = v.reshape(-1, n_samples)
    flat_y0 = y0.reshape(-1, r.size)
    flat_out = out.reshape(-1, n_samples, r.size)
    reversals = np.count_nonzero(np.diff(np.sign(np.diff(flat_v, axis=-1)), axis=-1))
    if flat_v.shape[0] > 1 and reversals > n_samples:
        # many noisy signals: one vectorised step per sample over the whole batch is cheaper
        y = flat_y0
        for i in range(n_samples):
            y = play_step(y, flat_v[:, i], r)
            flat_out[:, i] = y
    else:
        for j in range(flat_v.shape[0]):
            _play_1d(flat_v[j], r, flat_y0[j], flat_out[j])
    return out


# --------------------------------------------------------------------------------------
# P-I weights and their inverse, eqs. (19)-(20)
# --------------------------------------------------------------------------------------
def _inverse_weights(
    r: NDArray[np.float64], w: NDArray[np.float64], what: str
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Thresholds and weights of the inverse of a superposition, eqs. (19)-(20).

    ``r'_k = sum_{i<=k} w_i (r_k - r_i)``, ``w'_1 = 1/w_1``,
    ``w'_k = -w_k / (W_k W_{k-1})`` with the partial sums ``W_k = w_1 + ... + w_k``.
    The same algebra inverts a play-operator P-I model and a one-sided dead-zone superposition.
    """
    partial = np.cumsum(w)
    if np.any(partial <= 0):
        k = int(np.flatnonzero(partial <= 0)[0])
        raise NotInvertibleError(
            f"{what} is not invertible: the partial sum of weights w_1 + ... + w_{k + 1} = "
            f"{partial[k]:.6g} must be > 0 (the model's slope on that segment). Identify with "
            "nonnegative weights and a positive linear term, or with the modified model's "
            "invertibility constraints."
        )
    r_inv = partial * r - np.cumsum(w * r)
    w_inv = np.empty_like(w)
    w_inv[0] = 1.0 / w[0]
    w_inv[1:] = -w[1:] / (partial[1:] * partial[:-1])
    return r_inv, w_inv


def inverse_at(model: Any, sample_period_s: float) -> Any:
    """``model.inverse()`` for a loop sampled every ``sample_period_s``: a creep bank is resampled exactly first.

    The hysteresis is rate-independent; only the lags' coefficients depend on the period.
    """
    if isinstance(model, CreepPI) and model.sample_period_s != float(sample_period_s):
        model = model.with_sample_period(sample_period_s)
    return model.inverse()


class _RealTimeInverse:
    """What every inverse model shares: :class:`InverseStep` with the forward model's numbers.

    Its state is the forward model's (play operator outputs, creep carries, the last input of
    the asymmetric model): zeros at rest at 0 V, and any state the forward model left.
    """

    forward: Any

    @cached_property
    def _realtime(self) -> tuple[InverseStep, NDArray[np.float64]]:
        return inverse_realtime(self.forward)

    def realtime(self) -> tuple[InverseStep, NDArray[np.float64]]:
        """The controller's feedforward component: the step's structure and its parameter vector."""
        structure, params = self._realtime
        return structure, params.copy()

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray[np.float64]:
        """At rest at 0 V: zeros of shape ``batch + (n_states,)``."""
        return np.zeros(batch + (self._realtime[0].n_states,))

    def step(self, state: ArrayLike, target: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """One sample (numpy, batched): the input that makes the forward model output ``target``, and the next state."""
        structure, params = self._realtime
        v, nxt = structure.step(NUMPY, params, np.asarray(state, float), np.asarray(target, float))
        return np.asarray(v, float), np.asarray(nxt, float)

    def casadi_step(self, state: Any, target: Any) -> tuple[Any, Any]:
        """:meth:`step` on CasADi expressions (one loop), the model's numbers as constants."""
        structure, params = self._realtime
        return structure.step(CASADI, ca.DM(params), state, target)

    def run(self, target: ArrayLike, state: ArrayLike | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Inputs for the targets of shape (..., N), sample by sample from ``state`` (at rest by default), and the final state."""
        target = np.asarray(target, dtype=float)
        x = self.initial_state(target.shape[:-1]) if state is None else np.asarray(state, float)
        out = np.empty(target.shape)
        for k in range(target.shape[-1]):
            out[..., k], x = self.step(x, target[..., k])
        return out, x


# --------------------------------------------------------------------------------------
# the classical P-I model, eq. (15)
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ClassicalPI:
    """Classical Prandtl-Ishlinskii model, eq. (15): ``O = sum_k w_k F_{r_k}[v] + offset``.

    Parameters
    ----------
    thresholds : array_like, shape (n,)
        ``0 = r_1 < r_2 < ... < r_n`` in input units; ``r_1 = 0`` is the linear term.
    weights : array_like, shape (n,)
        ``w_k`` in output units per input unit.
    offset : float
        Output when every operator is at rest (state 0).
    """

    thresholds: NDArray[np.float64]
    weights: NDArray[np.float64]
    offset: float = 0.0
    kind: str = field(default="classical", init=False)

    def __post_init__(self) -> None:
        r = _vector("thresholds", self.thresholds)
        w = _vector("weights", self.weights)
        _check_thresholds("thresholds", r)
        if w.shape != r.shape:
            raise ValueError(f"weights must have {r.size} entries like thresholds, got {w.size}.")
        object.__setattr__(self, "thresholds", r)
        object.__setattr__(self, "weights", w)
        object.__setattr__(self, "offset", _scalar("offset", self.offset))

    @property
    def n_operators(self) -> int:
        return int(self.thresholds.size)

    @property
    def invertible(self) -> bool:
        return bool(np.all(np.cumsum(self.weights) > 0))

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray[np.float64]:
        """Operators at rest: zeros of shape ``batch + (n,)``."""
        return np.zeros(batch + (self.n_operators,))

    def __call__(self, v: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        """Output for input ``v`` of shape (..., N), from ``state`` (at rest by default)."""
        return play(v, self.thresholds, state) @ self.weights + self.offset

    def step(self, state: NDArray, v: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """One sample: returns ``(output, new_state)``; state shape (..., n)."""
        y = play_step(state, v, self.thresholds)
        return y @ self.weights + self.offset, y

    def inverse(self) -> InverseClassicalPI:
        """The analytic inverse, eqs. (19)-(20): a P-I model from output to input."""
        r_inv, w_inv = _inverse_weights(self.thresholds, self.weights, "this P-I model")
        return InverseClassicalPI(forward=self, thresholds=r_inv, weights=w_inv)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "thresholds": self.thresholds.tolist(),
            "weights": self.weights.tolist(),
            "offset": self.offset,
        }


@dataclass(frozen=True, eq=False)
class InverseClassicalPI(_RealTimeInverse):
    """Inverse of a :class:`ClassicalPI`: ``v = sum_k w'_k F_{r'_k}[O - offset]``, eqs. (19)-(20).

    Built by :meth:`ClassicalPI.inverse`. Called on a whole signal it runs the inverse
    operators, whose states relate to the forward ones by ``z_k = W_k y_k + sum_{i>k} w_i y_i``
    (``W_k`` the partial sums of the forward weights; :meth:`state_from_forward`), so it can
    start from any forward state. One sample at a time (:meth:`step`, :meth:`realtime`: the
    controller's feedforward) it is :class:`InverseStep`, whose state is the forward
    operators' own.
    """

    forward: ClassicalPI
    thresholds: NDArray[np.float64]
    weights: NDArray[np.float64]

    def state_from_forward(self, y: ArrayLike) -> NDArray[np.float64]:
        """Inverse-operator states equivalent to forward operator states ``y`` (..., n)."""
        y = np.asarray(y, dtype=float)
        w = self.forward.weights
        partial = np.cumsum(w)
        weighted = y * w
        tail = np.cumsum(weighted[..., ::-1], axis=-1)[..., ::-1]  # sum_{i>=k} w_i y_i
        return partial * y + tail - weighted

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray[np.float64]:
        return np.zeros(batch + (self.thresholds.size,))

    def __call__(self, target: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        """Input that makes the forward model output ``target`` (shape (..., N))."""
        z = np.asarray(target, dtype=float) - self.forward.offset
        return play(z, self.thresholds, state) @ self.weights


# --------------------------------------------------------------------------------------
# the paper's direction-switched asymmetric model, eq. (18)
# --------------------------------------------------------------------------------------
def rising(v: ArrayLike, v_prev: ArrayLike = 0.0) -> NDArray[np.bool_]:
    """``p`` of eq. (18): True where the input does not fall, ``v_i >= v_{i-1}`` (``v_{-1} = v_prev``)."""
    v = np.asarray(v, dtype=float)
    first = np.broadcast_to(np.asarray(v_prev, float), v.shape[:-1])[..., None]
    return v >= np.concatenate([first, v[..., :-1]], axis=-1)


@dataclass(frozen=True, eq=False)
class AsymmetricPI:
    """The paper's asymmetric P-I model, eq. (18).

    ``O(t_i) = sum_k (p w_rise_k + q w_fall_k) F_{r_k}[v](t_i) + offset`` with ``(p, q) = (1, 0)``
    while the input rises (``v_i >= v_{i-1}``) and ``(0, 1)`` while it falls.

    The output jumps by ``sum_k (w_rise_k - w_fall_k) F_{r_k}`` at every reversal of the input,
    so some outputs next to a reversal cannot be reached by any input: the model has no exact
    inverse everywhere (:attr:`invertible` is False); :meth:`inverse` is exact where the output is
    reachable and holds the input in the gaps. :class:`ModifiedPI` is the asymmetric model with
    an exact inverse. The state holds the operator outputs and the previous input
    (``v_{-1} = 0`` at rest).
    """

    thresholds: NDArray[np.float64]
    weights_rising: NDArray[np.float64]
    weights_falling: NDArray[np.float64]
    offset: float = 0.0
    kind: str = field(default="paper-asymmetric", init=False)

    def __post_init__(self) -> None:
        r = _vector("thresholds", self.thresholds)
        _check_thresholds("thresholds", r)
        for name in ("weights_rising", "weights_falling"):
            w = _vector(name, getattr(self, name))
            if w.shape != r.shape:
                raise ValueError(f"{name} must have {r.size} entries like thresholds, got {w.size}.")
            object.__setattr__(self, name, w)
        object.__setattr__(self, "thresholds", r)
        object.__setattr__(self, "offset", _scalar("offset", self.offset))

    @property
    def n_operators(self) -> int:
        return int(self.thresholds.size)

    invertible = False

    def __call__(self, v: ArrayLike, state: ArrayLike | None = None, v_prev: float = 0.0) -> NDArray[np.float64]:
        y = play(v, self.thresholds, state)
        p = rising(v, v_prev)
        return np.where(p, y @ self.weights_rising, y @ self.weights_falling) + self.offset

    def inverse(self) -> InverseAsymmetricPI:
        """The direction-switched inverse (:class:`InverseStep`): exact where the output is reachable.

        The output jumps by ``sum_k (w_rise_k - w_fall_k) F_{r_k}`` at every reversal of the
        input, so next to a reversal some outputs no input reaches; there the inverse holds the
        last input. Raises :class:`NotInvertibleError` if a partial sum of either weight set is
        not positive.
        """
        inverse = InverseAsymmetricPI(forward=self)
        inverse.realtime()  # checks both weight sets
        return inverse

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "thresholds": self.thresholds.tolist(),
            "weights_rising": self.weights_rising.tolist(),
            "weights_falling": self.weights_falling.tolist(),
            "offset": self.offset,
        }


# --------------------------------------------------------------------------------------
# one-sided dead-zone operators and Kuhnen's modified P-I model
# --------------------------------------------------------------------------------------
def deadzone(z: ArrayLike, thresholds: ArrayLike) -> NDArray[np.float64]:
    """One-sided dead-zone operators ``S_d(z)``, shape ``z.shape + (m,)``.

    ``S_d(z) = max(z - d, 0)`` for ``d > 0``, ``z`` for ``d = 0``, ``min(z - d, 0)`` for ``d < 0``.
    """
    z = np.asarray(z, dtype=float)[..., None]
    d = np.asarray(thresholds, dtype=float)
    return np.where(d > 0, np.maximum(z - d, 0.0), np.where(d < 0, np.minimum(z - d, 0.0), z))


@dataclass(frozen=True, eq=False)
class DeadZone:
    """Superposition of one-sided dead-zone operators: ``S(z) = sum_j u_j S_{d_j}(z)``.

    Thresholds ``d_{-m} < ... < d_0 = 0 < ... < d_m`` (any count on either side, exactly one
    zero). Strictly increasing, and so exactly invertible, when every partial sum of weights
    taken from ``d_0`` outwards is positive: those sums are the slopes of ``S``.
    """

    thresholds: NDArray[np.float64]
    weights: NDArray[np.float64]

    def __post_init__(self) -> None:
        d = _vector("deadzone_thresholds", self.thresholds)
        u = _vector("deadzone_weights", self.weights)
        if np.any(np.diff(d) <= 0):
            raise ValueError("deadzone_thresholds must be strictly increasing.")
        if np.count_nonzero(d == 0) != 1:
            raise ValueError("deadzone_thresholds must contain exactly one 0 (the linear element).")
        if u.shape != d.shape:
            raise ValueError(f"deadzone_weights must have {d.size} entries, got {u.size}.")
        object.__setattr__(self, "thresholds", d)
        object.__setattr__(self, "weights", u)

    @property
    def center(self) -> int:
        return int(np.flatnonzero(self.thresholds == 0)[0])

    def slopes(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Partial sums outwards: slopes on ``[d_j, d_{j+1})`` (positive side) and ``(d_{-j-1}, d_{-j}]``."""
        c = self.center
        return np.cumsum(self.weights[c:]), np.cumsum(self.weights[c::-1])

    @property
    def invertible(self) -> bool:
        up, down = self.slopes()
        return bool(np.all(up > 0) and np.all(down > 0))

    def __call__(self, z: ArrayLike) -> NDArray[np.float64]:
        return deadzone(z, self.thresholds) @ self.weights

    def inverse(self) -> DeadZone:
        """The inverse superposition, by eqs. (19)-(20) applied to each side of ``d_0``."""
        c = self.center
        d, u = self.thresholds, self.weights
        d_up, u_up = _inverse_weights(d[c:], u[c:], "the dead-zone superposition (positive side)")
        d_dn, u_dn = _inverse_weights(-d[c::-1], u[c::-1], "the dead-zone superposition (negative side)")
        return DeadZone(
            thresholds=np.concatenate([-d_dn[:0:-1], d_up]),
            weights=np.concatenate([u_dn[:0:-1], u_up]),
        )


@dataclass(frozen=True, eq=False)
class ModifiedPI:
    """Kuhnen's modified P-I model for asymmetric loops, with an exact analytic inverse.

    ``O = S(sum_k w_k F_{r_k}[v] + bias) + offset`` where ``S`` is a :class:`DeadZone`
    superposition (memoryless, piecewise linear) that bends the symmetric loops of the
    play operators into asymmetric ones (K. Kuhnen, "Modeling, identification and compensation
    of complex hysteretic nonlinearities: a modified Prandtl-Ishlinskii approach",
    Eur. J. Control 9(4):407-418, 2003). Its inverse is the inverse P-I model after the inverse
    dead-zone superposition, both analytic.
    """

    thresholds: NDArray[np.float64]
    weights: NDArray[np.float64]
    deadzone_thresholds: NDArray[np.float64]
    deadzone_weights: NDArray[np.float64]
    bias: float = 0.0
    offset: float = 0.0
    kind: str = field(default="modified", init=False)

    def __post_init__(self) -> None:
        pi = ClassicalPI(self.thresholds, self.weights, 0.0)
        dz = DeadZone(self.deadzone_thresholds, self.deadzone_weights)
        object.__setattr__(self, "thresholds", pi.thresholds)
        object.__setattr__(self, "weights", pi.weights)
        object.__setattr__(self, "deadzone_thresholds", dz.thresholds)
        object.__setattr__(self, "deadzone_weights", dz.weights)
        object.__setattr__(self, "bias", _scalar("bias", self.bias))
        object.__setattr__(self, "offset", _scalar("offset", self.offset))

    @property
    def n_operators(self) -> int:
        return int(self.thresholds.size)

    @property
    def play_model(self) -> ClassicalPI:
        return ClassicalPI(self.thresholds, self.weights, self.bias)

    @property
    def shaper(self) -> DeadZone:
        return DeadZone(self.deadzone_thresholds, self.deadzone_weights)

    @property
    def invertible(self) -> bool:
        return self.play_model.invertible and self.shaper.invertible

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray[np.float64]:
        return np.zeros(batch + (self.n_operators,))

    def __call__(self, v: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        return self.shaper(self.play_model(v, state)) + self.offset

    def step(self, state: NDArray, v: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        z, y = self.play_model.step(state, v)
        return self.shaper(z) + self.offset, y

    def inverse(self) -> InverseModifiedPI:
        return InverseModifiedPI(
            forward=self, play_inverse=self.play_model.inverse(), shaper_inverse=self.shaper.inverse()
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "thresholds": self.thresholds.tolist(),
            "weights": self.weights.tolist(),
            "deadzone_thresholds": self.deadzone_thresholds.tolist(),
            "deadzone_weights": self.deadzone_weights.tolist(),
            "bias": self.bias,
            "offset": self.offset,
        }


@dataclass(frozen=True, eq=False)
class InverseModifiedPI(_RealTimeInverse):
    """Inverse of a :class:`ModifiedPI`: ``v = Gamma^-1[S^-1(O - offset)]``."""

    forward: ModifiedPI
    play_inverse: InverseClassicalPI
    shaper_inverse: DeadZone

    def state_from_forward(self, y: ArrayLike) -> NDArray[np.float64]:
        return self.play_inverse.state_from_forward(y)

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray[np.float64]:
        return self.play_inverse.initial_state(batch)

    def __call__(self, target: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        z = self.shaper_inverse(np.asarray(target, dtype=float) - self.forward.offset)
        return self.play_inverse(z, state)


# --------------------------------------------------------------------------------------
# (de)serialisation: plain dicts, the artifact layer adds the envelope
# --------------------------------------------------------------------------------------
_FIELDS = {
    "classical": (ClassicalPI, ("thresholds", "weights", "offset")),
    "paper-asymmetric": (AsymmetricPI, ("thresholds", "weights_rising", "weights_falling", "offset")),
    "modified": (
        ModifiedPI,
        ("thresholds", "weights", "deadzone_thresholds", "deadzone_weights", "bias", "offset"),
    ),
}

HysteresisModel = ClassicalPI | AsymmetricPI | ModifiedPI


def model_from_dict(data: dict[str, Any], where: str = "model") -> HysteresisModel | CreepPI:
    """Rebuild a model from :meth:`to_dict` output; errors (:class:`InputError`, a ValueError) name the field.

    A kind ending in ``+creep`` (``"classical+creep"``, ...) is a :class:`CreepPI`: the
    hysteresis model's fields plus a ``creep`` object. Documents written before creep existed
    read as they did.
    """
    if not isinstance(data, dict):
        raise InputError(f"{where} must be an object, got {type(data).__name__}.")
    kind = data.get("kind")
    if isinstance(kind, str) and kind.endswith(_CREEP_SUFFIX) and kind[: -len(_CREEP_SUFFIX)] in _FIELDS:
        return _creep_model_from_dict(data, kind, where)
    if not isinstance(kind, str) or kind not in _FIELDS:
        kinds = sorted(_FIELDS) + sorted(k + _CREEP_SUFFIX for k in _FIELDS)
        raise InputError(f"{where}.kind must be one of {kinds}, got {kind!r}.")
    cls, names = _FIELDS[kind]
    missing = [n for n in names if n not in data]
    if missing:
        raise InputError(f"{where}.{missing[0]} is missing (a {kind} model needs {', '.join(names)}).")
    try:
        return cls(**{n: data[n] for n in names})
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: {exc}") from None


# --------------------------------------------------------------------------------------
# creep: linear creep operators (first-order lags) on the input, and the compound model
# --------------------------------------------------------------------------------------
# Kuhnen's modified P-I model with creep (Eur. J. Control 9(4), 2003) and Krejci & Kuhnen
# (IEE Proc. Control Theory Appl. 148(3), 2001) add to the hysteresis operator a superposition
# of linear creep operators: first-order lags of the input with time constants spread over the
# decades the creep covers, ``C[v] = sum_j c_j L_j[v]``, ``tau_j dL_j/dt = v - L_j``. The
# model stays linear in all its weights, so it is identified by the same QP, and its one-sample
# map stays a P-I model: see :class:`CreepPI`.


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
    sample's input is taken as reached linearly from 0 over one sample period. The recursion ``z_k = s_{k-1} + b0 v_k``, ``s_k = a z_k + b1 v_k`` is an
    IIR filter with numerator ``(b0, b1)`` and denominator ``(1, -a)`` whose transposed
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
            tau = _vector("creep time_constants_s", self.time_constants_s)
            c = _vector("creep weights", self.weights)
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
            raise InputError(f"creep sample_period_s must be a positive number of seconds, got {self.sample_period_s!r}.")
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
        return (1.0 - self.coefficients.b0) * v0[..., None]

    def lags(self, v: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        """The lag outputs ``L_j[v]``, shape ``(..., N, m)`` (see :func:`creep_lags`)."""
        return creep_lags(v, self.coefficients, state)

    def carry(self, lags: ArrayLike, v: ArrayLike) -> NDArray[np.float64]:
        """The state after a sample whose lag outputs are ``lags`` (..., m) and input ``v`` (...)."""
        k = self.coefficients
        return k.a * np.asarray(lags, float) + k.b1 * np.asarray(v, float)[..., None]

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


_CREEP_SUFFIX = "+creep"


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
        object.__setattr__(self, "kind", self.hysteresis.kind + _CREEP_SUFFIX)

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

    def without_creep(self) -> ClassicalPI | AsymmetricPI | ModifiedPI:
        """The hysteresis part alone (the creep's contribution dropped, static gain included)."""
        return self.hysteresis

    def with_sample_period(self, sample_period_s: float) -> CreepPI:
        """The same model at another sample period: the hysteresis is rate-independent, the lags resampled exactly."""
        return CreepPI(self.hysteresis, self.creep.with_sample_period(sample_period_s))

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray[np.float64]:
        """At rest at 0 V: zeros of shape ``batch + (n + m,)``."""
        return np.zeros(batch + (self.n_operators + self.n_lags,))

    def _split(self, state: ArrayLike | None, batch: tuple[int, ...]) -> tuple[NDArray, NDArray]:
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

    def _pre(self, ops: NDArray, creep: NDArray, v: NDArray, v_prev: ArrayLike) -> NDArray:
        h = self.hysteresis
        if isinstance(h, AsymmetricPI):
            p = rising(v, v_prev)
            return np.where(p, ops @ h.weights_rising, ops @ h.weights_falling) + creep
        bias = h.bias if isinstance(h, ModifiedPI) else 0.0
        return ops @ h.weights + creep + bias

    def _out(self, pre: NDArray) -> NDArray:
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
            raise InputError("step needs the classical or the modified model; run the asymmetric one with run(v, state, v_prev).")
        v = np.asarray(v, dtype=float)
        y_prev, s_prev = self._split(state, v.shape)
        k = self.creep.coefficients
        y = play_step(y_prev, v, self.thresholds)
        lags = s_prev + k.b0 * v[..., None]
        out = self._out(self._pre(y, lags @ self.creep.weights, v, 0.0))
        return out, np.concatenate([y, self.creep.carry(lags, v)], axis=-1)

    def inverse(self) -> InverseCreepPI:
        """The inverse, one sample at a time (:class:`InverseStep`); exact for the classical and the modified
        model, direction-switched for the paper's asymmetric one (exact where its output is reachable)."""
        inverse = InverseCreepPI(forward=self)
        inverse.realtime()  # raises NotInvertibleError with the reason
        return inverse

    def to_dict(self) -> dict[str, Any]:
        return {**self.hysteresis.to_dict(), "kind": self.kind, "creep": self.creep.to_dict()}


# --------------------------------------------------------------------------------------
# the inverse's one-sample step: one definition for every model, over the ops table
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class InverseStep:
    """One sample of the inverse of any P-I model here, over an ops table (:mod:`~piezopreload.models.ops`).

    The structure (sizes and whether the weights switch with the direction) is this object; the
    numbers are a parameter vector (:attr:`params`, built by :func:`inverse_realtime`), so one
    compiled step serves every model of one structure. It is the feedforward component of
    :class:`~piezopreload.models.controller.ControllerModel`, and the same code runs on numpy
    (the simulation, the rig's fall-back), on CasADi (the tuning graph, the compiled rig step,
    the exported C code).

    The state is the *forward* model's state (:attr:`state`): the play operator outputs ``y``
    (n), the creep carries ``s`` (m) and, for the paper's asymmetric model, the last input
    ``v_prev``. With ``x = target - offset``, one sample is:

    1. ``P = S^-1(x)``, the inverse dead-zone superposition of the modified model (``x`` for the
       others);
    2. ``g = P - bias - sum_j c_j s_j``: what the one-sample P-I map must give once the creep's
       part known from the last sample is taken off;
    3. for the one-sample weights ``w`` (``w_1`` plus the creep's gain ``beta`` of this sample's
       input, :class:`CreepPI`): the inverse operators' states ``z'_k = W_k y_k + sum_{i>k} w_i
       y_i`` (``W`` the partial sums), ``z' = max(g - r', min(g + r', z'))`` and
       ``v = sum w' z'``: eqs. (19)-(20);
    4. the asymmetric model does 3. with the rising and the falling weights and keeps an
       answer whose direction agrees with the weights used (``v_rise >= v_prev`` or
       ``v_fall < v_prev``), the one nearer ``v_prev`` where both do (the output of eq. (18)
       can jump up at a reversal, so a target may have two inputs); where neither does (the
       outputs next to a reversal that eq. (18) cannot reach) it holds ``v_prev``. Within
       ``1e-9 (1 + |v_prev|)`` of ``v_prev`` a candidate is moved to its own side of it, so a
       held target does not flip the direction by rounding;
    5. ``y = max(v - r, min(v + r, y))``, ``s = a s + e v``.

    Exact (to rounding) for the classical and the modified model with or without creep, and for
    the asymmetric model wherever its output is reachable.
    """

    n_operators: int
    n_lags: int = 0
    n_shaper: int = 0
    asymmetric: bool = False
    kind: str = field(default="inverse-pi", init=False)

    def __post_init__(self) -> None:
        for name, low in (("n_operators", 1), ("n_lags", 0), ("n_shaper", 0)):
            x = getattr(self, name)
            if not isinstance(x, int | np.integer) or isinstance(x, bool) or x < low:
                raise InputError(f"InverseStep.{name} must be an integer >= {low}, got {x!r}.")
        if not isinstance(self.asymmetric, bool):
            raise InputError(f"InverseStep.asymmetric must be True or False, got {self.asymmetric!r}.")

    @cached_property
    def params(self) -> Layout:
        n, m, d = self.n_operators, self.n_lags, self.n_shaper
        directions = ("rising", "falling") if self.asymmetric else ("rising",)
        fields: list[tuple[str, int | None]] = [("offset_N", None), ("shaper_thresholds", d), ("shaper_weights", d),
                                                ("bias", None), ("thresholds", n)]
        for name in directions:
            fields += [(f"weights_{name}", n), (f"partial_{name}", n), (f"inverse_thresholds_{name}", n),
                       (f"inverse_weights_{name}", n)]
        fields += [("creep_weights", m), ("creep_decay", m), ("creep_input", m)]
        return Layout("inverse P-I parameters", fields)

    @cached_property
    def state(self) -> Layout:
        return Layout("inverse P-I state", [("operators", self.n_operators), ("carries", self.n_lags),
                                            ("v_prev_V", 1 if self.asymmetric else 0)])

    @property
    def n_states(self) -> int:
        return int(self.state.size)

    def rest_state(self, ops: Ops, params: Any) -> Any:
        """At rest at 0 V: every operator, carry and the last input 0."""
        return ops.repeat(0.0, self.n_states)

    def _direction(self, ops: Ops, p: Any, name: str, g: Any, y: Any) -> Any:
        w, partial = getattr(p, f"weights_{name}"), getattr(p, f"partial_{name}")
        r_inv, w_inv = getattr(p, f"inverse_thresholds_{name}"), getattr(p, f"inverse_weights_{name}")
        wy = w * y
        z_prev = partial * y + ops.expand(ops.sum(wy)) - ops.cumsum(wy)
        ge = ops.expand(g)
        z = ops.maximum(ge - r_inv, ops.minimum(ge + r_inv, z_prev))
        return ops.dot(z, w_inv)

    def step(self, ops: Ops, params: Any, state: Any, target: Any) -> tuple[Any, Any]:
        """``(input, next state)`` that makes the forward model output ``target`` this sample."""
        p, s = self.params.unpack(params), self.state.unpack(state)
        x = target - p.offset_N
        if self.n_shaper:
            d = p.shaper_thresholds
            xd = ops.expand(x) - d
            shaped = ops.where(d > 0, ops.maximum(xd, 0.0), ops.where(d < 0, ops.minimum(xd, 0.0), xd + d))
            x = ops.dot(shaped, p.shaper_weights)
        g = x - p.bias
        if self.n_lags:
            g = g - ops.dot(s.carries, p.creep_weights)
        v = self._direction(ops, p, "rising", g, s.operators)
        last = ops.repeat(0.0, 0)
        if self.asymmetric:
            v_prev = ops.sum(s.v_prev_V)
            v_fall = self._direction(ops, p, "falling", g, s.operators)
            tol = 1e-9 * (1.0 + ops.fabs(v_prev))  # a held target: rounding must not flip the direction
            rise_ok, fall_ok = v >= v_prev - tol, v_fall < v_prev + tol
            v, v_fall = ops.maximum(v, v_prev), ops.minimum(v_fall, v_prev - tol)
            nearer = ops.where(v - v_prev <= v_prev - v_fall, v, v_fall)
            v = ops.where(ops.logical_and(rise_ok, fall_ok), nearer,
                          ops.where(rise_ok, v, ops.where(fall_ok, v_fall, v_prev)))
            last = ops.expand(v)
        ve = ops.expand(v)
        y = ops.maximum(ve - p.thresholds, ops.minimum(ve + p.thresholds, s.operators))
        carries = p.creep_decay * s.carries + p.creep_input * ve if self.n_lags else s.carries
        return v, self.state.pack(ops, operators=y, carries=carries, v_prev_V=last)


def inverse_realtime(model: HysteresisModel | CreepPI) -> tuple[InverseStep, NDArray[np.float64]]:
    """The :class:`InverseStep` of ``model`` and its parameter vector.

    Any model of this module: classical, modified, the paper's asymmetric, each with or without
    creep. Raises :class:`NotInvertibleError` where a partial sum of the one-sample weights (or of
    the dead-zone weights) is not positive.
    """
    h, creep = (model.hysteresis, model.creep) if isinstance(model, CreepPI) else (model, None)
    if not isinstance(h, ClassicalPI | ModifiedPI | AsymmetricPI):
        raise InputError(f"expected a P-I model of piezopreload.models.hysteresis, got {type(model).__name__}.")
    beta = 0.0 if creep is None else creep.instantaneous_gain
    what = "this P-I model" + (" with creep (its linear weight plus the creep's one-sample gain)" if creep else "")
    asymmetric = isinstance(h, AsymmetricPI)
    weights = {"rising": h.weights_rising, "falling": h.weights_falling} if isinstance(h, AsymmetricPI) \
        else {"rising": h.weights}
    parts: dict[str, Any] = {"offset_N": h.offset, "thresholds": h.thresholds, "bias": 0.0}
    for name, w in weights.items():
        w = w.copy()
        w[0] += beta
        r_inv, w_inv = _inverse_weights(h.thresholds, w, what + (f" ({name} weights)" if asymmetric else ""))
        parts.update({f"weights_{name}": w, f"partial_{name}": np.cumsum(w), f"inverse_thresholds_{name}": r_inv,
                      f"inverse_weights_{name}": w_inv})
    if isinstance(h, ModifiedPI):
        s_inv = h.shaper.inverse()
        parts.update(shaper_thresholds=s_inv.thresholds, shaper_weights=s_inv.weights, bias=h.bias)
    else:
        parts.update(shaper_thresholds=np.zeros(0), shaper_weights=np.zeros(0))
    if creep is None:
        parts.update(creep_weights=np.zeros(0), creep_decay=np.zeros(0), creep_input=np.zeros(0))
    else:
        k = creep.coefficients
        parts.update(creep_weights=creep.weights, creep_decay=k.a, creep_input=k.e)
    structure = InverseStep(h.n_operators, 0 if creep is None else creep.n_lags,
                            int(parts["shaper_thresholds"].size), asymmetric)
    return structure, structure.params.numbers(**parts)


@dataclass(frozen=True, eq=False)
class InverseAsymmetricPI(_RealTimeInverse):
    """The direction-switched inverse of the paper's asymmetric model, eq. (18) (:class:`InverseStep`, point 4).

    Exact wherever the target is an output the model reaches; in the gaps eq. (18) leaves at a
    reversal of the input it holds the last input. Built by :meth:`AsymmetricPI.inverse`.
    """

    forward: AsymmetricPI

    def __call__(self, target: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        return self.run(target, state)[0]


@dataclass(frozen=True, eq=False)
class InverseCreepPI(_RealTimeInverse):
    """The inverse of a :class:`CreepPI` (classical, modified, asymmetric), one sample at a time.

    Built by :meth:`CreepPI.inverse`: :class:`InverseStep` with the model's numbers; its state is
    the forward model's (``[play operator outputs (n), creep carries (m)]``, and the last input
    for the asymmetric model), so it takes over from any history the forward model left.
    """

    forward: CreepPI

    def __call__(self, target: ArrayLike, state: ArrayLike | None = None) -> NDArray[np.float64]:
        return self.run(target, state)[0]

def _creep_model_from_dict(data: dict[str, Any], kind: str, where: str) -> CreepPI:
    base = kind[: -len(_CREEP_SUFFIX)]
    creep = data.get("creep")
    if not isinstance(creep, dict):
        raise InputError(f"{where}.creep must be an object with time_constants_s, weights and sample_period_s "
                         f"(a {kind} model), got {type(creep).__name__}.")
    missing = [n for n in ("time_constants_s", "weights", "sample_period_s") if n not in creep]
    if missing:
        raise InputError(f"{where}.creep.{missing[0]} is missing (a creep bank needs time_constants_s, weights, sample_period_s).")
    hysteresis = model_from_dict({k: v for k, v in data.items() if k != "creep"} | {"kind": base}, where)
    if isinstance(hysteresis, CreepPI):  # not reached: the caller checked that base is a plain kind
        raise InternalError(f"{where}.kind {kind!r}: a creep model inside a creep model.")
    try:
        bank = Creep(creep["time_constants_s"], creep["weights"], creep["sample_period_s"])
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}.creep: {exc}") from None
    return CreepPI(hysteresis, bank)
