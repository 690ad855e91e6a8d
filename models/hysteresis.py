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
  any of the three models (:class:`CreepPI`), and the exact inverse of the classical and the
  modified model with creep, whose one-sample step (:func:`inverse_step`) is written once for
  numpy and CasADi.

Everything here is pure: parameters are frozen dataclasses that validate themselves, the
functions take explicit initial states and return final states, nothing is printed or read.
Arrays broadcast over leading batch dimensions: an input of shape ``(..., N)`` gives operator
outputs of shape ``(..., N, n)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from types import SimpleNamespace
from typing import Any, NamedTuple

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
    "InversePIStep",
    "InverseModifiedPIStep",
    "casadi_inverse_step",
    "AsymmetricPI",
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
    "NUMPY_OPS",
    "CASADI_OPS",
    "InverseStepLayout",
    "InverseStepParameters",
    "inverse_step",
    "inverse_step_parameters",
    "parametric_inverse_step",
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
class InverseClassicalPI:
    """Inverse of a :class:`ClassicalPI`: ``v = sum_k w'_k F_{r'_k}[O - offset]``, eqs. (19)-(20).

    Built by :meth:`ClassicalPI.inverse`. Its operator states relate to the forward ones by
    ``z_k = W_k y_k + sum_{i>k} w_i y_i`` (``W_k`` the partial sums of the forward weights),
    so the inverse can start from any forward state, for example one left by an earlier run.
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

    def step(self, state: NDArray, target: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """One sample (numpy, batched): ``(voltage, next operator states)``; :meth:`realtime`'s step."""
        structure, params = self.realtime()
        u, z = structure.step(NUMPY, params, np.asarray(state, dtype=float), np.asarray(target, dtype=float))
        return np.asarray(u, dtype=float), np.asarray(z, dtype=float)

    def casadi_step(self, state: Any, target: Any) -> tuple[Any, Any]:
        """:meth:`step` on CasADi expressions (one loop): ``(voltage, next operator states)``."""
        structure, params = self.realtime()
        return structure.step(CASADI, ca.DM(params), state, target)

    def realtime(self) -> tuple[InversePIStep, NDArray[np.float64]]:
        """The controller's feedforward component: its step's structure and its parameter vector."""
        structure = InversePIStep(self.thresholds.size)
        return structure, structure.params.numbers(offset_N=self.forward.offset, thresholds=self.thresholds,
                                                   weights=self.weights)


@dataclass(frozen=True)
class InversePIStep:
    """One sample of an inverse classical P-I model of ``n_operators``, over an ops table.

    ``v = sum_k w'_k z_k`` with ``z_k = max(O - offset - r'_k, min(O - offset + r'_k, z_k^-))``
    (eqs. (14), (19)-(20)); the model's numbers are a parameter vector (:attr:`params`), so one
    compiled step serves every model with as many operators. This is the feedforward component
    of :class:`~piezopreload.models.controller.ControllerModel`: ``kind``, ``params``,
    ``n_states``, ``rest_state`` and ``step`` are what a feedforward component supplies.
    """

    n_operators: int
    kind: str = field(default="inverse-classical-pi", init=False)

    @cached_property
    def params(self) -> Layout:
        return Layout("inverse P-I parameters", [("offset_N", None), ("thresholds", self.n_operators),
                                                 ("weights", self.n_operators)])

    @property
    def n_states(self) -> int:
        return self.n_operators

    def rest_state(self, ops: Ops, params: Any) -> Any:
        """Every operator at rest (0)."""
        return ops.repeat(0.0, self.n_operators)

    def step(self, ops: Ops, params: Any, state: Any, target: Any) -> tuple[Any, Any]:
        """``(voltage, next operator states)`` for the force ``target``."""
        p = self.params.unpack(params)
        v = ops.expand(target - p.offset_N)
        z = ops.maximum(v - p.thresholds, ops.minimum(v + p.thresholds, state))
        return ops.dot(z, p.weights), z


