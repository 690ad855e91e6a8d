"""The operators every P-I model here is built of, and the algebra of their inverses.

* the play operator, eq. (14) of Zhang, Jin, Lin (2021) (``docs/models.md``, section 2), one
  sample at a time (:func:`play_step`) and over whole signals (:func:`play`);
* the direction of the input, ``p`` of eq. (18) (:func:`rising`);
* one-sided dead-zone operators and their superposition (:class:`DeadZone`), the output
  operators of Kuhnen's modified model;
* the thresholds and weights of the inverse of a superposition, eqs. (19)-(20)
  (:func:`inverse_weights`), and the error raised where there is none.

Pure numpy: inputs of shape ``(..., N)`` give operator outputs of shape ``(..., N, n)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from piezopreload.core.errors import InputError

__all__ = ["NotInvertibleError", "uniform_thresholds", "play_step", "play", "rising", "deadzone", "DeadZone",
           "inverse_weights", "vector", "scalar", "check_thresholds"]


class NotInvertibleError(InputError):
    """The model has no exact inverse (a partial sum of its weights is not positive)."""



# --------------------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------------------
def vector(name: str, value: ArrayLike, *, min_len: int = 1) -> NDArray[np.float64]:
    """``value`` as a read-only 1-D array of finite numbers; a ValueError names ``name`` and the bad entry."""
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


def scalar(name: str, value: float) -> float:
    """``value`` as a finite float; a ValueError names ``name``."""
    x = float(value)
    if not np.isfinite(x):
        raise ValueError(f"{name} must be finite, got {value!r}.")
    return x


def check_thresholds(name: str, r: NDArray[np.float64]) -> None:
    """Thresholds start at 0 (the linear term) and increase strictly."""
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
    return np.asarray(np.maximum(v - r, np.minimum(v + r, y_prev)), np.float64)  # (..., n): an array


def _play_1d(v: NDArray[np.float64], r: NDArray[np.float64], y0: NDArray[np.float64],
             out: NDArray[np.float64]) -> None:
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



def rising(v: ArrayLike, v_prev: ArrayLike = 0.0) -> NDArray[np.bool_]:
    """``p`` of eq. (18): True where the input does not fall, ``v_i >= v_{i-1}`` (``v_{-1} = v_prev``)."""
    v = np.asarray(v, dtype=float)
    first = np.broadcast_to(np.asarray(v_prev, float), v.shape[:-1])[..., None]
    return v >= np.concatenate([first, v[..., :-1]], axis=-1)



# --------------------------------------------------------------------------------------
# P-I weights and their inverse, eqs. (19)-(20)
# --------------------------------------------------------------------------------------
def inverse_weights(
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
# one-sided dead-zone operators (the output operators of Kuhnen's modified P-I model)
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
        d = vector("deadzone_thresholds", self.thresholds)
        u = vector("deadzone_weights", self.weights)
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
        d_up, u_up = inverse_weights(d[c:], u[c:], "the dead-zone superposition (positive side)")
        d_dn, u_dn = inverse_weights(-d[c::-1], u[c::-1], "the dead-zone superposition (negative side)")
        return DeadZone(
            thresholds=np.concatenate([-d_dn[:0:-1], d_up]),
            weights=np.concatenate([u_dn[:0:-1], u_up]),
        )

