"""Prandtl-Ishlinskii hysteresis: play operators, P-I models and their analytic inverses.

Section 3.2 of Zhang, Jin, Lin (2021), restated in ``EQUATIONS.md``:

* the play operator, eq. (14);
* the classical P-I model, eq. (15), with a linear term (threshold 0) and an output offset;
* the paper's direction-switched asymmetric model, eq. (18);
* Kuhnen's modified P-I model (play operators followed by a superposition of one-sided
  dead-zone operators, K. Kuhnen, Eur. J. Control 9(4), 2003), which describes asymmetric
  loops and keeps an exact analytic inverse;
* the analytic inverses, eqs. (19)-(20).

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

from piezopreload.core.errors import InputError
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


def model_from_dict(data: dict[str, Any], where: str = "model") -> HysteresisModel:
    """Rebuild a model from :meth:`to_dict` output; errors name the offending field."""
    if not isinstance(data, dict):
        raise ValueError(f"{where} must be an object, got {type(data).__name__}.")
    kind = data.get("kind")
    if kind not in _FIELDS:
        raise ValueError(f"{where}.kind must be one of {sorted(_FIELDS)}, got {kind!r}.")
    cls, names = _FIELDS[kind]
    missing = [n for n in names if n not in data]
    if missing:
        raise ValueError(f"{where}.{missing[0]} is missing (a {kind} model needs {', '.join(names)}).")
    try:
        return cls(**{n: data[n] for n in names})
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None