def casadi_inverse_step(state: Any, target: Any, offset: Any, thresholds: Any, weights: Any) -> tuple[Any, Any]:
    """:class:`InversePIStep` on CasADi expressions with the model's numbers given one by one."""
    n = int(thresholds.numel()) if hasattr(thresholds, "numel") else len(thresholds)
    return InversePIStep(n).step(CASADI, ca.vertcat(offset, thresholds, weights), state, target)


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
    inverse, and :meth:`inverse` says so. For asymmetric loops that must be inverted use
    :class:`ModifiedPI`. The state holds the operator outputs and the previous input
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

    def inverse(self) -> None:
        raise NotInvertibleError(
            "the paper's direction-switched model (eq. 18) has no exact inverse: its output jumps "
            "at every input reversal, leaving outputs no input reaches. Identify the 'modified' "
            "model for an asymmetric loop with an exact inverse, or the 'classical' one."
        )

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
class InverseModifiedPI:
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

    def step(self, state: NDArray, target: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """One sample (numpy, batched): ``(voltage, next operator states)``; :meth:`realtime`'s step."""
        structure, params = self.realtime()
        u, z = structure.step(NUMPY, params, np.asarray(state, dtype=float), np.asarray(target, dtype=float))
        return np.asarray(u, dtype=float), np.asarray(z, dtype=float)

    def realtime(self) -> tuple[InverseModifiedPIStep, NDArray[np.float64]]:
        """The controller's feedforward component: its step's structure and its parameter vector."""
        structure = InverseModifiedPIStep(self.play_inverse.thresholds.size, self.shaper_inverse.thresholds.size)
        return structure, structure.params.numbers(
            offset_N=self.forward.offset, deadzone_thresholds=self.shaper_inverse.thresholds,
            deadzone_weights=self.shaper_inverse.weights, bias=self.play_inverse.forward.offset,
            thresholds=self.play_inverse.thresholds, weights=self.play_inverse.weights)


@dataclass(frozen=True)
class InverseModifiedPIStep:
    """One sample of an inverse modified P-I model, over an ops table: the inverse dead-zone
    superposition of ``O - offset``, less the bias, through the inverse P-I operators (as
    :class:`InversePIStep`)."""

    n_operators: int
    n_deadzone: int
    kind: str = field(default="inverse-modified-pi", init=False)

    @cached_property
    def params(self) -> Layout:
        return Layout("inverse modified P-I parameters", [
            ("offset_N", None), ("deadzone_thresholds", self.n_deadzone), ("deadzone_weights", self.n_deadzone),
            ("bias", None), ("thresholds", self.n_operators), ("weights", self.n_operators)])

    @property
    def n_states(self) -> int:
        return self.n_operators

    def rest_state(self, ops: Ops, params: Any) -> Any:
        return ops.repeat(0.0, self.n_operators)

    def step(self, ops: Ops, params: Any, state: Any, target: Any) -> tuple[Any, Any]:
        p = self.params.unpack(params)
        x = ops.expand(target - p.offset_N) - p.deadzone_thresholds
        d = p.deadzone_thresholds
        shaped = ops.where(d > 0, ops.maximum(x, 0.0), ops.where(d < 0, ops.minimum(x, 0.0), x + d))
        v = ops.expand(ops.dot(shaped, p.deadzone_weights) - p.bias)
        z = ops.maximum(v - p.thresholds, ops.minimum(v + p.thresholds, state))
        return ops.dot(z, p.weights), z


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
        """The exact inverse, one sample at a time (classical and modified models)."""
        layout, params, play_inverse = _inverse_step_model(self)
        return InverseCreepPI(forward=self, layout=layout, parameters=params, play_inverse=play_inverse)

    def to_dict(self) -> dict[str, Any]:
        return {**self.hysteresis.to_dict(), "kind": self.kind, "creep": self.creep.to_dict()}


# --------------------------------------------------------------------------------------
# the inverse's one-sample step, written once over a table of operations
# --------------------------------------------------------------------------------------
#: Operations the one-sample steps need that differ between numpy arrays (a batch of loops in
#: the leading axes, operators on the last axis) and CasADi expressions (column vectors). A
#: superset of the controller's table, so one table can serve both steps.
NUMPY_OPS = SimpleNamespace(
    where=np.where, minimum=np.minimum, maximum=np.maximum,
    logical_and=np.logical_and, logical_or=np.logical_or,
    dot=lambda w, x: np.asarray(x) @ np.asarray(w),  # sum over the operators' axis
    lift=lambda x: np.asarray(x, dtype=float)[..., None],  # a per-loop number against a per-operator vector
    split=lambda x, n: (x[..., :n], x[..., n:]),
    join=lambda a, b: np.concatenate([a, b], axis=-1),
)
CASADI_OPS = SimpleNamespace(
    where=ca.if_else, minimum=ca.fmin, maximum=ca.fmax,
    logical_and=ca.logic_and, logical_or=ca.logic_or,
    dot=ca.dot,
    lift=lambda x: x,
    split=lambda x, n: (x[:n], x[n:]),
    join=ca.vertcat,
)


class InverseStepParameters(NamedTuple):
    """The parameter vector of :func:`inverse_step`, split into its parts (in this order)."""

    offset: Any
    bias: Any
    shaper_center: Any
    shaper_up_thresholds: Any
    shaper_up_weights: Any
    shaper_down_thresholds: Any
    shaper_down_weights: Any
    thresholds: Any
    weights: Any
    creep_weights: Any
    creep_decay: Any
    creep_input: Any


@dataclass(frozen=True)
class InverseStepLayout:
    """Sizes of an inverse model's state and parameter vectors (:func:`inverse_step`).

    State (``n + m``): ``[inverse play operator states z' (n), creep carries s (m)]``.
    Parameters (``3 + 2 (n_up + n_down) + 2 n + 3 m``), in this order:
    ``offset``, ``bias``, the inverse dead-zone superposition's central weight ``u'_0``, its
    positive thresholds and weights ``d'_up, u'_up`` (``n_up`` each), its negative ones
    ``d'_down, u'_down`` (``n_down`` each), the inverse thresholds ``r'`` and weights ``w'``
    of eqs. (19)-(20) (``n`` each), the creep weights ``c``, decays ``a`` and carry inputs
    ``e = a b0 + b1`` (``m`` each). A classical model has no shaper (``u'_0 = 1``,
    ``n_up = n_down = 0``, ``bias = 0``); a model without creep has ``m = 0``.
    """

    n_operators: int
    n_lags: int = 0
    n_shaper_up: int = 0
    n_shaper_down: int = 0

    def __post_init__(self) -> None:
        for name in ("n_operators", "n_lags", "n_shaper_up", "n_shaper_down"):
            x = getattr(self, name)
            if not isinstance(x, int | np.integer) or x < (1 if name == "n_operators" else 0):
                raise InputError(f"InverseStepLayout.{name} must be an integer >= {1 if name == 'n_operators' else 0}, got {x!r}.")

    @property
    def n_states(self) -> int:
        return int(self.n_operators + self.n_lags)

    @property
    def n_parameters(self) -> int:
        return int(3 + 2 * (self.n_shaper_up + self.n_shaper_down) + 2 * self.n_operators + 3 * self.n_lags)

    def split(self, params: Any) -> InverseStepParameters:
        """The parts of a parameter vector (numpy 1-D or CasADi column)."""
        sizes = [1, 1, 1, self.n_shaper_up, self.n_shaper_up, self.n_shaper_down, self.n_shaper_down,
                 self.n_operators, self.n_operators, self.n_lags, self.n_lags, self.n_lags]
        edges = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        parts = [params[int(a)] if k < 3 else params[int(a):int(b)] for k, (a, b) in enumerate(zip(edges[:-1], edges[1:]))]
        return InverseStepParameters(*parts)

    def to_dict(self) -> dict[str, int]:
        return {"n_operators": int(self.n_operators), "n_lags": int(self.n_lags),
                "n_shaper_up": int(self.n_shaper_up), "n_shaper_down": int(self.n_shaper_down)}


def inverse_step(ops: Any, layout: InverseStepLayout, params: Any, state: Any, target: Any) -> tuple[Any, Any]:
    """One sample of the exact inverse of a (modified) P-I model with creep: ``(input, next state)``.

    On numpy arrays (:data:`NUMPY_OPS`; a batch in the leading axes of ``state`` and
    ``target``) or CasADi expressions (:data:`CASADI_OPS`); ``params`` and ``state`` as
    :class:`InverseStepLayout` lays them out. With ``x = target - offset``:

    1. ``P = S^-1(x) = u'_0 x + sum u'_up max(x - d'_up, 0) + sum u'_down min(x - d'_down, 0)``,
       the inverse dead-zone superposition (identity for the classical model);
    2. ``g = P - bias - sum_j c_j s_j``: what the one-sample P-I map must give, once the
       creep's part known from the last sample is taken off;
    3. ``z' = max(g - r', min(g + r', z'_prev))``, ``v = sum w' z'``: the inverse P-I model of
       eqs. (19)-(20) for the one-sample weights ``(w_1 + beta, w_2, ..., w_n)``;
    4. ``s = a s_prev + e v``: the creep carries take this sample's input.
    """
    p = layout.split(params)
    play_state, creep_state = ops.split(state, layout.n_operators)
    x = target - p.offset
    xs = ops.lift(x)
    pre = (p.shaper_center * x
           + ops.dot(p.shaper_up_weights, ops.maximum(xs - p.shaper_up_thresholds, 0.0))
           + ops.dot(p.shaper_down_weights, ops.minimum(xs - p.shaper_down_thresholds, 0.0)))
    g = ops.lift(pre - p.bias - ops.dot(p.creep_weights, creep_state))
    z = ops.maximum(g - p.thresholds, ops.minimum(g + p.thresholds, play_state))
    v = ops.dot(p.weights, z)
    carry = p.creep_decay * creep_state + p.creep_input * ops.lift(v)
    return v, ops.join(z, carry)


def _inverse_step_model(
    model: ClassicalPI | ModifiedPI | CreepPI,
) -> tuple[InverseStepLayout, NDArray[np.float64], InverseClassicalPI]:
    """Layout, parameter vector and the one-sample inverse P-I model of an invertible model."""
    h = model.hysteresis if isinstance(model, CreepPI) else model
    if isinstance(h, AsymmetricPI):
        h.inverse()  # raises NotInvertibleError with the reason
    if not isinstance(h, ClassicalPI | ModifiedPI):
        raise InputError(f"expected a ClassicalPI, ModifiedPI or CreepPI, got {type(model).__name__}.")
    w = h.weights.copy()
    if isinstance(model, CreepPI):
        k = model.creep.coefficients
        w[0] += model.creep.instantaneous_gain
        c, a, e = model.creep.weights, k.a, k.e
        what = "this P-I model with creep (its linear weight plus the creep's one-sample gain)"
    else:
        c = a = e = np.zeros(0)
        what = "this P-I model"
    play_inverse = ClassicalPI(h.thresholds, w, 0.0)
    r_inv, w_inv = _inverse_weights(h.thresholds, w, what)
    play_inv = InverseClassicalPI(forward=play_inverse, thresholds=r_inv, weights=w_inv)
    if isinstance(h, ModifiedPI):
        s_inv = h.shaper.inverse()
        ctr = s_inv.center
        up_d, up_u = s_inv.thresholds[ctr + 1 :], s_inv.weights[ctr + 1 :]
        dn_d, dn_u = s_inv.thresholds[:ctr], s_inv.weights[:ctr]
        center, bias = float(s_inv.weights[ctr]), h.bias
    else:
        up_d = up_u = dn_d = dn_u = np.zeros(0)
        center, bias = 1.0, 0.0
    layout = InverseStepLayout(h.n_operators, int(c.size), int(up_d.size), int(dn_d.size))
    params = np.concatenate([[h.offset, bias, center], up_d, up_u, dn_d, dn_u, r_inv, w_inv, c, a, e])
    return layout, params, play_inv


def inverse_step_parameters(model: ClassicalPI | ModifiedPI | CreepPI) -> tuple[InverseStepLayout, NDArray[np.float64]]:
    """The layout and parameter vector of :func:`inverse_step` for an invertible model.

    A :class:`ClassicalPI` or :class:`ModifiedPI` without creep gives ``n_lags = 0``, so one
    compiled step serves models with and without creep. Raises :class:`NotInvertibleError`
    for the paper's asymmetric model and for weights with a nonpositive partial sum.
    """
    layout, params, _ = _inverse_step_model(model)
    return layout, params


def parametric_inverse_step(layout: InverseStepLayout) -> ca.Function:
    """:func:`inverse_step` as a CasADi function with every number an input, for code generation.

    ``pp_inverse_step(state, target, params) -> (v, state_next)``; one function serves every
    model of this layout.
    """
    x = ca.SX.sym("state", layout.n_states)
    target = ca.SX.sym("target")
    prm = ca.SX.sym("params", layout.n_parameters)
    v, nxt = inverse_step(CASADI_OPS, layout, prm, x, target)
    return ca.Function("pp_inverse_step", [x, target, prm], [v, nxt], ["state", "target", "params"], ["v", "state_next"])


@dataclass(frozen=True, eq=False)
class InverseCreepPI:
    """Exact inverse of a :class:`CreepPI` (classical or modified), one sample at a time.

    Built by :meth:`CreepPI.inverse`; :meth:`step` and :meth:`casadi_step` are
    :func:`inverse_step` on numpy and on CasADi, with :attr:`parameters` laid out as
    :attr:`layout` says. Its state is ``[inverse play operator states (n), creep carries (m)]``;
    :meth:`state_from_forward` converts a forward state, so the inverse can take over from
    any history. Code generated for any model of a layout comes from
    :func:`parametric_inverse_step`, fed :attr:`parameters`.
    """

    forward: CreepPI
    layout: InverseStepLayout
    parameters: NDArray[np.float64]
    play_inverse: InverseClassicalPI

    def initial_state(self, batch: tuple[int, ...] = ()) -> NDArray[np.float64]:
        """At rest at 0 V, as the forward model's :meth:`CreepPI.initial_state`."""
        return np.zeros(batch + (self.layout.n_states,))

    def state_from_forward(self, state: ArrayLike) -> NDArray[np.float64]:
        """The inverse's state equivalent to a forward state ``[play outputs, carries]``."""
        y, s = self.forward._split(state, np.shape(state)[:-1])
        return np.concatenate([self.play_inverse.state_from_forward(y), s], axis=-1)

    def step(self, state: ArrayLike, target: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """One sample: the input that makes the forward model output ``target``, and the next state."""
        v, nxt = inverse_step(NUMPY_OPS, self.layout, self.parameters, np.asarray(state, float), np.asarray(target, float))
        return np.asarray(v, float), np.asarray(nxt, float)

    def casadi_step(self, state: Any, target: Any) -> tuple[Any, Any]:
        """:meth:`step` on CasADi expressions, the model's numbers as constants."""
        return inverse_step(CASADI_OPS, self.layout, ca.DM(self.parameters), state, target)

    def run(self, target: ArrayLike, state: ArrayLike | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Inputs for the targets of shape (..., N) from ``state`` (at rest by default), and the final state."""
        target = np.asarray(target, dtype=float)
        x = self.initial_state(target.shape[:-1]) if state is None else np.asarray(state, float)
        out = np.empty(target.shape)
        for k in range(target.shape[-1]):
            out[..., k], x = self.step(x, target[..., k])
        return out, x

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
